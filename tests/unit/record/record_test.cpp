// McapWriter and Recorder, read back with the test reader in mcap_reader.hpp (written from the
// specification, independently of the writer; the independent @mcap/core check is tests/record/).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "mcap_reader.hpp"
#include "tendril/record/crc32.hpp"
#include "tendril/record/mcap_writer.hpp"
#include "tendril/record/recorder.hpp"

namespace tendril::record {
namespace {

using test::read_mcap;
using test::read_mcap_bytes;

std::vector<std::uint8_t> bytes_of(std::string_view s) { return {s.begin(), s.end()}; }

// A fresh directory per test (gtest_discover_tests runs each test in its own process).
class RecordTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string(info->test_suite_name()) + "-" + info->name();
    std::replace(name.begin(), name.end(), '/', '-');
    dir_ = std::filesystem::temp_directory_path() /
           ("tendril-record-" + std::to_string(::getpid()) + "-" + name);
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path dir_;
};

// A joint-state-like JSON text (compressible) and a deterministic payload of a given size for channel
// c, message i, so a reader can check every byte.
std::vector<std::uint8_t> joint_state(std::uint64_t i) {
  return bytes_of(R"({"position":[)" + std::to_string(i * 0.001) +
                  R"(,0.25,-1.5,3.0],"velocity":[0,0,0,0]})");
}
std::vector<std::uint8_t> payload(std::uint32_t c, std::uint64_t i, std::size_t size) {
  std::vector<std::uint8_t> v(size);
  std::mt19937 rng(static_cast<std::uint32_t>(c * 100003 + i));
  for (std::size_t k = 0; k < size; ++k) v[k] = static_cast<std::uint8_t>(k % 64 < 32 ? rng() : k);
  return v;
}

TEST(Crc32, MatchesTheStandardCheckValueAndExtends) {
  const auto check = bytes_of("123456789");
  EXPECT_EQ(crc32(check), 0xCBF43926U);  // the CRC-32/ISO-HDLC check value
  EXPECT_EQ(crc32({}), 0U);
  const auto long_text =
      bytes_of("The quick brown fox jumps over the lazy dog, twice over for slicing-by-8.");
  const std::span<const std::uint8_t> all(long_text);
  for (std::size_t cut = 0; cut <= all.size(); ++cut) {
    EXPECT_EQ(crc32(all.subspan(cut), crc32(all.first(cut))), crc32(all)) << cut;
  }
  EXPECT_EQ(crc32(bytes_of("The quick brown fox jumps over the lazy dog")), 0x414FA339U);
}

class WriterRoundTrip : public RecordTest, public ::testing::WithParamInterface<Compression> {};

TEST_P(WriterRoundTrip, EveryMessageComesBackWithValidCrcsAndIndexes) {
  const auto path = dir_ / "round_trip.mcap";
  McapWriterOptions options;
  options.compression = GetParam();
  options.chunk_size = 64 * 1024;
  options.profile = "";
  options.library = "tendril-record-test";
  McapWriter writer(path, options);
  const auto schema = writer.add_schema("tendril.JointState", "jsonschema", bytes_of(R"({"type":"object"})"));
  const auto joints = writer.add_channel(schema, "/robot/joint_states", "json", {{"robot", "srmc"}});
  const auto image = writer.add_channel(0, "/imaging/ap", "jpeg-bytes");
  constexpr std::uint64_t kJoint = 600, kImage = 12;
  std::uint64_t t = 1'000'000'000;
  std::uint64_t images = 0;
  for (std::uint64_t i = 0; i < kJoint; ++i, t += 1'000'000) {
    writer.write_message(joints, static_cast<std::uint32_t>(i), t, t, joint_state(i));
    if (i % 50 == 0 && images < kImage) {
      writer.write_message(image, static_cast<std::uint32_t>(images), t, t + 7, payload(2, images, 150'000));
      ++images;
    }
  }
  writer.close();
  EXPECT_FALSE(writer.is_open());
  EXPECT_EQ(writer.stats().messages, kJoint + kImage);
  EXPECT_EQ(writer.stats().flushed_messages, kJoint + kImage);
  EXPECT_EQ(writer.stats().bytes, std::filesystem::file_size(path));

  const auto file = read_mcap(path);
  ASSERT_TRUE(file.complete);
  EXPECT_EQ(file.library, "tendril-record-test");
  ASSERT_EQ(file.messages.size(), kJoint + kImage);
  EXPECT_EQ(file.statistics_channel_counts.at(joints), kJoint);
  EXPECT_EQ(file.statistics_channel_counts.at(image), kImage);
  EXPECT_EQ(file.schemas.at(schema).name, "tendril.JointState");
  EXPECT_EQ(file.channels.at(joints).schema_id, schema);
  EXPECT_EQ(file.channels.at(image).schema_id, 0);
  std::uint64_t next_joint = 0, next_image = 0;
  for (const auto& m : file.messages) {
    if (m.channel_id == joints) {
      EXPECT_EQ(m.sequence, next_joint);
      EXPECT_EQ(m.data, joint_state(next_joint));
      EXPECT_EQ(m.log_time, 1'000'000'000 + next_joint * 1'000'000);
      ++next_joint;
    } else {
      EXPECT_EQ(m.sequence, next_image);
      EXPECT_EQ(m.publish_time, m.log_time + 7);
      EXPECT_EQ(m.data, payload(2, next_image, 150'000));
      ++next_image;
    }
  }
  EXPECT_GT(file.chunk_compressions.size(), 3U);
  // The joint states compress, so with a compressor at least one chunk is stored compressed.
  const std::string name(compression_name(GetParam()));
  EXPECT_TRUE(std::count(file.chunk_compressions.begin(), file.chunk_compressions.end(), name) > 0) << name;
}

INSTANTIATE_TEST_SUITE_P(AllCompressions, WriterRoundTrip,
                         ::testing::Values(Compression::kNone, Compression::kZstd, Compression::kLz4),
                         [](const auto& info) {
                           return info.param == Compression::kNone
                                      ? std::string("none")
                                      : std::string(compression_name(info.param));
                         });

TEST_F(RecordTest, AChunkThatDoesNotShrinkIsStoredUncompressed) {
  const auto path = dir_ / "random.mcap";
  McapWriter writer(path, McapWriterOptions{});  // zstd
  const auto ch = writer.add_channel(0, "/noise", "bytes");
  std::mt19937 rng(7);
  std::vector<std::uint8_t> noise(200'000);
  for (auto& b : noise) b = static_cast<std::uint8_t>(rng());
  writer.write_message(ch, 0, 5, 5, noise);
  writer.close();
  const auto file = read_mcap(path);
  ASSERT_EQ(file.chunk_compressions.size(), 1U);
  EXPECT_EQ(file.chunk_compressions[0], "");
  ASSERT_EQ(file.messages.size(), 1U);
  EXPECT_EQ(file.messages[0].data, noise);
}

// What SIGKILL leaves: the bytes on disk at any moment. Every prefix of a file that was never closed
// reads as exactly the messages of the chunks complete within it.
TEST_F(RecordTest, AFileCutAnywhereReadsUpToItsLastCompleteChunk) {
  const auto path = dir_ / "cut.mcap";
  McapWriterOptions options;
  options.chunk_size = 4096;
  McapWriter writer(path, options);
  const auto ch = writer.add_channel(0, "/robot/joint_states", "json");
  std::vector<std::uint64_t> flushed_after;  // file size -> messages safe, after each chunk
  std::vector<std::uint64_t> size_after;
  for (std::uint64_t i = 0; i < 400; ++i) {
    const auto chunks = writer.stats().chunks;
    writer.write_message(ch, static_cast<std::uint32_t>(i), i, i, joint_state(i));
    if (writer.stats().chunks != chunks) {
      size_after.push_back(writer.stats().bytes);
      flushed_after.push_back(writer.stats().flushed_messages);
    }
  }
  ASSERT_GE(size_after.size(), 5U);
  std::ifstream in(path, std::ios::binary);
  const std::vector<std::uint8_t> on_disk((std::istreambuf_iterator<char>(in)),
                                          std::istreambuf_iterator<char>());
  // Nothing but complete chunks has reached the file (the open chunk is still in memory).
  EXPECT_EQ(on_disk.size(), size_after.back());
  for (std::size_t cut = 8; cut <= on_disk.size(); cut += 97) {
    const std::vector<std::uint8_t> prefix(on_disk.begin(),
                                           on_disk.begin() + static_cast<std::ptrdiff_t>(cut));
    const auto file = read_mcap_bytes(prefix);
    EXPECT_FALSE(file.complete);
    // A chunk counts once its Chunk record is whole; the Message Index after it (one channel here:
    // 15 bytes + 16 per message) is an index, not data.
    std::uint64_t expected = 0;
    for (std::size_t k = 0; k < size_after.size(); ++k) {
      const std::uint64_t in_chunk = flushed_after[k] - (k > 0 ? flushed_after[k - 1] : 0);
      if (size_after[k] - (15 + 16 * in_chunk) <= cut) expected = flushed_after[k];
    }
    ASSERT_EQ(file.messages.size(), expected) << "cut at " << cut;
    for (std::size_t i = 0; i < file.messages.size(); ++i) EXPECT_EQ(file.messages[i].sequence, i);
  }
  writer.close();
  EXPECT_TRUE(read_mcap(path).complete);
}

TEST_F(RecordTest, WriterRefusesWrongUseWithClearErrors) {
  const auto path = dir_ / "once.mcap";
  McapWriter writer(path, McapWriterOptions{});
  EXPECT_THROW(writer.write_message(1, 0, 0, 0, {}), McapError);   // no channel yet
  EXPECT_THROW(writer.add_channel(3, "/x", "json"), McapError);    // no such schema
  EXPECT_THROW(McapWriter(path, McapWriterOptions{}), McapError);  // never overwrites
  McapWriterOptions bad;
  bad.chunk_size = 0;
  EXPECT_THROW(McapWriter(dir_ / "bad.mcap", bad), std::invalid_argument);
  bad.chunk_size = 1024;
  bad.zstd_level = 99;
  EXPECT_THROW(McapWriter(dir_ / "bad.mcap", bad), std::invalid_argument);
  EXPECT_THROW(parse_compression("gzip"), std::invalid_argument);
  EXPECT_EQ(parse_compression("lz4"), Compression::kLz4);
  writer.close();
  EXPECT_THROW(writer.add_channel(0, "/x", "json"), McapError);
}

ChannelSpec joint_spec() {
  return ChannelSpec{"/robot/joint_states",
                     "json",
                     "tendril.JointState",
                     "jsonschema",
                     bytes_of(R"({"type":"object"})"),
                     {}};
}

TEST_F(RecordTest, RecorderRotatesBySizeIntoSeveralCompleteFiles) {
  RecorderOptions options;
  options.directory = dir_;
  options.writer.chunk_size = 16 * 1024;
  options.max_file_bytes = 100 * 1024;
  options.queue_capacity = 1024;
  Recorder recorder(options);
  const auto joints = recorder.add_channel(joint_spec());
  const auto image = recorder.add_channel(ChannelSpec{"/imaging/ap", "jpeg-bytes", "", "", {}, {}});
  // Queued before start, so none can be dropped whatever the machine's speed.
  constexpr std::uint64_t kJoint = 900, kImage = 9;
  for (std::uint64_t i = 0; i < kJoint; ++i) {
    ASSERT_TRUE(recorder.record(joints, i * 1'000'000, joint_state(i)));
    if (i % 100 == 0) {
      ASSERT_TRUE(recorder.record(image, i * 1'000'000, payload(1, i / 100, 60'000)));
    }
  }
  recorder.start();
  recorder.stop();
  const auto stats = recorder.stats();
  EXPECT_EQ(stats.dropped, 0U);
  EXPECT_EQ(stats.written, kJoint + kImage);
  EXPECT_EQ(stats.flushed, kJoint + kImage);
  EXPECT_TRUE(stats.error.empty()) << stats.error;
  const auto files = recorder.files();
  ASSERT_GE(files.size(), 3U);
  EXPECT_EQ(stats.files, files.size());
  std::uint64_t joint_seen = 0, image_seen = 0, bytes = 0;
  for (std::size_t f = 0; f < files.size(); ++f) {
    const std::string name = files[f].filename().string();
    EXPECT_EQ(name.rfind("tendril_", 0), 0U) << name;
    EXPECT_NE(name.find("_" + std::string(f < 10 ? "000" : "00") + std::to_string(f) + ".mcap"),
              std::string::npos)
        << name;
    const auto file = read_mcap(files[f]);
    ASSERT_TRUE(file.complete) << name;
    // Size bound: the limit, overshot by at most the open chunk and the summary.
    bytes += std::filesystem::file_size(files[f]);
    EXPECT_LE(std::filesystem::file_size(files[f]), options.max_file_bytes + 2 * options.writer.chunk_size)
        << name;
    EXPECT_EQ(file.metadata.at("tendril.recorder").at("file_index"), std::to_string(f));
    for (const auto& m : file.messages) {
      if (m.topic == "/robot/joint_states") {
        EXPECT_EQ(m.sequence, joint_seen);  // continuous across files
        EXPECT_EQ(m.data, joint_state(joint_seen));
        ++joint_seen;
      } else {
        EXPECT_EQ(m.data, payload(1, image_seen, 60'000));
        ++image_seen;
      }
    }
  }
  EXPECT_EQ(joint_seen, kJoint);
  EXPECT_EQ(image_seen, kImage);
  EXPECT_EQ(bytes, stats.bytes);
}

TEST_F(RecordTest, RecorderRotatesByLogTimeDuration) {
  RecorderOptions options;
  options.directory = dir_;
  options.max_file_duration_ns = 1'000'000'000;  // 1 s of log time per file
  Recorder recorder(options);
  const auto joints = recorder.add_channel(joint_spec());
  // 3.5 s of messages every 100 ms: files [0, 1), [1, 2), [2, 3), [3, 3.5].
  for (std::uint64_t i = 0; i < 36; ++i)
    ASSERT_TRUE(recorder.record(joints, 5'000'000'000 + i * 100'000'000, joint_state(i)));
  recorder.start();
  recorder.stop();
  const auto files = recorder.files();
  ASSERT_EQ(files.size(), 4U);
  const std::vector<std::size_t> counts{10, 10, 10, 6};
  for (std::size_t f = 0; f < files.size(); ++f) {
    const auto file = read_mcap(files[f]);
    ASSERT_TRUE(file.complete);
    ASSERT_EQ(file.messages.size(), counts[f]);
    EXPECT_EQ(file.messages.front().log_time, 5'000'000'000 + f * 1'000'000'000);
    EXPECT_LT(file.messages.back().log_time - file.messages.front().log_time, options.max_file_duration_ns);
    // Each file stands alone: its own schema and channel records.
    EXPECT_EQ(file.channels.size(), 1U);
    EXPECT_EQ(file.schemas.size(), 1U);
  }
}

// With max_chunk_delay 0 every message is its own chunk, written at once: what stats() reports as
// flushed is on disk, readable without a footer, while the recorder still runs.
TEST_F(RecordTest, FlushedMessagesAreReadableWhileTheRecorderRuns) {
  RecorderOptions options;
  options.directory = dir_;
  options.max_chunk_delay = std::chrono::milliseconds(0);
  Recorder recorder(options);
  const auto joints = recorder.add_channel(joint_spec());
  recorder.start();
  for (std::uint64_t i = 0; i < 25; ++i) ASSERT_TRUE(recorder.record(joints, i, joint_state(i)));
  while (recorder.stats().flushed < 25) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  const auto running = read_mcap(recorder.files().at(0));
  EXPECT_FALSE(running.complete);
  ASSERT_EQ(running.messages.size(), 25U);
  EXPECT_EQ(running.chunk_compressions.size(), 25U);  // one chunk per message
  for (std::uint32_t i = 0; i < 25; ++i) EXPECT_EQ(running.messages[i].data, joint_state(i));
  recorder.stop();
  const auto finished = read_mcap(recorder.files().at(0));
  EXPECT_TRUE(finished.complete);
  EXPECT_EQ(finished.messages.size(), 25U);
}

TEST_F(RecordTest, QueueOverflowIsCountedPerChannelAndShowsAsSequenceGaps) {
  RecorderOptions options;
  options.directory = dir_;
  options.queue_capacity = 8;
  std::vector<std::string> lines;
  options.log = [&lines](std::string_view line) { lines.emplace_back(line); };
  Recorder recorder(options);
  const auto joints = recorder.add_channel(joint_spec());
  // Nothing drains before start(): the ninth message onwards finds the queue full.
  std::size_t kept = 0;
  for (std::uint64_t i = 0; i < 20; ++i) kept += recorder.record(joints, i, joint_state(i)) ? 1 : 0;
  EXPECT_EQ(kept, 8U);
  EXPECT_EQ(recorder.stats().dropped, 12U);
  EXPECT_EQ(recorder.dropped(joints), 12U);
  EXPECT_EQ(recorder.stats().queue_high_water, 8U);
  recorder.start();
  recorder.stop();
  ASSERT_EQ(recorder.files().size(), 1U);
  const auto file = read_mcap(recorder.files()[0]);
  ASSERT_EQ(file.messages.size(), 8U);
  for (std::uint32_t i = 0; i < 8; ++i) EXPECT_EQ(file.messages[i].sequence, i);
  const auto& meta = file.metadata.at("tendril.recorder");
  EXPECT_EQ(meta.at("dropped_total"), "12");
  EXPECT_EQ(meta.at("dropped:/robot/joint_states"), "12");
  EXPECT_EQ(meta.at("messages"), "8");
  // And the log says so.
  EXPECT_TRUE(std::any_of(lines.begin(), lines.end(), [](const std::string& l) {
    return l.find("dropped 12 messages") != std::string::npos;
  }));
  // After stop() nothing is taken, and that is counted too.
  EXPECT_FALSE(recorder.record(joints, 99, joint_state(99)));
  EXPECT_EQ(recorder.stats().dropped, 13U);
}

// record(shared_ptr): the publisher's serialised payload is held, not copied, until written.
TEST_F(RecordTest, SharedPayloadsAreWrittenAndReleased) {
  RecorderOptions options;
  options.directory = dir_;
  options.queue_max_bytes = 1000;
  Recorder recorder(options);
  const auto joints = recorder.add_channel(joint_spec());
  const auto text = joint_state(3);
  auto payload = std::make_shared<const std::string>(text.begin(), text.end());
  EXPECT_TRUE(recorder.record(joints, 10, payload));
  EXPECT_EQ(payload.use_count(), 2);                                               // the queue holds it
  EXPECT_TRUE(recorder.record(joints, 11, std::shared_ptr<const std::string>{}));  // null: empty message
  auto big = std::make_shared<const std::string>(2000, 'x');
  EXPECT_FALSE(recorder.record(joints, 12, big));  // the byte budget counts shared payloads too
  EXPECT_EQ(big.use_count(), 1);
  recorder.start();
  recorder.stop();
  EXPECT_EQ(payload.use_count(), 1);  // released once written
  const auto file = read_mcap(recorder.files().at(0));
  ASSERT_EQ(file.messages.size(), 2U);
  EXPECT_EQ(file.messages[0].data, text);
  EXPECT_TRUE(file.messages[1].data.empty());
  EXPECT_EQ(recorder.dropped(joints), 1U);
}

TEST_F(RecordTest, QueueByteBudgetDropsLargeMessages) {
  RecorderOptions options;
  options.directory = dir_;
  options.queue_max_bytes = 1000;
  Recorder recorder(options);
  const auto image = recorder.add_channel(ChannelSpec{"/imaging/ap", "jpeg-bytes", "", "", {}, {}});
  EXPECT_TRUE(recorder.record(image, 1, payload(0, 1, 400)));
  EXPECT_TRUE(recorder.record(image, 2, payload(0, 2, 400)));
  EXPECT_FALSE(recorder.record(image, 3, payload(0, 3, 400)));  // 1200 > 1000 bytes waiting
  EXPECT_TRUE(recorder.record(image, 4, payload(0, 4, 150)));
  EXPECT_EQ(recorder.dropped(image), 1U);
  recorder.start();
  recorder.stop();
  const auto file = read_mcap(recorder.files().at(0));
  ASSERT_EQ(file.messages.size(), 3U);
  EXPECT_EQ(file.messages[2].sequence, 3U);  // sequence 2 was the dropped one
}

TEST_F(RecordTest, RecorderRefusesBadSetUpAndUnknownChannels) {
  RecorderOptions options;
  EXPECT_THROW(Recorder{options}, std::invalid_argument);  // no directory
  options.directory = dir_;
  options.queue_capacity = 1;
  EXPECT_THROW(Recorder{options}, std::invalid_argument);
  options.queue_capacity = 16;
  options.max_channels = 1;
  Recorder recorder(options);
  EXPECT_THROW(recorder.add_channel(ChannelSpec{}), std::invalid_argument);  // no topic
  const auto joints = recorder.add_channel(joint_spec());
  EXPECT_THROW(recorder.add_channel(joint_spec()), std::invalid_argument);  // past max_channels
  EXPECT_FALSE(recorder.record(joints + 1, 0, std::span<const std::uint8_t>{}));
  recorder.stop();  // never started: no file
  EXPECT_TRUE(recorder.files().empty());
}

// Several producer threads at once, with a queue small enough to overflow: every message is either
// in the file, intact and in its channel's order, or counted as dropped.
TEST_F(RecordTest, ConcurrentProducersLoseNothingUncounted) {
  RecorderOptions options;
  options.directory = dir_;
  options.queue_capacity = 64;
  options.writer.chunk_size = 16 * 1024;
  Recorder recorder(options);
  constexpr int kThreads = 4;
  constexpr std::uint64_t kEach = 3000;
  std::vector<Recorder::ChannelId> channels;
  for (int t = 0; t < kThreads; ++t) {
    channels.push_back(
        recorder.add_channel(ChannelSpec{"/producer/" + std::to_string(t), "bytes", "", "", {}, {}}));
  }
  recorder.start();
  std::vector<std::thread> producers;
  std::atomic<std::uint64_t> refused{0};
  for (int t = 0; t < kThreads; ++t) {
    producers.emplace_back([&, t] {
      for (std::uint64_t i = 0; i < kEach; ++i) {
        if (!recorder.record(channels[t], i, payload(static_cast<std::uint32_t>(t), i, 200)))
          refused.fetch_add(1);
      }
    });
  }
  for (auto& p : producers) p.join();
  recorder.stop();
  const auto stats = recorder.stats();
  EXPECT_EQ(stats.dropped, refused.load());
  EXPECT_EQ(stats.written + stats.dropped, kThreads * kEach);
  const auto file = read_mcap(recorder.files().at(0));
  ASSERT_EQ(file.messages.size(), stats.written);
  std::vector<std::int64_t> last(kThreads, -1);
  std::uint64_t dropped_seen = 0;
  for (const auto& m : file.messages) {
    const int t = std::stoi(m.topic.substr(std::string("/producer/").size()));
    EXPECT_GT(static_cast<std::int64_t>(m.sequence), last[t]);
    dropped_seen += m.sequence - static_cast<std::uint64_t>(last[t] + 1);
    last[t] = m.sequence;
    EXPECT_EQ(m.log_time, m.sequence);
    EXPECT_EQ(m.data, payload(static_cast<std::uint32_t>(t), m.sequence, 200));
  }
  for (int t = 0; t < kThreads; ++t) dropped_seen += kEach - 1 - static_cast<std::uint64_t>(last[t]);
  EXPECT_EQ(dropped_seen, stats.dropped);  // every drop is a gap in the sequence numbers
}

}  // namespace
}  // namespace tendril::record
