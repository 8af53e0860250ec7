// McapReader: reads one MCAP file (https://mcap.dev/spec, major version 0) — a finalised one through
// its summary (Schema, Channel and Chunk Index records, checked against the Footer's summary CRC) and
// an unfinished one (the process was killed: no summary, no footer, perhaps a partial record at the
// end) by streaming its whole records from the start and stopping before the first incomplete one.
// Every chunk's CRC is checked when it is decompressed (zstd, lz4 or none); with check_data_crc the
// Data End CRC of a finalised file is checked at open (one read of the whole file).
//
// McapMessageCursor yields the messages of one file or of several (a rotated set) in log-time order
// (equal times in chunk order), decompressing a chunk only when the merge reaches its start time, so
// it holds the chunks that overlap in time, not the recording.
//
// Bad input (outside files: this parses them) ends in McapFormatError with a message naming the file,
// the byte offset and what was wrong; nothing is assumed about a file beyond what the spec says.
// Messages outside chunks (which the spec allows, and tendril's writer never writes) are refused with
// a McapFormatError saying so. Not thread-safe: one thread reads a reader.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "tendril/record/mcap_writer.hpp"

namespace tendril::record {

// A file that is not MCAP, is damaged (CRC mismatch, a record that runs past its parent, an index
// pointing nowhere) or uses what this reader does not read (an unknown compression, unchunked
// messages). The message is for a person: file, offset, what was expected.
class McapFormatError : public McapError {
 public:
  using McapError::McapError;
};

struct McapSchema {
  std::uint16_t id = 0;
  std::string name;
  std::string encoding;  // "jsonschema", "protobuf", "ros2msg", …; "" = none
  std::vector<std::uint8_t> data;
};

struct McapChannel {
  std::uint16_t id = 0;
  std::uint16_t schema_id = 0;  // 0: no schema
  std::string topic;
  std::string message_encoding;
  std::map<std::string, std::string> metadata;
};

struct McapMessage {
  std::uint16_t channel_id = 0;
  std::uint32_t sequence = 0;
  std::uint64_t log_time = 0;
  std::uint64_t publish_time = 0;
  std::vector<std::uint8_t> data;
};

struct McapReaderOptions {
  // Check the Data End CRC of a finalised file at open (reads the whole data section once). Chunk CRCs
  // and the summary CRC are always checked.
  bool check_data_crc = true;
  // A chunk whose uncompressed_size is larger is refused (a damaged or hostile size must not make the
  // reader allocate gigabytes). The writer's chunks are 1 MiB, or one message when it is larger.
  std::uint64_t max_chunk_bytes = std::uint64_t{512} << 20;
};

class McapReader {
 public:
  // One chunk (or, in a finalised file, one Chunk Index entry): where it is and its log-time span.
  struct ChunkRef {
    std::uint64_t offset = 0;  // of the Chunk record (its opcode)
    std::uint64_t length = 0;  // of the whole record
    std::uint64_t start_time = 0, end_time = 0;
  };

  // Opens and indexes the file. Throws McapError when it cannot be read, McapFormatError when it is
  // not a readable MCAP file.
  explicit McapReader(const std::filesystem::path& path, McapReaderOptions options = {});
  // The same over bytes in memory (tests, the fuzz target); `name` stands for the file in messages.
  McapReader(std::vector<std::uint8_t> bytes, std::string name, McapReaderOptions options = {});
  ~McapReader();
  McapReader(McapReader&&) noexcept;
  McapReader& operator=(McapReader&&) noexcept;

  const std::string& name() const noexcept { return name_; }
  // True when the file has a valid footer and summary (finalised); false when it was read by streaming
  // (a recording cut by SIGKILL, or a file written without a summary).
  bool finalised() const noexcept { return finalised_; }
  // Bytes after the last whole record of an unfinished file (a partial chunk lost with the process).
  std::uint64_t truncated_bytes() const noexcept { return truncated_bytes_; }
  std::string_view profile() const noexcept { return profile_; }
  std::string_view library() const noexcept { return library_; }

  const std::map<std::uint16_t, McapSchema>& schemas() const noexcept { return schemas_; }
  const std::map<std::uint16_t, McapChannel>& channels() const noexcept { return channels_; }
  // The channel's schema, or null when it has none.
  const McapSchema* schema_of(const McapChannel& channel) const;
  // Metadata records by name (a finalised file's, or those met while streaming).
  const std::map<std::string, std::map<std::string, std::string>>& metadata() const noexcept {
    return metadata_;
  }

  // Chunks in file order.
  const std::vector<ChunkRef>& chunks() const noexcept { return chunks_; }
  // Messages in the file: the Statistics record's count when finalised, else those counted while
  // streaming.
  std::uint64_t message_count() const noexcept { return message_count_; }
  // Log-time span of the messages (0, 0 when there are none).
  std::uint64_t start_time() const noexcept { return start_time_; }
  std::uint64_t end_time() const noexcept { return end_time_; }

  // The messages of chunk i (index into chunks()), sorted by log time (stable: equal times keep their
  // order in the chunk). Checks the chunk's CRC; throws McapFormatError.
  std::vector<McapMessage> read_chunk(std::size_t i) const;

 private:
  struct Source;
  void open();
  bool read_summary();
  void stream();
  std::vector<std::uint8_t> chunk_records(std::uint64_t offset, std::uint64_t length,
                                          ChunkRef* ref_out) const;
  [[noreturn]] void fail(std::uint64_t offset, const std::string& what) const;

  std::string name_;
  McapReaderOptions options_;
  std::unique_ptr<Source> source_;
  bool finalised_ = false;
  std::uint64_t truncated_bytes_ = 0;
  std::string profile_, library_;
  std::map<std::uint16_t, McapSchema> schemas_;
  std::map<std::uint16_t, McapChannel> channels_;
  std::map<std::string, std::map<std::string, std::string>> metadata_;
  std::vector<ChunkRef> chunks_;
  std::uint64_t message_count_ = 0, start_time_ = 0, end_time_ = 0;
};

// Messages of one or more readers in log-time order; equal log times come in the order of their chunks
// (by the chunks' start times, then the readers' order, then file order) and, within a chunk, in the
// order written. The readers must outlive the cursor.
class McapMessageCursor {
 public:
  struct Item {
    std::size_t reader = 0;  // index into the readers given
    const McapChannel* channel = nullptr;
    const McapSchema* schema = nullptr;  // null: none
    McapMessage message;
  };

  explicit McapMessageCursor(std::vector<const McapReader*> readers, std::uint64_t start_time = 0);
  // Next message with log_time >= start_time, or false at the end. Throws McapFormatError for a
  // damaged chunk (the messages before it have been yielded).
  bool next(Item& out);
  // Starts again at the first message with log_time >= start_time.
  void seek(std::uint64_t start_time);

 private:
  struct Pending {
    std::uint64_t log_time;
    std::size_t chunk_order;  // position in chunks_ (reader, then file order)
    std::size_t index;        // position in that chunk's sorted messages
  };
  struct ChunkSlot {
    std::size_t reader, chunk;
    std::uint64_t start_time, end_time;
    std::vector<McapMessage> messages;  // loaded while the merge is inside it
  };
  void load(std::size_t slot);

  std::vector<const McapReader*> readers_;
  std::vector<ChunkSlot> slots_;  // every chunk of every reader, by (start_time, reader, file order)
  std::size_t next_slot_ = 0;     // the first chunk not loaded yet
  std::vector<Pending> heap_;     // a min-heap of the next message of each loaded chunk
  std::uint64_t start_time_ = 0;
};

// The MCAP files a path names: the file itself, or a folder's *.mcap files sorted by name (the
// recorder's names sort by opening time and index). Throws McapError when there is none.
std::vector<std::filesystem::path> mcap_files(const std::filesystem::path& file_or_folder);

}  // namespace tendril::record
