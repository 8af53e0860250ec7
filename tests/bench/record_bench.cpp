// MCAP recorder throughput (record/): the teleoperation load of issue 18 — two 1024×1024 JPEG image
// streams (about 150 kB a frame, incompressible like a real JPEG) at 30 fps each plus joint states at
// 1 kHz — recorded to a temporary directory, per chunk compression. One iteration is one second of
// that load, enqueued as fast as the producer can and waited for until the writer thread has handed
// every message to the kernel (page cache; no fsync). realtime_x = seconds of load recorded per
// second of wall time. The producer side, which the data publishers pay (never the control thread,
// which only fills a state snapshot), is measured alone in BM_RecordCall_*.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "tendril/record/recorder.hpp"

namespace {

using tendril::record::ChannelSpec;
using tendril::record::Compression;
using tendril::record::Recorder;
using tendril::record::RecorderOptions;

constexpr std::size_t kImageBytes = 150'000;

std::filesystem::path bench_dir(const std::string& name) {
  auto dir = std::filesystem::temp_directory_path() /
             ("tendril-record-bench-" + std::to_string(::getpid()) + "-" + name);
  std::filesystem::remove_all(dir);
  return dir;
}

std::vector<std::vector<std::uint8_t>> images(std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<std::vector<std::uint8_t>> v(8, std::vector<std::uint8_t>(kImageBytes));
  for (auto& image : v) {
    for (auto& b : image) b = static_cast<std::uint8_t>(rng());
  }
  return v;
}

std::vector<std::uint8_t> joint_state(std::uint64_t i) {
  const std::string s =
      R"({"t":)" + std::to_string(i) +
      R"(,"position":[12.5,0.31,-0.42,0.05],"velocity":[0.1,0,0,0],"effort":[0.2,0.1,0.3,0.1]})";
  return {s.begin(), s.end()};
}

RecorderOptions options_for(const std::filesystem::path& dir, Compression compression) {
  RecorderOptions o;
  o.directory = dir;
  o.writer.compression = compression;
  o.max_file_bytes = std::uint64_t{512} << 20;
  o.queue_capacity = 1 << 14;
  o.queue_max_bytes = std::size_t{256} << 20;
  return o;
}

void BM_RecorderThroughput(benchmark::State& state) {
  const auto compression = static_cast<Compression>(state.range(0));
  const auto dir = bench_dir("throughput");
  Recorder recorder(options_for(dir, compression));
  const auto joints = recorder.add_channel(ChannelSpec{"/robot/joint_states", "json", "", "", {}, {}});
  const auto ap = recorder.add_channel(ChannelSpec{"/imaging/ap", "jpeg", "", "", {}, {}});
  const auto lateral = recorder.add_channel(ChannelSpec{"/imaging/lateral", "jpeg", "", "", {}, {}});
  const auto ap_images = images(1), lateral_images = images(2);
  std::vector<std::vector<std::uint8_t>> joint_messages;
  for (std::uint64_t i = 0; i < 1000; ++i) joint_messages.push_back(joint_state(i));
  recorder.start();

  std::uint64_t t = 0, messages = 0, bytes = 0, frame = 0;
  for (auto _ : state) {
    for (std::uint64_t step = 0; step < 1000; ++step, t += 1'000'000) {
      recorder.record(joints, t, joint_messages[step]);
      bytes += joint_messages[step].size();
      ++messages;
      if (step % 33 == 0 && step < 990) {  // 30 frames a second on each plane
        recorder.record(ap, t, ap_images[frame % ap_images.size()]);
        recorder.record(lateral, t, lateral_images[frame % lateral_images.size()]);
        bytes += 2 * kImageBytes;
        messages += 2;
        ++frame;
      }
    }
    while (recorder.stats().written + recorder.stats().dropped < messages) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  }
  recorder.stop();
  const auto stats = recorder.stats();
  state.SetBytesProcessed(static_cast<std::int64_t>(bytes));
  state.SetItemsProcessed(static_cast<std::int64_t>(messages));
  state.counters["dropped"] = static_cast<double>(stats.dropped);
  // MCAP bytes on disk per payload byte (framing, indexes and compression together).
  state.counters["file_per_payload"] = static_cast<double>(stats.bytes) / static_cast<double>(bytes);
  state.counters["realtime_x"] =
      benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  std::filesystem::remove_all(dir);
}
BENCHMARK(BM_RecorderThroughput)
    ->Arg(static_cast<int>(Compression::kNone))
    ->Arg(static_cast<int>(Compression::kZstd))
    ->Arg(static_cast<int>(Compression::kLz4))
    ->ArgName("compression_none0_zstd1_lz4_2")
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(3.0);

// The producer's cost of record(): a copy into the queue and a few atomics, never a wait, while the
// writer thread drains (zstd) at the same time.
void record_calls(benchmark::State& state, std::size_t size) {
  const auto dir = bench_dir("calls");
  auto options = options_for(dir, Compression::kZstd);
  options.queue_capacity = 1 << 17;
  options.queue_max_bytes = std::size_t{1} << 30;
  Recorder recorder(options);
  const auto channel = recorder.add_channel(ChannelSpec{"/bench", "bytes", "", "", {}, {}});
  const std::vector<std::uint8_t> message(size, 0x5A);
  recorder.start();
  std::uint64_t t = 0;
  for (auto _ : state) benchmark::DoNotOptimize(recorder.record(channel, ++t, message));
  recorder.stop();
  state.counters["dropped"] = static_cast<double>(recorder.stats().dropped);
  std::filesystem::remove_all(dir);
}
void BM_RecordCall_JointState(benchmark::State& state) { record_calls(state, 120); }
// record(shared_ptr): the WebSocket publisher's already-serialised message, held rather than copied.
void BM_RecordCall_SharedImage(benchmark::State& state) {
  const auto dir = bench_dir("shared");
  auto options = options_for(dir, Compression::kZstd);
  options.queue_max_bytes = std::size_t{1} << 30;
  Recorder recorder(options);
  const auto channel = recorder.add_channel(ChannelSpec{"/bench", "json", "", "", {}, {}});
  const auto message = std::make_shared<const std::string>(kImageBytes, 'j');
  recorder.start();
  std::uint64_t t = 0;
  for (auto _ : state) benchmark::DoNotOptimize(recorder.record(channel, ++t, message));
  recorder.stop();
  state.counters["dropped"] = static_cast<double>(recorder.stats().dropped);
  std::filesystem::remove_all(dir);
}
BENCHMARK(BM_RecordCall_SharedImage)->Iterations(2000);
void BM_RecordCall_Image(benchmark::State& state) { record_calls(state, kImageBytes); }
BENCHMARK(BM_RecordCall_JointState)->Iterations(100000);
BENCHMARK(BM_RecordCall_Image)->Iterations(2000);

}  // namespace
