// tendril-record-selftest: writes a known recording through tendril::record::Recorder for the
// independent reader test (read_mcap.test.mjs, @mcap/core).
//
//   tendril-record-selftest --out DIR [--compression zstd|lz4|none] [--seconds S] [--max-file-bytes B]
//       Records S seconds of log time (default 2) on three channels: /robot/joint_states at 1 kHz
//       (json with a JSON Schema), /imaging/ap at 30 Hz (a 150 kB JPEG-sized payload) and
//       /robot/events at 10 Hz (json, no schema), then stops the recorder and prints one JSON line:
//       {"files": [...], "sent": {topic: count}, "dropped": n, "written": n}.
//   tendril-record-selftest --out DIR --until-killed [--compression …]
//       Records the same streams without end (paced at about real time) and prints
//       "flushed F written W" whenever the count of messages in complete chunks changes, so the test
//       knows what a SIGKILL must leave readable.
//
// Message contents are a function of (topic, sequence), so the reader checks every byte it reads.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "tendril/record/recorder.hpp"

namespace {

using tendril::record::ChannelSpec;
using tendril::record::Recorder;

std::vector<std::uint8_t> text(const std::string& s) { return {s.begin(), s.end()}; }

std::vector<std::uint8_t> joint_state(std::uint64_t seq) {
  return text(R"({"seq":)" + std::to_string(seq) + R"(,"position":[)" + std::to_string(seq * 0.001) +
              R"(,0.25,-1.5,3.0],"velocity":[0.1,0,0,0]})");
}
std::vector<std::uint8_t> event(std::uint64_t seq) {
  return text(R"({"seq":)" + std::to_string(seq) + R"(,"kind":"transition","to":"ENABLED"})");
}
// JPEG-sized: 150 000 bytes, starting with the JPEG SOI marker and the sequence number (little-endian
// uint32), then bytes from a fixed linear congruential generator seeded by the sequence (what the test
// recomputes), ending with the EOI marker.
constexpr std::size_t kImageBytes = 150'000;
std::vector<std::uint8_t> image(std::uint64_t seq) {
  std::vector<std::uint8_t> v(kImageBytes);
  v[0] = 0xFF;
  v[1] = 0xD8;
  for (int i = 0; i < 4; ++i) v[2 + i] = static_cast<std::uint8_t>(seq >> (8 * i));
  std::uint32_t x = static_cast<std::uint32_t>(seq) * 2654435761U + 1U;
  for (std::size_t k = 6; k + 2 < v.size(); ++k) {
    x = x * 1664525U + 1013904223U;
    v[k] = static_cast<std::uint8_t>(x >> 24);
  }
  v[v.size() - 2] = 0xFF;
  v[v.size() - 1] = 0xD9;
  return v;
}

[[noreturn]] void usage(const std::string& why) {
  std::cerr << "tendril-record-selftest: " << why
            << "\nusage: tendril-record-selftest --out DIR [--compression zstd|lz4|none] [--seconds S]"
               " [--max-file-bytes B] [--until-killed]\n";
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  tendril::record::RecorderOptions options;
  double seconds = 2.0;
  bool until_killed = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage(arg + " needs a value");
      return argv[++i];
    };
    try {
      if (arg == "--out") {
        options.directory = value();
      } else if (arg == "--compression") {
        options.writer.compression = tendril::record::parse_compression(value());
      } else if (arg == "--seconds") {
        seconds = std::stod(value());
      } else if (arg == "--max-file-bytes") {
        options.max_file_bytes = std::stoull(value());
      } else if (arg == "--until-killed") {
        until_killed = true;
      } else {
        usage("unknown option " + arg);
      }
    } catch (const std::invalid_argument& e) {
      usage(arg + ": " + e.what());
    }
  }
  if (options.directory.empty()) usage("--out is required");
  if (!(seconds > 0.0 && seconds < 3600.0)) usage("--seconds must be in (0, 3600)");
  options.file_prefix = "selftest";
  options.queue_capacity = 1 << 14;
  options.queue_max_bytes = std::size_t{512} << 20;
  if (until_killed) {
    // Small chunks written often, so that a kill finds several on disk.
    options.writer.chunk_size = 256 * 1024;
    options.max_chunk_delay = std::chrono::milliseconds(20);
  }
  options.log = [](std::string_view line) { std::cerr << line << "\n"; };

  Recorder recorder(options);
  const auto joints = recorder.add_channel(ChannelSpec{
      "/robot/joint_states",
      "json",
      "tendril.JointState",
      "jsonschema",
      text(R"({"type":"object","properties":{"seq":{"type":"integer"},"position":{"type":"array"}}})"),
      {{"robot", "selftest"}}});
  const auto images = recorder.add_channel(ChannelSpec{"/imaging/ap", "jpeg", "", "", {}, {}});
  const auto events = recorder.add_channel(ChannelSpec{"/robot/events", "json", "", "", {}, {}});
  recorder.start();

  // Log time: 1 ms steps from t0; an image every 33 ms (30 fps), an event every 100 ms.
  constexpr std::uint64_t kT0 = 1'700'000'000'000'000'000ULL;
  const auto steps = static_cast<std::uint64_t>(seconds * 1000.0);
  std::map<std::string, std::uint64_t> sent;
  std::uint64_t n_joint = 0, n_image = 0, n_event = 0, last_flushed = 0;
  for (std::uint64_t step = 0; until_killed || step < steps; ++step) {
    const std::uint64_t t = kT0 + step * 1'000'000;
    if (step % 33 == 0) {
      if (recorder.record(images, t, image(n_image))) ++sent["/imaging/ap"];
      ++n_image;
    }
    if (recorder.record(joints, t, joint_state(n_joint))) ++sent["/robot/joint_states"];
    ++n_joint;
    if (step % 100 == 0) {
      if (recorder.record(events, t, event(n_event))) ++sent["/robot/events"];
      ++n_event;
    }
    if (until_killed) {
      const auto stats = recorder.stats();
      if (stats.flushed != last_flushed) {
        last_flushed = stats.flushed;
        std::printf("flushed %llu written %llu\n", static_cast<unsigned long long>(stats.flushed),
                    static_cast<unsigned long long>(stats.written));
        std::fflush(stdout);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  recorder.stop();
  const auto stats = recorder.stats();
  std::cout << R"({"files":[)";
  const auto files = recorder.files();
  for (std::size_t f = 0; f < files.size(); ++f)
    std::cout << (f ? "," : "") << '"' << files[f].string() << '"';
  std::cout << R"(],"sent":{)";
  bool first = true;
  for (const auto& [topic, n] : sent) {
    std::cout << (first ? "" : ",") << '"' << topic << "\":" << n;
    first = false;
  }
  std::cout << R"(},"dropped":)" << stats.dropped << R"(,"written":)" << stats.written << R"(,"error":")"
            << (stats.error.empty() ? "" : "see stderr") << "\"}" << std::endl;
  return stats.error.empty() ? 0 : 1;
}
