// Recorder retention (keep_total_bytes, keep_age): after each rotation the oldest finished files of the
// recorder's prefix beyond the budget are deleted, never the open one and never a file of another name.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "tendril/record/recorder.hpp"

namespace tendril::record {
namespace {

class RetentionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("tendril-retention-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  void put(const std::string& name, std::size_t bytes) {
    std::ofstream(dir_ / name, std::ios::binary) << std::string(bytes, 'x');
  }
  bool has(const std::string& name) const { return std::filesystem::exists(dir_ / name); }
  std::vector<std::string> recordings() const {
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(dir_)) {
      const auto n = e.path().filename().string();
      if (n.rfind("tendril_2", 0) == 0) names.push_back(n);
    }
    std::sort(names.begin(), names.end());
    return names;
  }
  std::uint64_t recording_bytes() const {
    std::uint64_t total = 0;
    for (const auto& n : recordings()) total += std::filesystem::file_size(dir_ / n);
    return total;
  }

  // ~200 KB of 2 KB messages over 2 s of log time; with 40 KB files that is five or six rotations.
  RecorderStats record(RecorderOptions options, std::vector<std::string>* log = nullptr) {
    options.directory = dir_;
    options.writer.compression = Compression::kNone;
    options.writer.chunk_size = 8 * 1024;
    options.max_file_bytes = 40 * 1024;
    if (log) options.log = [log](std::string_view line) { log->emplace_back(line); };
    Recorder recorder(options);
    const auto channel = recorder.add_channel(ChannelSpec{"/imaging/ap", "json", "", "", {}, {}});
    const std::vector<std::uint8_t> payload(2000, 'i');
    for (int i = 0; i < 100; ++i)
      EXPECT_TRUE(recorder.record(channel, static_cast<std::uint64_t>(i) * 20'000'000, payload));
    recorder.start();
    recorder.stop();
    started_ = recorder.files();
    return recorder.stats();
  }

  std::filesystem::path dir_;
  std::vector<std::filesystem::path> started_;  // the files the last recorder started
};

TEST_F(RetentionTest, TheOldestFinishedFilesGoFirstUntilTheRecordingsFitTheBudget) {
  // Earlier sessions' files (oldest by name), and files that are not this recorder's.
  put("tendril_20200101T000000Z_0000.mcap", 30'000);
  put("tendril_20200101T000000Z_0001.mcap", 30'000);
  put("tendril_20210101T000000Z_0000.mcap", 30'000);
  put("notes.mcap", 50'000);
  put("tendril_export.mcap", 50'000);
  put("other_20200101T000000Z_0000.mcap", 50'000);
  RecorderOptions options;
  options.keep_total_bytes = 100 * 1024;
  std::vector<std::string> log;
  const auto stats = record(options, &log);
  EXPECT_TRUE(stats.error.empty()) << stats.error;
  EXPECT_GE(stats.files, 5U);
  // The old sessions' files went first, oldest first.
  EXPECT_FALSE(has("tendril_20200101T000000Z_0000.mcap"));
  EXPECT_FALSE(has("tendril_20200101T000000Z_0001.mcap"));
  EXPECT_FALSE(has("tendril_20210101T000000Z_0000.mcap"));
  EXPECT_TRUE(has("notes.mcap"));
  EXPECT_TRUE(has("tendril_export.mcap"));
  EXPECT_TRUE(has("other_20200101T000000Z_0000.mcap"));
  // Within the budget at the last rotation; the last file then grew up to one file's size.
  EXPECT_LE(recording_bytes(), options.keep_total_bytes + 40 * 1024 + 2 * 8 * 1024);
  // The newest files are this session's, the last one started is there and whole.
  const auto left = recordings();
  ASSERT_FALSE(left.empty());
  ASSERT_FALSE(started_.empty());
  EXPECT_EQ(left.back(), started_.back().filename().string());
  EXPECT_EQ(stats.files_deleted, 3U + (stats.files - left.size()));
  EXPECT_TRUE(std::any_of(log.begin(), log.end(), [](const std::string& line) {
    return line.find("retention: deleted") != std::string::npos &&
           line.find("tendril_20200101T000000Z_0000.mcap") != std::string::npos;
  }));
}

TEST_F(RetentionTest, FilesOlderThanKeepAgeAreDeletedAndTheOpenFileNever) {
  put("tendril_20200101T000000Z_0000.mcap", 1000);
  put("tendril_20200101T000000Z_0001.mcap", 1000);
  const auto ten_days_ago = std::filesystem::file_time_type::clock::now() - std::chrono::hours(24 * 10);
  std::filesystem::last_write_time(dir_ / "tendril_20200101T000000Z_0000.mcap", ten_days_ago);
  RecorderOptions options;
  options.keep_age = std::chrono::hours(24 * 7);
  const auto stats = record(options);
  EXPECT_FALSE(has("tendril_20200101T000000Z_0000.mcap"));
  EXPECT_TRUE(has("tendril_20200101T000000Z_0001.mcap"));  // old by name, but written recently
  EXPECT_EQ(stats.files_deleted, 1U);
  EXPECT_EQ(recordings().size(), stats.files + 1);

  // A budget smaller than one file: every finished file goes at each rotation, the open one stays.
  std::filesystem::remove_all(dir_);
  std::filesystem::create_directories(dir_);
  RecorderOptions tiny;
  tiny.keep_total_bytes = 1;
  const auto tiny_stats = record(tiny);
  EXPECT_GE(tiny_stats.files, 5U);
  EXPECT_EQ(recordings().size(), 1U);
  EXPECT_EQ(tiny_stats.files_deleted, tiny_stats.files - 1);
}

}  // namespace
}  // namespace tendril::record
