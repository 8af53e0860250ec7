// Sensing disk units (Abah 2022, ch. 3, continuum/): how many ToF points per second go into the voxel map,
// what one control cycle's SDU supervision costs, what a SIMULATED disk costs to sense, and the disks'
// CAN bus load (worst-case stuffing) as counters.
#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>
#include <vector>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_perception.hpp"
#include "tendril/continuum/sdu_safety.hpp"
#include "tendril/continuum/sdu_simulation.hpp"

namespace tc = tendril::continuum;

namespace {

tc::Scene box_room() {
  tc::Scene scene;
  scene.add(tc::ScenePlane{Eigen::Vector3d(0, 185, 0), -Eigen::Vector3d::UnitY()});
  scene.add(tc::ScenePlane{Eigen::Vector3d(0, -185, 0), Eigen::Vector3d::UnitY()});
  scene.add(tc::ScenePlane{Eigen::Vector3d(185, 0, 0), -Eigen::Vector3d::UnitX()});
  scene.add(tc::ScenePlane{Eigen::Vector3d(-185, 0, 0), Eigen::Vector3d::UnitX()});
  return scene;
}

// A 60 s sweep of the 5-disk segment in a box room, as the disks would send it (samples and poses).
struct Scan {
  std::vector<std::array<Eigen::Isometry3d, tc::kSdusPerSegment>> poses;
  std::vector<std::array<tc::SduSample, tc::kSdusPerSegment>> samples;
};
const Scan& scan() {
  static const Scan s = [] {
    Scan out;
    const tc::SduSegmentModel m;
    const auto scene = box_room();
    std::vector<tc::SimulatedSduNode> nodes;
    for (std::size_t i = 0; i < tc::kSdusPerSegment; ++i)
      nodes.emplace_back(m, tc::TofModel{}, tc::HallModel{}, i + 1);
    for (int k = 0; k < 2000; ++k) {
      const double t = k * 0.03;
      const tc::SegmentConfiguration q{1.5 * std::sin(0.1 * t), 0.3 + 0.2 * std::sin(0.07 * t),
                                       2.0 * std::sin(0.05 * t)};
      out.poses.push_back(tc::disk_poses(m, q));
      std::array<tc::SduSample, tc::kSdusPerSegment> s{};
      for (std::size_t i = 0; i < tc::kSdusPerSegment; ++i)
        s[i] = nodes[i].sense(scene, out.poses.back()[i], t);
      out.samples.push_back(s);
    }
    return out;
  }();
  return s;
}

// Ranges → points in {0} → voxel map (5 mm), the whole mapping path of one 5-disk sample per iteration.
void BM_MapPointsPerSecond(benchmark::State& state) {
  const tc::SduSegmentModel m;
  const auto& s = scan();
  tc::VoxelMap map(5.0, 1'000'000);
  std::array<Eigen::Vector3d, tc::kTofPerSdu> pts;
  std::size_t k = 0;
  std::int64_t points = 0;
  for (auto _ : state) {
    const auto& poses = s.poses[k];
    const auto& samples = s.samples[k];
    for (std::size_t i = 0; i < tc::kSdusPerSegment; ++i) {
      const std::size_t n = tc::sample_points(m, poses[i], samples[i], 130.0, pts);
      for (std::size_t p = 0; p < n; ++p) benchmark::DoNotOptimize(map.insert(pts[p]));
      points += static_cast<std::int64_t>(n);
    }
    k = (k + 1) % s.poses.size();
  }
  state.SetItemsProcessed(points);  // items/s = points/s into the map
  state.counters["voxels"] = static_cast<double>(map.size());
}
BENCHMARK(BM_MapPointsPerSecond);

// The voxel map alone, on a stream of scattered points (a worst case for the hash: many new voxels).
void BM_VoxelInsert(benchmark::State& state) {
  std::vector<Eigen::Vector3d> pts;
  std::uint64_t x = 88172645463325252ULL;
  for (int i = 0; i < 1 << 16; ++i) {
    x ^= x << 13, x ^= x >> 7, x ^= x << 17;
    pts.emplace_back((x % 4000) * 0.1, ((x >> 16) % 4000) * 0.1, ((x >> 32) % 4000) * 0.1);
  }
  tc::VoxelMap map(5.0, static_cast<std::size_t>(state.range(0)));
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(map.insert(pts[i]));
    i = (i + 1) & (pts.size() - 1);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VoxelInsert)->Arg(100'000)->Arg(1'000'000);

// One control cycle of the SDU supervisor on five disks' samples.
void BM_SupervisorStep(benchmark::State& state) {
  const tc::SduSegmentModel m;
  tc::SduSupervisorParameters p;
  p.unbias_samples = 1;
  auto supervisor = std::make_unique<tc::SduSupervisor>(m, tc::kSdusPerSegment, p);
  const auto& s = scan();
  std::int64_t now = 1'000'000'000;
  std::size_t k = 0;
  for (auto _ : state) {
    now += 10'000'000;
    auto samples = s.samples[k];
    for (auto& x : samples) x.stamp_ns = now;
    const auto& d = supervisor->step(now, s.poses[k], samples);
    benchmark::DoNotOptimize(tc::apply_sdu_safety(d, p, Eigen::Vector3d(10, 20, 0)));
    k = (k + 1) % s.poses.size();
  }
}
BENCHMARK(BM_SupervisorStep);

// One SIMULATED disk sensing the box room (8 ToF × 25 rays, 8 Hall windows × 9 samples).
void BM_SimulatedDiskSense(benchmark::State& state) {
  const tc::SduSegmentModel m;
  const auto scene = box_room();
  tc::SimulatedSduNode node(m, tc::TofModel{}, tc::HallModel{}, 3);
  const auto pose = tc::disk_pose(m, {0.0, 0.4, 0.3}, 4);
  double t = 0.0;
  for (auto _ : state) benchmark::DoNotOptimize(node.sense(scene, pose, t += 0.01));
}
BENCHMARK(BM_SimulatedDiskSense);

// Frames → sample reassembly on the bus thread, per 5-disk sample (35 frames).
void BM_FrameAssembly(benchmark::State& state) {
  const auto& s = scan();
  std::vector<std::array<tendril::can::Frame, tc::kSduFramesPerSample>> frames;
  for (std::size_t i = 0; i < tc::kSdusPerSegment; ++i)
    frames.push_back(tc::encode_sdu_sample(i, s.samples[0][i]));
  tc::SduFrameAssembler a(tc::kSdusPerSegment);
  std::int64_t now = 0;
  for (auto _ : state) {
    now += 10'000'000;
    for (const auto& disk : frames)
      for (const auto& f : disk) benchmark::DoNotOptimize(a.handle(f, now));
  }
  state.SetItemsProcessed(state.iterations() * 35);
}
BENCHMARK(BM_FrameAssembly);

// Not a timing: the worst-case bus load of 5 disks on classic CAN at 1 Mbit/s, reported as counters.
void BM_SduBusLoad(benchmark::State& state) {
  const double rate = static_cast<double>(state.range(0));
  tc::SduBusLoad load;
  for (auto _ : state) benchmark::DoNotOptimize(load = tc::estimate_sdu_bus_load(1'000'000, rate, 5));
  state.counters["load_pct"] = 100.0 * load.load;
  state.counters["bit_per_s"] = load.bits_per_second;
  state.SetLabel(load.breakdown);
}
BENCHMARK(BM_SduBusLoad)->Arg(100)->Arg(140)->Arg(200);

}  // namespace
