// SessionRecording: the "recording" configuration and the publisher tap that records channels,
// messages and commands through tendril::record (the files are read back with the unit tests' own
// MCAP reader in tests/unit/record; here only what the tap decides and the configuration's mistakes).
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

#include "tendril/server/config.hpp"
#include "tendril/server/session_recording.hpp"

namespace tendril::server {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const fs::path kServerFile = "/etc/tendril/server.json";

TEST(RecordingConfig, DefaultsResolveAgainstTheServerFileAndMistakesNameTheKey) {
  EXPECT_FALSE(parse_recording_config(nullptr, kServerFile).enabled) << "no section: no recording";
  const auto c = parse_recording_config(json::object(), kServerFile);
  EXPECT_TRUE(c.enabled) << "a section turns it on";
  EXPECT_EQ(c.directory, fs::path("/etc/tendril/recordings"));
  EXPECT_EQ(c.compression, record::Compression::kZstd);
  EXPECT_EQ(c.max_file_bytes, std::uint64_t{1} << 30);
  EXPECT_EQ(c.max_file_duration_ns, 3600ULL * 1'000'000'000ULL);
  EXPECT_FALSE(c.images_always);
  const auto d = parse_recording_config({{"enabled", false},
                                         {"directory", "/data/rec"},
                                         {"compression", "lz4"},
                                         {"max_file_mb", 2},
                                         {"max_file_minutes", 0.5},
                                         {"images", "always"},
                                         {"keep_total_mb", 500},
                                         {"keep_days", 0.5}},
                                        kServerFile);
  EXPECT_EQ(d.keep_total_bytes, 500ULL * 1024 * 1024);
  EXPECT_EQ(d.keep_age, std::chrono::seconds(43200));
  EXPECT_EQ(c.keep_total_bytes, 0U) << "no retention unless asked";
  EXPECT_EQ(c.keep_age.count(), 0);
  EXPECT_FALSE(d.enabled);
  EXPECT_EQ(d.directory, fs::path("/data/rec"));
  EXPECT_EQ(d.compression, record::Compression::kLz4);
  EXPECT_EQ(d.max_file_bytes, 2u * 1024u * 1024u);
  EXPECT_EQ(d.max_file_duration_ns, 30'000'000'000ULL);
  EXPECT_TRUE(d.images_always);
  const auto refuses = [](const json& j, const std::string& words) {
    try {
      parse_recording_config(j, kServerFile);
      ADD_FAILURE() << "accepted " << j.dump();
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  refuses(json::array(), "recording: expected an object");
  refuses({{"enabled", "yes"}}, "recording.enabled");
  refuses({{"directory", ""}}, "recording.directory");
  refuses({{"compression", "gzip"}}, "recording.compression");
  refuses({{"max_file_mb", 0}}, "recording.max_file_mb");
  refuses({{"max_file_mb", std::nan("")}}, "recording.max_file_mb");
  refuses({{"max_file_minutes", -1}}, "recording.max_file_minutes");
  refuses({{"images", "sometimes"}}, "recording.images");
  refuses({{"topics", "all"}}, "recording.topics: unknown key");
  refuses({{"keep_total_mb", 0}}, "recording.keep_total_mb");
  refuses({{"keep_total_mb", "1G"}}, "recording.keep_total_mb");
  refuses({{"keep_days", 0}}, "recording.keep_days");
  refuses({{"keep_days", -3}}, "recording.keep_days");
  refuses({{"keep_days", std::nan("")}}, "recording.keep_days");
}

TEST(SessionRecording, RecordsAdvertisedChannelsAndCommandsAndWantsImagesOnlyWhenAskedTo) {
  const fs::path dir =
      fs::temp_directory_path() / ("tendril-session-recording-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  auto config = parse_recording_config({{"directory", dir.string()}, {"compression", "none"}}, kServerFile);
  {
    SessionRecording recording(config, nullptr);
    EXPECT_TRUE(recording.wants("/srmc/joint_states", false)) << "robot topics: always";
    EXPECT_FALSE(recording.wants("/imaging/ap", true)) << "images: while watched";
    EXPECT_TRUE(recording.wants("/imaging/segmentation", true)) << "segmentation parameters: always";
    recording.start();
    recording.channel(7, "/srmc/joint_states", "tendril.JointState", R"({"type":"object"})", "json",
                      "jsonschema");
    recording.message(7, 1000, std::make_shared<const std::string>(R"({"position":[1,2]})"));
    recording.message(8, 1001, std::make_shared<const std::string>("{}"));  // never advertised: ignored
    recording.command(1002, "srmc", "move_jp", "surgeon", {{"goal", {1, 2}}}, 202, "");
    recording.command(1003, "srmc", "servo_jv", "script", {{"velocity", {std::nan("")}}}, 400,
                      "bad_request: velocity[0] is not finite");
    recording.stop();
    const auto stats = recording.stats();
    EXPECT_EQ(stats.written, 3u) << "one message and two commands";
    EXPECT_EQ(stats.dropped, 0u);
    ASSERT_EQ(recording.files().size(), 1u);
    EXPECT_TRUE(fs::is_regular_file(recording.files()[0]));
    EXPECT_GT(fs::file_size(recording.files()[0]), 100u);
  }
  auto always = config;
  always.images_always = true;
  SessionRecording images(always, nullptr);
  EXPECT_TRUE(images.wants("/imaging/ap", true));
  images.stop();
  fs::remove_all(dir);
}

TEST(SessionRecording, ADirectoryThatCannotBeMadeIsAConfigurationError) {
  const fs::path file = fs::temp_directory_path() / ("tendril-not-a-dir-" + std::to_string(::getpid()));
  std::ofstream(file) << "x";
  auto config = parse_recording_config({{"directory", (file / "sub").string()}}, kServerFile);
  EXPECT_THROW(SessionRecording(config, nullptr), ConfigError);
  fs::remove(file);
}

}  // namespace
}  // namespace tendril::server
