// Cost of one catheter tip EKF step (Abah 2022, §4.9.3): predict (4.41)–(4.42) and the H = I
// correction, as run once per 3 mm insertion increment and segmented frame; and the κ lookup that
// feeds it.
#include <benchmark/benchmark.h>

#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "tendril/teleop/perception/planar_curvature.hpp"
#include "tendril/teleop/perception/tip_ekf.hpp"

namespace {

using tendril::teleop::perception::PlanarCurvatureProfile;
using tendril::teleop::perception::TipEkf;
using tendril::teleop::perception::TipEkfNoise;
using tendril::teleop::perception::TipEkfState;

void BM_TipEkfStep(benchmark::State& state) {
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  TipEkfState tip = ekf.start_at({0.0, 0.0, 0.0});
  double s = 0.0;
  for (auto _ : state) {
    // A measurement that follows a gentle arc, so the state stays bounded however many iterations run.
    s += 3.0;
    const Eigen::Vector3d z(50.0 * std::sin(s / 50.0), 50.0 * (1.0 - std::cos(s / 50.0)), s / 50.0);
    benchmark::DoNotOptimize(ekf.step(tip, 3.0, 0.02, z));
    benchmark::DoNotOptimize(tip);
    if (s > 1e6) s = 0.0;
  }
}
BENCHMARK(BM_TipEkfStep);

void BM_TipEkfStepWithCurvatureLookup(benchmark::State& state) {
  std::vector<Eigen::Vector2d> arc;
  for (int i = 0; i <= 3000; ++i) {
    const double s = 0.05 * i;
    arc.emplace_back(50.0 * std::sin(s / 50.0), 50.0 * (1.0 - std::cos(s / 50.0)));
  }
  const PlanarCurvatureProfile profile = PlanarCurvatureProfile::from_polyline(arc);
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  TipEkfState tip = ekf.start_at({0.0, 0.0, 0.0});
  double s = 0.0;
  for (auto _ : state) {
    const double next = s + 3.0 > profile.length() ? 3.0 : s + 3.0;
    const double start = next == 3.0 ? 0.0 : s;
    const Eigen::Vector2d p = profile.point_at(next);
    const Eigen::Vector3d z(p.x(), p.y(), profile.heading_at(next));
    benchmark::DoNotOptimize(ekf.step(tip, next - start, profile.mean_curvature(start, next), z));
    benchmark::DoNotOptimize(tip);
    s = next;
  }
}
BENCHMARK(BM_TipEkfStepWithCurvatureLookup);

}  // namespace
