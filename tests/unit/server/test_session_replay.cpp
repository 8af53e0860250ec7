// SessionReplay (server/src/session_replay.cpp): a recording written by McapWriter is published again
// with its topics and schemas, every message in order, at the recorded pace times the rate, with
// play/pause/seek/rate controls that refuse bad input. Timing is asserted one way only where it is
// deterministic (a message is never replayed before its time) and with generous upper bounds (a shared
// 2-core machine may be late, never early).
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/record/mcap_writer.hpp"
#include "tendril/server/session_replay.hpp"

namespace tendril::server {
namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

constexpr std::uint64_t kT0 = 1'764'000'000'000'000'000ULL;  // a log time in 2025, ns
constexpr std::uint64_t kJointPeriod = 20'000'000;           // 50 Hz, as the publisher records
constexpr int kJoints = 101;                                 // 0 … 2 s

std::vector<std::uint8_t> bytes_of(const std::string& s) { return {s.begin(), s.end()}; }

class SessionReplayTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("tendril-replay-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    path_ = dir_ / "session.mcap";
    record::McapWriterOptions options;
    options.chunk_size = 2048;
    record::McapWriter writer(path_, options);
    const auto js = writer.add_schema("tendril.JointState", "jsonschema", bytes_of(R"({"type":"object"})"));
    const auto ev = writer.add_schema("tendril.SafetyEvents", "jsonschema", bytes_of(R"({"type":"object"})"));
    const auto joints = writer.add_channel(js, "/srmc/joint_states", "json");
    const auto events = writer.add_channel(ev, "/safety/events", "json");
    for (int i = 0; i < kJoints; ++i) {
      const std::uint64_t t = kT0 + static_cast<std::uint64_t>(i) * kJointPeriod;
      writer.write_message(joints, static_cast<std::uint32_t>(i), t, t, bytes_of(json{{"i", i}}.dump()));
      if (i % 25 == 0) writer.write_message(events, static_cast<std::uint32_t>(i / 25), t, t, bytes_of("{}"));
    }
    writer.close();
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::filesystem::path dir_, path_;
};

// Every published joint state with its arrival time, seen from the source's ready callback (called by
// the playback thread after each message, so none is coalesced away).
struct Collector {
  std::mutex mutex;
  std::vector<std::pair<Clock::time_point, int>> joints;
  std::uint64_t version = 0;
  void attach(SessionReplay& replay) {
    replay.set_ready_callback([this, &replay] {
      const auto now = Clock::now();
      std::lock_guard lock(mutex);
      if (const auto m = replay.latest("/srmc/joint_states", version)) {
        version = m->version;
        joints.emplace_back(now, json::parse(*m->payload).at("i").get<int>());
      }
    });
  }
  std::size_t size() {
    std::lock_guard lock(mutex);
    return joints.size();
  }
};

bool wait_for(const std::function<bool()>& done, std::chrono::seconds limit) {
  const auto deadline = Clock::now() + limit;
  while (Clock::now() < deadline) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return done();
}

TEST_F(SessionReplayTest, AdvertisesTheRecordedTopicsWithTheirSchemasAndAStatusTopic) {
  SessionReplay replay(path_);
  const auto topics = replay.topics();
  ASSERT_EQ(topics.size(), 3U);
  EXPECT_EQ(topics[0].topic, "/srmc/joint_states");
  EXPECT_EQ(topics[0].schema_name, "tendril.JointState");
  EXPECT_EQ(topics[0].schema_encoding, "jsonschema");
  EXPECT_EQ(topics[0].encoding, "json");
  EXPECT_EQ(topics[0].schema, R"({"type":"object"})");
  EXPECT_EQ(topics[1].topic, "/safety/events");
  EXPECT_EQ(topics[2].topic, SessionReplay::kStatusTopic);
  EXPECT_EQ(topics[2].schema_name, "tendril.ReplayStatus");
  const auto status = replay.status();
  EXPECT_EQ(status.start_ns, kT0);
  EXPECT_EQ(status.end_ns, kT0 + 100 * kJointPeriod);
  const auto rest = replay.replay_status();
  ASSERT_TRUE(rest.ok());
  EXPECT_EQ(rest.body.at("files").size(), 1U);
  EXPECT_EQ(rest.body.at("files")[0].at("messages"), kJoints + 5);
  EXPECT_TRUE(rest.body.at("files")[0].at("finalised").get<bool>());
}

TEST_F(SessionReplayTest, ReplaysEveryMessageInOrderAtTheRecordedPaceTimesTheRate) {
  ReplayOptions options;
  options.start_playing = false;
  SessionReplay replay(path_, options);
  Collector seen;
  seen.attach(replay);
  replay.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(seen.size(), 0U) << "paused at the start: nothing is replayed";

  for (const double rate : {1.0, 2.0}) {
    {
      std::lock_guard lock(seen.mutex);
      seen.joints.clear();
    }
    replay.seek(kT0);
    replay.set_rate(rate);
    const auto started = Clock::now();
    replay.set_playing(true);
    ASSERT_TRUE(wait_for([&] { return replay.status().ended; }, std::chrono::seconds(30))) << rate;
    std::lock_guard lock(seen.mutex);
    ASSERT_EQ(seen.joints.size(), static_cast<std::size_t>(kJoints)) << rate;
    for (int i = 0; i < kJoints; ++i) {
      ASSERT_EQ(seen.joints[static_cast<std::size_t>(i)].second, i) << "rate " << rate;
      // Never early: message i is due (i × 20 ms) / rate after play.
      const double due_s = i * 0.020 / rate;
      const double at_s =
          std::chrono::duration<double>(seen.joints[static_cast<std::size_t>(i)].first - started).count();
      ASSERT_GE(at_s, due_s - 0.001) << "message " << i << " at rate " << rate;
    }
    const double span_s = std::chrono::duration<double>(seen.joints.back().first - started).count();
    std::printf("rate %.0f: %d joint states replayed over %.3f s (recorded: 2 s; due: %.3f s)\n", rate,
                kJoints, span_s, 2.0 / rate);
    EXPECT_GE(span_s, 2.0 / rate - 0.001) << rate;
    EXPECT_LT(span_s, 2.0 / rate + 3.0) << rate;  // generous: a loaded machine is late, not early
    const auto status = replay.status();
    EXPECT_FALSE(status.playing);
    EXPECT_EQ(status.position_ns, status.end_ns);
    EXPECT_DOUBLE_EQ(status.rate, rate);
  }
  const auto status = replay.latest(SessionReplay::kStatusTopic, 0);
  ASSERT_TRUE(status);
  const json j = json::parse(*status->payload);
  EXPECT_TRUE(j.at("ended").get<bool>());
  EXPECT_EQ(j.at("messages_sent").get<std::uint64_t>(), 2U * (kJoints + 5));
}

TEST_F(SessionReplayTest, ASeekPublishesTheStateThereAndPlayContinuesFromIt) {
  ReplayOptions options;
  options.start_playing = false;
  SessionReplay replay(path_, options);
  Collector seen;
  seen.attach(replay);
  replay.start();
  replay.seek(kT0 + 50 * kJointPeriod);  // 1 s in, paused
  ASSERT_TRUE(wait_for([&] { return seen.size() >= 1; }, std::chrono::seconds(20)));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  {
    std::lock_guard lock(seen.mutex);
    ASSERT_EQ(seen.joints.size(), 1U) << "paused: only the state at the position";
    EXPECT_EQ(seen.joints.front().second, 49) << "the last joint state before the seek position";
  }
  replay.set_rate(10);
  replay.set_playing(true);
  ASSERT_TRUE(wait_for([&] { return seen.size() >= 10; }, std::chrono::seconds(20)));
  replay.set_playing(false);
  const auto held = replay.status().position_ns;
  const auto count = seen.size();
  std::this_thread::sleep_for(std::chrono::milliseconds(150));
  EXPECT_EQ(replay.status().position_ns, held);
  EXPECT_LE(seen.size(), count + 1);  // at most the one being published when paused
  std::lock_guard lock(seen.mutex);
  for (std::size_t i = 1; i < seen.joints.size(); ++i) {
    EXPECT_EQ(seen.joints[i].second, 49 + static_cast<int>(i)) << "played on from the seek position";
  }
}

TEST_F(SessionReplayTest, RefusesBadControlsWithAMessageAndChangesNothing) {
  ReplayOptions options;
  options.start_playing = false;
  SessionReplay replay(path_, options);
  const auto end = kT0 + 100 * kJointPeriod;
  const std::vector<json> bad = {
      json::array(),
      json::object(),
      {{"speed", 2}},
      {{"rate", -1}},
      {{"rate", 0.05}},
      {{"rate", 10.5}},
      {{"rate", "fast"}},
      {{"rate", std::nan("")}},
      {{"rate", true}},
      {{"playing", 1}},
      {{"position_ns", -5}},
      {{"position_ns", 1.5e18}},
      {{"position_ns", end + 1'000'001}},  // within 1 ms of the span is its edge (JavaScript's precision)
      {{"position_ns", kT0 - 1'000'001}},
      {{"position_ns", kT0}, {"rate", 0}},  // all or nothing: the valid seek is not applied either
  };
  for (const auto& body : bad) {
    const auto result = replay.control_replay(body);
    EXPECT_EQ(result.status, 400) << body.dump();
    EXPECT_EQ(result.code, "bad_replay_control") << body.dump();
    EXPECT_FALSE(result.message.empty());
  }
  EXPECT_EQ(replay.status().position_ns, kT0);
  EXPECT_DOUBLE_EQ(replay.status().rate, 1.0);
  EXPECT_THROW(replay.set_rate(0), std::invalid_argument);
  EXPECT_THROW(replay.seek(end + 1), std::invalid_argument);
  const auto edge = replay.control_replay({{"position_ns", end + 1000}});
  ASSERT_TRUE(edge.ok()) << edge.message;
  EXPECT_EQ(edge.body.at("position_ns").get<std::uint64_t>(), end);

  const auto ok =
      replay.control_replay({{"playing", false}, {"rate", 0.5}, {"position_ns", kT0 + 1'000'000'000}});
  ASSERT_TRUE(ok.ok()) << ok.message;
  EXPECT_EQ(ok.body.at("position_ns").get<std::uint64_t>(), kT0 + 1'000'000'000);
  EXPECT_DOUBLE_EQ(ok.body.at("rate").get<double>(), 0.5);
  EXPECT_FALSE(ok.body.at("playing").get<bool>());
}

TEST_F(SessionReplayTest, ACutRecordingReplaysAndADamagedOneIsRefused) {
  // A copy cut in the middle of its last chunk, as SIGKILL leaves a file.
  const auto size = std::filesystem::file_size(path_);
  std::filesystem::copy_file(path_, dir_ / "cut.mcap");
  std::filesystem::resize_file(dir_ / "cut.mcap", size / 2);
  std::filesystem::remove(path_);
  {
    SessionReplay replay(dir_);
    EXPECT_GT(replay.status().end_ns, kT0);
    EXPECT_FALSE(replay.replay_status().body.at("files")[0].at("finalised").get<bool>());
  }
  std::ofstream(dir_ / "cut.mcap", std::ios::trunc) << "not a recording";
  EXPECT_THROW(SessionReplay{dir_}, record::McapFormatError);
  EXPECT_THROW(SessionReplay{dir_ / "missing"}, record::McapError);
}

}  // namespace
}  // namespace tendril::server
