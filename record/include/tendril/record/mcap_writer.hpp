// McapWriter: writes one MCAP file (https://mcap.dev/spec, major version 0) with every Schema,
// Channel and Message record inside Chunks, a Message Index after each chunk, and, on close, the
// Data End record, a Summary section (Schema, Channel, Metadata Index, Chunk Index, Statistics
// groups), one Summary Offset per group, the Footer and the closing magic.
//
// Crash safety: a chunk and its message indexes go to the kernel in one write, as soon as the chunk
// is complete, and nothing else is buffered in the process. A file cut at any moment (SIGKILL, the
// process dying) therefore ends after the last complete chunk (plus, at worst, a partial record that
// a streaming reader stops at), and a reader that scans from the start reads every message up to it.
// With sync_each_chunk the chunk is also fdatasync'ed, for power loss; SIGKILL does not need it.
//
// Not thread-safe: one thread owns a writer (the Recorder's writer thread).
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

struct ZSTD_CCtx_s;  // zstd's compression context, kept between chunks

namespace tendril::record {

// I/O failures and wrong use (unknown channel id, writing after close), with the file named.
class McapError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class Compression { kNone, kZstd, kLz4 };

// "", "zstd" or "lz4": the Chunk record's compression field.
std::string_view compression_name(Compression compression) noexcept;
// Parses "none" (or ""), "zstd", "lz4"; throws std::invalid_argument naming the choices otherwise.
Compression parse_compression(std::string_view name);

struct McapWriterOptions {
  Compression compression = Compression::kZstd;
  // A chunk is closed and written once its uncompressed records reach this size. Larger chunks
  // compress better; smaller ones lose less when the process is killed. A single larger message
  // makes a chunk of its own size.
  std::size_t chunk_size = std::size_t{1} << 20;
  // zstd level 1: the fastest, since most of a recording's bytes are JPEG images that do not compress.
  int zstd_level = 1;
  // fdatasync after each chunk (power-loss safety; costs a disk flush per chunk).
  bool sync_each_chunk = false;
  std::string profile;  // the Header's profile ("" = none of the well-known profiles)
  std::string library = "tendril-record";
};

// What a finished (or in-progress) file holds so far.
struct McapFileStats {
  std::uint64_t messages = 0;          // messages written (in complete chunks + the open one)
  std::uint64_t chunks = 0;            // complete chunks on disk
  std::uint64_t flushed_messages = 0;  // messages in complete chunks, i.e. safe from SIGKILL
  std::uint64_t bytes = 0;             // bytes handed to the kernel so far
  std::uint64_t message_start_time = 0;
  std::uint64_t message_end_time = 0;
};

class McapWriter {
 public:
  // Creates the file (refuses to overwrite: O_EXCL) and writes the magic and the Header record.
  McapWriter(const std::filesystem::path& path, McapWriterOptions options);
  ~McapWriter();  // close(), errors swallowed; call close() to see them
  McapWriter(const McapWriter&) = delete;
  McapWriter& operator=(const McapWriter&) = delete;

  // Ids are 1, 2, … in call order. The records go into the open chunk, before any message that uses
  // them, so a file cut later still defines every channel it holds messages for.
  std::uint16_t add_schema(std::string_view name, std::string_view encoding,
                           std::span<const std::uint8_t> data);
  // schema_id 0: no schema (self-describing encodings such as json).
  std::uint16_t add_channel(std::uint16_t schema_id, std::string_view topic,
                            std::string_view message_encoding,
                            const std::map<std::string, std::string>& metadata = {});

  // Appends a Message record to the open chunk; writes the chunk when it reaches chunk_size.
  void write_message(std::uint16_t channel_id, std::uint32_t sequence, std::uint64_t log_time,
                     std::uint64_t publish_time, std::span<const std::uint8_t> data);

  // A Metadata record, written in the data section between chunks (the open chunk is written first);
  // indexed in the summary.
  void write_metadata(std::string_view name, const std::map<std::string, std::string>& metadata);

  // Writes the open chunk now, if it holds any record (the recorder's time bound on data at risk).
  void flush_chunk();

  // Writes the open chunk, Data End, the summary, the summary offsets, the footer and the magic; closes
  // the file. Idempotent.
  void close();

  bool is_open() const noexcept { return fd_ >= 0; }
  const std::filesystem::path& path() const noexcept { return path_; }
  const McapFileStats& stats() const noexcept { return stats_; }
  // Bytes of records waiting in the open chunk (uncompressed).
  std::size_t open_chunk_bytes() const noexcept { return chunk_.size(); }

 private:
  struct ChannelInfo {
    std::uint16_t id;
    std::vector<std::uint8_t> record;  // the whole Channel record, kept for the summary
    std::uint64_t message_count = 0;
  };
  struct ChunkIndexEntry {
    std::uint64_t start_time, end_time, offset, length, message_index_length, compressed_size,
        uncompressed_size;
    std::string_view compression;
    std::vector<std::pair<std::uint16_t, std::uint64_t>> message_index_offsets;
  };
  struct MetadataIndexEntry {
    std::uint64_t offset, length;
    std::string name;
  };

  void write_out(std::span<const std::uint8_t> bytes);  // to the file, counted in the data CRC
  void require_open(const char* what) const;

  std::filesystem::path path_;
  McapWriterOptions options_;
  int fd_ = -1;
  std::uint32_t data_crc_ = 0;  // CRC of everything written so far (the data section, until close)
  McapFileStats stats_;

  std::vector<std::vector<std::uint8_t>> schemas_;  // whole Schema records, id = index + 1
  std::vector<ChannelInfo> channels_;               // id = index + 1

  // The open chunk: its uncompressed records, its time range and, per channel, the (log time, offset)
  // of each message in it (indexed by channel id - 1; a channel's list is empty if it has none here).
  std::vector<std::uint8_t> chunk_;
  std::uint64_t chunk_start_time_ = 0, chunk_end_time_ = 0;
  std::uint64_t chunk_messages_ = 0;
  std::vector<std::vector<std::pair<std::uint64_t, std::uint64_t>>> chunk_index_;

  ZSTD_CCtx_s* zstd_ = nullptr;
  std::vector<std::uint8_t> compressed_;  // reused compression output
  std::vector<std::uint8_t> out_;         // reused: message index records after a chunk
  std::vector<ChunkIndexEntry> chunk_indexes_;
  std::vector<MetadataIndexEntry> metadata_indexes_;
};

}  // namespace tendril::record
