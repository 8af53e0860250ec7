// Ultrasound reconstruction and FBG shape (Heunis et al. 2021, §3.2–3.3 and Appendix B): one slice's ellipse
// EKF fit (the per-image cost at the scanner's 30 Hz, we ask ≤ 33 ms), the SIMULATED slice renderer that
// feeds it, and one FBG frame's shape reconstruction.
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "tendril/ultrasound/ellipse_ekf.hpp"
#include "tendril/ultrasound/fbg_shape.hpp"
#include "tendril/ultrasound/simulated_bmode.hpp"

namespace {

using namespace tendril::ultrasound;

tendril::teleop::CenterlinePolyline tube() {
  tendril::teleop::CenterlinePolyline line;
  for (int i = -40; i <= 40; ++i) {
    line.points.emplace_back(static_cast<double>(i), 0.0, 30.0);
    line.radii.push_back(5.0);
  }
  return line;
}

Eigen::Isometry3d oblique_pose() {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  pose.translation() = Eigen::Vector3d(0.0, -1.0, 1.5);
  return pose;
}

// N = 30 rays, M = 40 candidates, seed 1.4 mm off the centre: blur + star iterations until converged.
void BM_EllipseEkfSlice(benchmark::State& state) {
  const BModeGeometry geometry{};
  const SimulatedBModeProbe probe(tube(), geometry);
  const BModeImage image = probe.render(oblique_pose(), 1);
  const Eigen::Vector2d seed = probe.truth(oblique_pose())->centre + Eigen::Vector2d(1.0, 1.0);
  EllipseSliceSegmenter segmenter(geometry);
  int iterations = 0;
  for (auto _ : state) {
    const SliceSegmentation& result = segmenter.segment(image, seed);
    iterations = result.iterations;
    benchmark::DoNotOptimize(result.centre);
  }
  state.counters["star_iterations"] = iterations;
}
BENCHMARK(BM_EllipseEkfSlice)->Unit(benchmark::kMillisecond);

void BM_SimulatedBModeRender(benchmark::State& state) {
  const SimulatedBModeProbe probe(tube(), BModeGeometry{});
  std::uint64_t seed = 0;
  for (auto _ : state) benchmark::DoNotOptimize(probe.render(oblique_pose(), ++seed).pixels.data());
}
BENCHMARK(BM_SimulatedBModeRender)->Unit(benchmark::kMillisecond);

void BM_FbgShapeReconstruction(benchmark::State& state) {
  const MulticoreFiber fiber;
  SimulatedFbgInterrogator interrogator(fiber, 1.2, 1);
  std::vector<Eigen::Vector3d> arc;
  for (double s = 0.0; s <= 271.0; s += 0.1)
    arc.emplace_back(100.0 * (1.0 - std::cos(s / 100.0)), 0.0, 100.0 * std::sin(s / 100.0));
  const FbgFrame frame = interrogator.measure(arc, 0.0, 1);
  FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
  for (auto _ : state) benchmark::DoNotOptimize(reconstructor.reconstruct(frame).points.data());
}
BENCHMARK(BM_FbgShapeReconstruction)->Unit(benchmark::kMicrosecond);

}  // namespace
