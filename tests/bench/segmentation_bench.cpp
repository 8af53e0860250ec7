// Fluoroscopy segmentation (Abah 2022, §4.8.1; we ask ≥ 10 Hz per view): one bi-plane pair of
// 1024 × 1024 SIMULATED frames (noise, anatomy, the synthetic ICA in contrast, a bent catheter)
// segmented per iteration, AP then lateral, on one core. Items/s = pairs per second. The vessel
// centerline of the roadmap (≥ 20 Hz) is timed on its own.
#include <benchmark/benchmark.h>

#include <vector>

#include "tendril/drivers/sim/simulated_fluoroscope.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/perception/fluoroscopy_segmenter.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace {

using namespace tendril;

constexpr int kSize = 1024;

struct Plane {
  std::vector<std::uint8_t> roadmap, frame;
};

std::vector<Plane> render_pair() {
  sim::FluoroscopeOptions o;
  o.geometry.width = o.geometry.height = kSize;
  o.geometry.pixel_spacing_mm = 160.0 / kSize;
  o.geometry.isocentre = {0.0, 0.0, 50.0};
  const auto ica = teleop::make_synthetic_ica(1);
  const std::vector<sim::VesselTube> vessels{{ica.points, ica.radii}};
  teleop::CatheterParameters p;
  p.shaft_length = 80.0;
  const teleop::ConstantCurvatureCatheter model(p);
  std::vector<Eigen::Vector3d> backbone(model.backbone_point_count(40));
  backbone.resize(
      model.backbone(teleop::ConstantCurvatureCatheter::JointVector(50, -0.7, -0.3, 0.9), 40, backbone));
  std::vector<Plane> planes;
  for (auto view : {sim::FluoroView::kAp, sim::FluoroView::kLateral}) {
    sim::SimulatedFluoroscope f(view, o, vessels);
    Plane plane;
    auto image = f.render({});
    plane.roadmap.assign(image.begin(), image.end());
    image = f.render(backbone);
    plane.frame.assign(image.begin(), image.end());
    planes.push_back(std::move(plane));
  }
  return planes;
}

void BM_SegmentBiplanePair1024(benchmark::State& state) {
  const auto planes = render_pair();
  teleop::perception::FluoroscopySegmentationParameters p;
  p.downsample = static_cast<int>(state.range(0));
  std::vector<teleop::perception::FluoroscopySegmenter> segmenters;
  for (const auto& plane : planes) {
    segmenters.emplace_back(p);
    segmenters.back().set_roadmap(teleop::perception::grey_image(plane.roadmap, kSize, kSize));
  }
  for (auto _ : state) {
    for (std::size_t i = 0; i < planes.size(); ++i) {
      const auto& result =
          segmenters[i].segment(teleop::perception::grey_image(planes[i].frame, kSize, kSize));
      if (!result.found) state.SkipWithError(result.message.c_str());
      benchmark::DoNotOptimize(result.tip);
    }
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_SegmentBiplanePair1024)->Arg(1)->Arg(2)->Arg(4)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_VesselCenterline1024(benchmark::State& state) {
  const auto planes = render_pair();
  teleop::perception::FluoroscopySegmentationParameters p;
  for (auto _ : state) {
    // A new parameter set each time: the centerline is otherwise cached per roadmap.
    teleop::perception::FluoroscopySegmenter segmenter(p);
    segmenter.set_roadmap(teleop::perception::grey_image(planes[0].roadmap, kSize, kSize));
    benchmark::DoNotOptimize(segmenter.vessel_centerline().length_px);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VesselCenterline1024)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
