// McapReader and McapMessageCursor against files the McapWriter and the Recorder write: each
// compression, finalised and cut (every prefix), rotated sets merged in log-time order, seeking, and
// damaged files refused with McapFormatError.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "tendril/record/mcap_reader.hpp"
#include "tendril/record/mcap_writer.hpp"
#include "tendril/record/recorder.hpp"

namespace tendril::record {
namespace {

std::vector<std::uint8_t> bytes_of(std::string_view s) { return {s.begin(), s.end()}; }

std::vector<std::uint8_t> file_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::vector<std::uint8_t> joint_state(std::uint64_t i) {
  return bytes_of(R"({"position":[)" + std::to_string(i) + R"(,0.25,-1.5,3.0],"velocity":[0,0,0,0]})");
}

class McapReaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string(info->test_suite_name()) + "-" + info->name();
    std::replace(name.begin(), name.end(), '/', '-');
    dir_ = std::filesystem::temp_directory_path() /
           ("tendril-mcap-reader-" + std::to_string(::getpid()) + "-" + name);
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  // Two channels: joint states every 1 ms and an event every 10 ms, written 3 ms *late* (log time
  // earlier than the joint state written before it), so chunks hold messages out of log-time order
  // as a recorder fed by several threads does.
  struct Written {
    std::uint16_t joints = 0, events = 0;
    std::uint64_t count = 0;
  };
  Written write_file(const std::filesystem::path& path, Compression compression, std::size_t chunk_size,
                     std::uint64_t n, bool close = true, std::uint64_t t0 = 1'000'000'000,
                     std::uint64_t step = 1'000'000) {
    McapWriterOptions options;
    options.compression = compression;
    options.chunk_size = chunk_size;
    writer_ = std::make_unique<McapWriter>(path, options);
    Written w;
    const auto schema =
        writer_->add_schema("tendril.JointState", "jsonschema", bytes_of(R"({"type":"object"})"));
    w.joints = writer_->add_channel(schema, "/srmc/joint_states", "json", {{"robot", "srmc"}});
    w.events = writer_->add_channel(0, "/safety/events", "json");
    std::uint32_t events = 0;
    for (std::uint64_t i = 0; i < n; ++i) {
      const std::uint64_t t = t0 + i * step;
      writer_->write_message(w.joints, static_cast<std::uint32_t>(i), t, t, joint_state(i));
      ++w.count;
      if (i % 10 == 9) {
        writer_->write_message(w.events, events++, t - 3 * step, t, bytes_of(R"({"event":"tick"})"));
        ++w.count;
      }
    }
    if (close) writer_->close();
    return w;
  }

  std::filesystem::path dir_;
  std::unique_ptr<McapWriter> writer_;
};

std::vector<McapMessageCursor::Item> read_all(const std::vector<const McapReader*>& readers,
                                              std::uint64_t start = 0) {
  McapMessageCursor cursor(readers, start);
  std::vector<McapMessageCursor::Item> items;
  McapMessageCursor::Item item;
  while (cursor.next(item)) items.push_back(item);
  return items;
}

class ReaderRoundTrip : public McapReaderTest, public ::testing::WithParamInterface<Compression> {};

TEST_P(ReaderRoundTrip, AFinalisedFileIsReadThroughItsSummaryInLogTimeOrder) {
  const auto path = dir_ / "finalised.mcap";
  const auto w = write_file(path, GetParam(), 2048, 500);
  const McapReader reader(path);
  EXPECT_TRUE(reader.finalised());
  EXPECT_EQ(reader.truncated_bytes(), 0U);
  EXPECT_EQ(reader.library(), "tendril-record");
  EXPECT_EQ(reader.message_count(), w.count);
  EXPECT_GT(reader.chunks().size(), 5U);
  ASSERT_EQ(reader.channels().size(), 2U);
  const McapChannel& joints = reader.channels().at(w.joints);
  EXPECT_EQ(joints.topic, "/srmc/joint_states");
  EXPECT_EQ(joints.message_encoding, "json");
  EXPECT_EQ(joints.metadata.at("robot"), "srmc");
  ASSERT_NE(reader.schema_of(joints), nullptr);
  EXPECT_EQ(reader.schema_of(joints)->name, "tendril.JointState");
  EXPECT_EQ(reader.schema_of(joints)->encoding, "jsonschema");
  EXPECT_EQ(reader.schema_of(reader.channels().at(w.events)), nullptr);
  EXPECT_EQ(reader.start_time(), 1'000'000'000U);
  EXPECT_EQ(reader.end_time(), 1'000'000'000U + 499'000'000U);

  const auto items = read_all({&reader});
  ASSERT_EQ(items.size(), w.count);
  std::uint32_t next_joint = 0, next_event = 0;
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i > 0) {
      ASSERT_LE(items[i - 1].message.log_time, items[i].message.log_time) << i;
    }
    const auto& m = items[i].message;
    if (m.channel_id == w.joints) {
      EXPECT_EQ(items[i].channel->topic, "/srmc/joint_states");
      EXPECT_EQ(items[i].schema->name, "tendril.JointState");
      EXPECT_EQ(m.sequence, next_joint);
      EXPECT_EQ(m.data, joint_state(next_joint));
      ++next_joint;
    } else {
      EXPECT_EQ(items[i].schema, nullptr);
      EXPECT_EQ(m.sequence, next_event++);
      EXPECT_EQ(m.publish_time - m.log_time, 3'000'000U);
    }
  }
  EXPECT_EQ(next_joint, 500U);
  EXPECT_EQ(next_event, 50U);
}

TEST_P(ReaderRoundTrip, EveryPrefixOfAFileReadsTheMessagesOfItsWholeChunks) {
  const auto path = dir_ / "cut.mcap";
  const auto w = write_file(path, GetParam(), 512, 40);
  const auto bytes = file_bytes(path);
  const McapReader full(bytes, "full");
  std::vector<std::pair<std::uint64_t, std::size_t>> chunk_ends;  // end offset, messages
  for (std::size_t c = 0; c < full.chunks().size(); ++c) {
    chunk_ends.emplace_back(full.chunks()[c].offset + full.chunks()[c].length, full.read_chunk(c).size());
  }
  ASSERT_GT(chunk_ends.size(), 3U);
  std::size_t readable = 0;
  // Every byte at the start (the magic and the Header), then every third: a cut inside each record field.
  for (std::size_t cut = 0; cut < bytes.size(); cut += cut < 64 ? 1 : 3) {
    const std::vector<std::uint8_t> prefix(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(cut));
    std::size_t expected = 0;
    for (const auto& [end, n] : chunk_ends) expected += end <= cut ? n : 0;
    try {
      const McapReader reader(prefix, "prefix");
      EXPECT_FALSE(reader.finalised()) << cut;
      const auto items = read_all({&reader});
      ASSERT_EQ(items.size(), expected) << "cut at " << cut;
      ASSERT_EQ(reader.message_count(), expected) << cut;
      for (std::size_t i = 1; i < items.size(); ++i) {
        ASSERT_LE(items[i - 1].message.log_time, items[i].message.log_time);
      }
      ++readable;
    } catch (const McapFormatError& e) {
      // Only a prefix without a whole Header is unreadable.
      EXPECT_LT(cut, 8U + 9U + 8U + std::string("tendril-record").size()) << cut << ": " << e.what();
    }
  }
  EXPECT_GT(readable, (bytes.size() - 64) / 3);
  (void)w;
}

INSTANTIATE_TEST_SUITE_P(AllCompressions, ReaderRoundTrip,
                         ::testing::Values(Compression::kNone, Compression::kZstd, Compression::kLz4),
                         [](const auto& info) {
                           return info.param == Compression::kNone
                                      ? std::string("none")
                                      : std::string(compression_name(info.param));
                         });

TEST_F(McapReaderTest, AFileStillBeingWrittenReadsItsFlushedChunks) {
  const auto path = dir_ / "open.mcap";
  const auto w = write_file(path, Compression::kZstd, 1024, 300, /*close=*/false);
  const std::uint64_t flushed = writer_->stats().flushed_messages;
  ASSERT_GT(flushed, 0U);
  ASSERT_LT(flushed, w.count);
  const McapReader reader(path);  // what SIGKILL would leave: no summary, no footer
  EXPECT_FALSE(reader.finalised());
  EXPECT_EQ(reader.message_count(), flushed);
  EXPECT_EQ(read_all({&reader}).size(), flushed);
  EXPECT_EQ(reader.channels().size(), 2U);
  writer_->close();
  const McapReader closed(path);
  EXPECT_TRUE(closed.finalised());
  EXPECT_EQ(read_all({&closed}).size(), w.count);
}

TEST_F(McapReaderTest, ARotatedSetMergesInLogTimeOrderWithContinuousSequences) {
  RecorderOptions options;
  options.directory = dir_;
  options.writer.chunk_size = 4 * 1024;
  options.max_file_duration_ns = 200'000'000;  // 0.2 s of log time per file
  Recorder recorder(options);
  ChannelSpec spec;
  spec.topic = "/srmc/joint_states";
  spec.message_encoding = "json";
  const auto joints = recorder.add_channel(spec);
  spec.topic = "/safety/events";
  const auto events = recorder.add_channel(spec);
  constexpr std::uint64_t kJoint = 1000;
  for (std::uint64_t i = 0; i < kJoint; ++i) {
    ASSERT_TRUE(recorder.record(joints, i * 1'000'000, joint_state(i)));
    if (i % 100 == 0) {
      ASSERT_TRUE(recorder.record(events, i * 1'000'000, bytes_of("{}")));
    }
  }
  recorder.start();
  recorder.stop();
  const auto files = mcap_files(dir_);
  ASSERT_EQ(files.size(), 5U);
  EXPECT_EQ(files, recorder.files());
  std::vector<McapReader> readers;
  for (const auto& f : files) readers.emplace_back(f);
  std::vector<const McapReader*> pointers;
  for (const auto& r : readers) pointers.push_back(&r);
  const auto items = read_all(pointers);
  ASSERT_EQ(items.size(), kJoint + 10);
  std::map<std::string, std::uint32_t> next;
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i > 0) {
      ASSERT_LE(items[i - 1].message.log_time, items[i].message.log_time);
    }
    EXPECT_EQ(items[i].message.sequence, next[items[i].channel->topic]++) << items[i].channel->topic;
    EXPECT_EQ(items[i].reader, items[i].message.log_time / 200'000'000);
  }
  EXPECT_EQ(next["/srmc/joint_states"], kJoint);
  EXPECT_EQ(next["/safety/events"], 10U);
}

TEST_F(McapReaderTest, FilesOverlappingInTimeInterleaveAndSeekStartsAtTheTimeAsked) {
  // Two files over the same span: even and odd milliseconds.
  write_file(dir_ / "a.mcap", Compression::kLz4, 700, 100, true, 0, 2'000'000);
  write_file(dir_ / "b.mcap", Compression::kNone, 900, 100, true, 1'000'000, 2'000'000);
  const McapReader a(dir_ / "a.mcap"), b(dir_ / "b.mcap");
  const auto items = read_all({&a, &b});
  ASSERT_EQ(items.size(), 220U);
  for (std::size_t i = 1; i < items.size(); ++i) {
    ASSERT_LE(items[i - 1].message.log_time, items[i].message.log_time) << i;
  }
  EXPECT_EQ(items.front().message.log_time, 0U);  // joint 0 of a
  EXPECT_EQ(items[1].message.log_time, 1'000'000U);
  EXPECT_EQ(items[1].reader, 1U);

  McapMessageCursor cursor({&a, &b}, 150'000'000);
  McapMessageCursor::Item item;
  ASSERT_TRUE(cursor.next(item));
  EXPECT_EQ(item.message.log_time, 150'000'000U);
  std::size_t after = 1;
  while (cursor.next(item)) ++after;
  const auto expected = std::count_if(items.begin(), items.end(),
                                      [](const auto& x) { return x.message.log_time >= 150'000'000; });
  EXPECT_EQ(after, static_cast<std::size_t>(expected));
  cursor.seek(0);
  ASSERT_TRUE(cursor.next(item));
  EXPECT_EQ(item.message.log_time, 0U);
  cursor.seek(1'000'000'000'000);
  EXPECT_FALSE(cursor.next(item));
}

TEST_F(McapReaderTest, DamagedFilesAreRefusedWithTypedErrorsThatSayWhat) {
  const auto path = dir_ / "good.mcap";
  write_file(path, Compression::kNone, 1024, 200);
  const auto good = file_bytes(path);
  const McapReader reader(good, "good");
  const auto chunk = reader.chunks().at(1);
  const auto expect_error = [](const auto& make, const std::string& words) {
    try {
      make();
      ADD_FAILURE() << "no error; expected one saying '" << words << "'";
    } catch (const McapFormatError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };

  // A byte inside a chunk's records: the data-section CRC at open, or the chunk CRC when read.
  auto flipped = good;
  flipped[chunk.offset + chunk.length - 10] ^= 0x40;
  expect_error([&] { McapReader{flipped, "flipped"}; }, "data section CRC mismatch");
  McapReaderOptions lazy;
  lazy.check_data_crc = false;
  const McapReader unchecked(flipped, "flipped", lazy);
  expect_error([&] { unchecked.read_chunk(1); }, "chunk CRC mismatch");
  expect_error([&] { read_all({&unchecked}); }, "chunk CRC mismatch");

  // The summary.
  auto summary = good;
  summary[summary.size() - 60] ^= 0x01;
  expect_error([&] { McapReader{summary, "summary"}; }, "summary CRC mismatch");

  // Not MCAP at all, and too short.
  expect_error([] { McapReader{bytes_of("{\"hello\": \"world\"}"), "json"}; }, "not an MCAP file");
  expect_error([] { McapReader{bytes_of("\x89MC"), "short"}; }, "too short");

  // A chunk larger than the reader accepts (a hostile uncompressed_size must not allocate).
  McapReaderOptions small;
  small.max_chunk_bytes = 100;
  const McapReader limited(good, "limited", small);
  expect_error([&] { limited.read_chunk(0); }, "more than");

  // A cut file whose chunk was damaged: streaming checks the CRC too.
  std::vector<std::uint8_t> cut(
      flipped.begin(), flipped.begin() + static_cast<std::ptrdiff_t>(chunk.offset + chunk.length + 5));
  expect_error([&] { McapReader{cut, "cut"}; }, "chunk CRC mismatch");

  // An unknown file or folder.
  EXPECT_THROW(McapReader(dir_ / "missing.mcap"), McapError);
  EXPECT_THROW(mcap_files(dir_ / "missing"), McapError);
  std::filesystem::create_directories(dir_ / "empty");
  EXPECT_THROW(mcap_files(dir_ / "empty"), McapError);
}

}  // namespace
}  // namespace tendril::record
