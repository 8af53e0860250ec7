#include "tendril/record/mcap_writer.hpp"

#include <fcntl.h>
#include <lz4frame.h>
#include <sys/uio.h>
#include <unistd.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <limits>

#include "tendril/record/crc32.hpp"

namespace tendril::record {
namespace {

// Opcodes (spec, "Records").
constexpr std::uint8_t kHeader = 0x01, kFooter = 0x02, kSchema = 0x03, kChannel = 0x04, kMessage = 0x05,
                       kChunk = 0x06, kMessageIndex = 0x07, kChunkIndex = 0x08, kStatistics = 0x0B,
                       kMetadata = 0x0C, kMetadataIndex = 0x0D, kSummaryOffset = 0x0E, kDataEnd = 0x0F;
constexpr std::array<std::uint8_t, 8> kMagic = {0x89, 'M', 'C', 'A', 'P', 0x30, '\r', '\n'};

using Bytes = std::vector<std::uint8_t>;

// Little-endian fixed-width integers, whatever the host's order.
void put_u8(Bytes& b, std::uint8_t v) { b.push_back(v); }
void put_u16(Bytes& b, std::uint16_t v) {
  for (int i = 0; i < 2; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void put_u32(Bytes& b, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void put_u64(Bytes& b, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void patch_u64(Bytes& b, std::size_t at, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) b[at + i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_bytes(Bytes& b, std::span<const std::uint8_t> data) { b.insert(b.end(), data.begin(), data.end()); }

std::uint32_t checked_u32(std::size_t n, const char* what) {
  if (n > std::numeric_limits<std::uint32_t>::max()) {
    throw McapError(std::string("MCAP: ") + what + " is larger than 4 GiB, which the format cannot hold");
  }
  return static_cast<std::uint32_t>(n);
}
// String: uint32 byte length, then the bytes.
void put_string(Bytes& b, std::string_view s) {
  put_u32(b, checked_u32(s.size(), "a string"));
  b.insert(b.end(), s.begin(), s.end());
}
// Map<string, string>: uint32 byte length of the entries, then key, value, key, value, …
void put_string_map(Bytes& b, const std::map<std::string, std::string>& m) {
  std::size_t length = 0;
  for (const auto& [k, v] : m) length += 8 + k.size() + v.size();
  put_u32(b, checked_u32(length, "a metadata map"));
  for (const auto& [k, v] : m) {
    put_string(b, k);
    put_string(b, v);
  }
}

// <opcode><uint64 content length><content>: begin_record writes the opcode and a placeholder length,
// end_record fills the length in once the content is appended.
std::size_t begin_record(Bytes& b, std::uint8_t opcode) {
  b.push_back(opcode);
  const std::size_t at = b.size();
  put_u64(b, 0);
  return at;
}
void end_record(Bytes& b, std::size_t length_at) { patch_u64(b, length_at, b.size() - length_at - 8); }

std::span<const std::uint8_t> as_bytes(const Bytes& b) { return {b.data(), b.size()}; }

}  // namespace

std::string_view compression_name(Compression compression) noexcept {
  switch (compression) {
    case Compression::kZstd:
      return "zstd";
    case Compression::kLz4:
      return "lz4";
    case Compression::kNone:
      break;
  }
  return "";
}

Compression parse_compression(std::string_view name) {
  if (name.empty() || name == "none") return Compression::kNone;
  if (name == "zstd") return Compression::kZstd;
  if (name == "lz4") return Compression::kLz4;
  throw std::invalid_argument("unknown MCAP chunk compression '" + std::string(name) +
                              "' (choose one of: none, zstd, lz4)");
}

McapWriter::McapWriter(const std::filesystem::path& path, McapWriterOptions options)
    : path_(path), options_(std::move(options)) {
  if (options_.chunk_size == 0) throw std::invalid_argument("MCAP chunk_size must be at least 1 byte");
  if (options_.compression == Compression::kZstd) {
    if (options_.zstd_level < ZSTD_minCLevel() || options_.zstd_level > ZSTD_maxCLevel()) {
      throw std::invalid_argument("zstd level " + std::to_string(options_.zstd_level) + " is outside " +
                                  std::to_string(ZSTD_minCLevel()) + ".." + std::to_string(ZSTD_maxCLevel()));
    }
    zstd_ = ZSTD_createCCtx();
    if (zstd_ == nullptr) throw McapError("MCAP: zstd could not allocate a compression context");
  }
  // O_EXCL: a recording never overwrites another.
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd_ < 0) {
    const int err = errno;
    ZSTD_freeCCtx(zstd_);
    throw McapError("cannot create MCAP file " + path_.string() + ": " + std::strerror(err));
  }
  chunk_.reserve(options_.chunk_size + (options_.chunk_size >> 3));
  Bytes head(kMagic.begin(), kMagic.end());
  const std::size_t at = begin_record(head, kHeader);
  put_string(head, options_.profile);
  put_string(head, options_.library);
  end_record(head, at);
  try {
    write_out(as_bytes(head));
  } catch (...) {
    ::close(fd_);
    fd_ = -1;
    ZSTD_freeCCtx(zstd_);
    throw;
  }
}

McapWriter::~McapWriter() {
  try {
    close();
  } catch (const std::exception&) {  // the destructor cannot report; close() does
  }
  ZSTD_freeCCtx(zstd_);
}

void McapWriter::require_open(const char* what) const {
  if (fd_ < 0) throw McapError(std::string("MCAP: ") + what + " after " + path_.string() + " was closed");
}

void McapWriter::write_out(std::span<const std::uint8_t> bytes) {
  const std::uint8_t* p = bytes.data();
  std::size_t left = bytes.size();
  while (left > 0) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw McapError("cannot write MCAP file " + path_.string() + ": " + std::strerror(errno));
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  data_crc_ = crc32(bytes, data_crc_);
  stats_.bytes += bytes.size();
}

std::uint16_t McapWriter::add_schema(std::string_view name, std::string_view encoding,
                                     std::span<const std::uint8_t> data) {
  require_open("add_schema");
  if (schemas_.size() >= std::numeric_limits<std::uint16_t>::max()) {
    throw McapError("MCAP: more than 65535 schemas in " + path_.string());
  }
  const auto id = static_cast<std::uint16_t>(schemas_.size() + 1);
  Bytes r;
  const std::size_t at = begin_record(r, kSchema);
  put_u16(r, id);
  put_string(r, name);
  put_string(r, encoding);
  put_u32(r, checked_u32(data.size(), "a schema"));
  put_bytes(r, data);
  end_record(r, at);
  put_bytes(chunk_, as_bytes(r));
  schemas_.push_back(std::move(r));
  return id;
}

std::uint16_t McapWriter::add_channel(std::uint16_t schema_id, std::string_view topic,
                                      std::string_view message_encoding,
                                      const std::map<std::string, std::string>& metadata) {
  require_open("add_channel");
  if (schema_id > schemas_.size()) {
    throw McapError("MCAP: channel '" + std::string(topic) + "' names schema " + std::to_string(schema_id) +
                    ", but " + path_.string() + " has " + std::to_string(schemas_.size()) + " schemas");
  }
  if (channels_.size() >= std::numeric_limits<std::uint16_t>::max()) {
    throw McapError("MCAP: more than 65535 channels in " + path_.string());
  }
  const auto id = static_cast<std::uint16_t>(channels_.size() + 1);
  Bytes r;
  const std::size_t at = begin_record(r, kChannel);
  put_u16(r, id);
  put_u16(r, schema_id);
  put_string(r, topic);
  put_string(r, message_encoding);
  put_string_map(r, metadata);
  end_record(r, at);
  put_bytes(chunk_, as_bytes(r));
  channels_.push_back(ChannelInfo{id, std::move(r), 0});
  chunk_index_.emplace_back();
  return id;
}

void McapWriter::write_message(std::uint16_t channel_id, std::uint32_t sequence, std::uint64_t log_time,
                               std::uint64_t publish_time, std::span<const std::uint8_t> data) {
  require_open("write_message");
  if (channel_id == 0 || channel_id > channels_.size()) {
    throw McapError("MCAP: message on channel " + std::to_string(channel_id) + ", but " + path_.string() +
                    " has channels 1.." + std::to_string(channels_.size()));
  }
  const std::uint64_t offset = chunk_.size();
  // Message: channel_id, sequence, log_time, publish_time, data (the rest of the record).
  put_u8(chunk_, kMessage);
  put_u64(chunk_, 2 + 4 + 8 + 8 + data.size());
  put_u16(chunk_, channel_id);
  put_u32(chunk_, sequence);
  put_u64(chunk_, log_time);
  put_u64(chunk_, publish_time);
  put_bytes(chunk_, data);

  chunk_index_[channel_id - 1].emplace_back(log_time, offset);
  if (chunk_messages_ == 0 || log_time < chunk_start_time_) chunk_start_time_ = log_time;
  if (chunk_messages_ == 0 || log_time > chunk_end_time_) chunk_end_time_ = log_time;
  ++chunk_messages_;
  ++channels_[channel_id - 1].message_count;
  if (stats_.messages == 0 || log_time < stats_.message_start_time) stats_.message_start_time = log_time;
  if (stats_.messages == 0 || log_time > stats_.message_end_time) stats_.message_end_time = log_time;
  ++stats_.messages;
  if (chunk_.size() >= options_.chunk_size) flush_chunk();
}

void McapWriter::flush_chunk() {
  if (fd_ < 0 || chunk_.empty()) return;
  const std::span<const std::uint8_t> records(chunk_.data(), chunk_.size());

  // Compress; a chunk that does not shrink (JPEG images) is stored as it is, compression "", which the
  // spec allows per chunk and which spares every reader a pointless decompression.
  std::string_view compression = compression_name(options_.compression);
  std::span<const std::uint8_t> payload = records;
  if (options_.compression == Compression::kZstd) {
    compressed_.resize(ZSTD_compressBound(records.size()));
    const std::size_t n = ZSTD_compressCCtx(zstd_, compressed_.data(), compressed_.size(), records.data(),
                                            records.size(), options_.zstd_level);
    if (ZSTD_isError(n) != 0U) throw McapError(std::string("MCAP: zstd failed: ") + ZSTD_getErrorName(n));
    payload = {compressed_.data(), n};
  } else if (options_.compression == Compression::kLz4) {
    LZ4F_preferences_t prefs{};
    prefs.frameInfo.contentSize = records.size();  // lets a reader size its buffer from the frame
    compressed_.resize(LZ4F_compressFrameBound(records.size(), &prefs));
    const std::size_t n =
        LZ4F_compressFrame(compressed_.data(), compressed_.size(), records.data(), records.size(), &prefs);
    if (LZ4F_isError(n) != 0U) throw McapError(std::string("MCAP: lz4 failed: ") + LZ4F_getErrorName(n));
    payload = {compressed_.data(), n};
  }
  if (payload.size() >= records.size()) {
    payload = records;
    compression = "";
  }

  // Chunk: message_start_time, message_end_time, uncompressed_size, uncompressed_crc, compression,
  // records (uint64 length + bytes).
  Bytes head;
  head.reserve(64);
  const std::size_t at = begin_record(head, kChunk);
  put_u64(head, chunk_messages_ > 0 ? chunk_start_time_ : 0);
  put_u64(head, chunk_messages_ > 0 ? chunk_end_time_ : 0);
  put_u64(head, records.size());
  put_u32(head, crc32(records));
  put_string(head, compression);
  put_u64(head, payload.size());
  patch_u64(head, at, head.size() - at - 8 + payload.size());

  const std::uint64_t chunk_offset = stats_.bytes;
  const std::uint64_t chunk_length = head.size() + payload.size();

  // One Message Index per channel with messages in this chunk, in channel order, each sorted by log
  // time (stable: equal times keep their order in the chunk).
  ChunkIndexEntry entry{chunk_messages_ > 0 ? chunk_start_time_ : 0,
                        chunk_messages_ > 0 ? chunk_end_time_ : 0,
                        chunk_offset,
                        chunk_length,
                        0,
                        payload.size(),
                        records.size(),
                        compression,
                        {}};
  out_.clear();
  for (std::size_t c = 0; c < chunk_index_.size(); ++c) {
    auto& list = chunk_index_[c];
    if (list.empty()) continue;
    std::stable_sort(list.begin(), list.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    entry.message_index_offsets.emplace_back(static_cast<std::uint16_t>(c + 1),
                                             chunk_offset + chunk_length + out_.size());
    const std::size_t mat = begin_record(out_, kMessageIndex);
    put_u16(out_, static_cast<std::uint16_t>(c + 1));
    put_u32(out_, checked_u32(list.size() * 16, "a message index"));
    for (const auto& [time, offset] : list) {
      put_u64(out_, time);
      put_u64(out_, offset);
    }
    end_record(out_, mat);
    list.clear();
  }
  entry.message_index_length = out_.size();

  // The chunk record and its message indexes in one writev, so that the kernel has all of it or (if
  // the process dies inside the call) a tail that a streaming reader recognises as incomplete.
  std::array<iovec, 3> iov{iovec{head.data(), head.size()},
                           iovec{const_cast<std::uint8_t*>(payload.data()), payload.size()},
                           iovec{out_.data(), out_.size()}};
  std::size_t first = 0;
  while (first < iov.size()) {
    const ssize_t n = ::writev(fd_, &iov[first], static_cast<int>(iov.size() - first));
    if (n < 0) {
      if (errno == EINTR) continue;
      throw McapError("cannot write MCAP file " + path_.string() + ": " + std::strerror(errno));
    }
    auto left = static_cast<std::size_t>(n);
    while (first < iov.size() && left >= iov[first].iov_len) {
      left -= iov[first].iov_len;
      ++first;
    }
    if (first < iov.size()) {
      iov[first].iov_base = static_cast<std::uint8_t*>(iov[first].iov_base) + left;
      iov[first].iov_len -= left;
    }
  }
  data_crc_ = crc32(as_bytes(head), data_crc_);
  data_crc_ = crc32(payload, data_crc_);
  data_crc_ = crc32(as_bytes(out_), data_crc_);
  stats_.bytes += chunk_length + out_.size();
  if (options_.sync_each_chunk && ::fdatasync(fd_) != 0) {
    throw McapError("cannot sync MCAP file " + path_.string() + ": " + std::strerror(errno));
  }

  chunk_indexes_.push_back(std::move(entry));
  ++stats_.chunks;
  stats_.flushed_messages += chunk_messages_;
  chunk_.clear();
  chunk_messages_ = 0;
}

void McapWriter::write_metadata(std::string_view name, const std::map<std::string, std::string>& metadata) {
  require_open("write_metadata");
  flush_chunk();
  Bytes r;
  const std::size_t at = begin_record(r, kMetadata);
  put_string(r, name);
  put_string_map(r, metadata);
  end_record(r, at);
  const std::uint64_t offset = stats_.bytes;
  write_out(as_bytes(r));
  metadata_indexes_.push_back(MetadataIndexEntry{offset, r.size(), std::string(name)});
}

void McapWriter::close() {
  if (fd_ < 0) return;
  try {
    flush_chunk();
    // Data End: the CRC of every byte before it.
    Bytes tail;
    std::size_t at = begin_record(tail, kDataEnd);
    put_u32(tail, data_crc_);
    end_record(tail, at);
    write_out(as_bytes(tail));

    // The summary, grouped by opcode; each group is located by a Summary Offset record.
    const std::uint64_t summary_start = stats_.bytes;
    Bytes summary;
    struct Group {
      std::uint8_t opcode;
      std::uint64_t start, length;
    };
    std::vector<Group> groups;
    auto group = [&](std::uint8_t opcode, auto&& append_records) {
      const std::size_t begin = summary.size();
      append_records();
      if (summary.size() > begin) groups.push_back({opcode, summary_start + begin, summary.size() - begin});
    };
    group(kSchema, [&] {
      for (const auto& s : schemas_) put_bytes(summary, as_bytes(s));
    });
    group(kChannel, [&] {
      for (const auto& c : channels_) put_bytes(summary, as_bytes(c.record));
    });
    group(kMetadataIndex, [&] {
      for (const auto& m : metadata_indexes_) {
        const std::size_t mat = begin_record(summary, kMetadataIndex);
        put_u64(summary, m.offset);
        put_u64(summary, m.length);
        put_string(summary, m.name);
        end_record(summary, mat);
      }
    });
    group(kChunkIndex, [&] {
      for (const auto& c : chunk_indexes_) {
        const std::size_t cat = begin_record(summary, kChunkIndex);
        put_u64(summary, c.start_time);
        put_u64(summary, c.end_time);
        put_u64(summary, c.offset);
        put_u64(summary, c.length);
        put_u32(summary, checked_u32(c.message_index_offsets.size() * 10, "a chunk index"));
        for (const auto& [channel, offset] : c.message_index_offsets) {
          put_u16(summary, channel);
          put_u64(summary, offset);
        }
        put_u64(summary, c.message_index_length);
        put_string(summary, c.compression);
        put_u64(summary, c.compressed_size);
        put_u64(summary, c.uncompressed_size);
        end_record(summary, cat);
      }
    });
    group(kStatistics, [&] {
      const std::size_t sat = begin_record(summary, kStatistics);
      put_u64(summary, stats_.messages);
      put_u16(summary, static_cast<std::uint16_t>(schemas_.size()));
      put_u32(summary, static_cast<std::uint32_t>(channels_.size()));
      put_u32(summary, 0);  // attachments
      put_u32(summary, static_cast<std::uint32_t>(metadata_indexes_.size()));
      put_u32(summary, checked_u32(chunk_indexes_.size(), "the chunk count"));
      put_u64(summary, stats_.messages > 0 ? stats_.message_start_time : 0);
      put_u64(summary, stats_.messages > 0 ? stats_.message_end_time : 0);
      put_u32(summary, static_cast<std::uint32_t>(channels_.size() * 10));
      for (const auto& c : channels_) {
        put_u16(summary, c.id);
        put_u64(summary, c.message_count);
      }
      end_record(summary, sat);
    });
    const std::uint64_t summary_offset_start = summary_start + summary.size();
    for (const auto& g : groups) {
      const std::size_t oat = begin_record(summary, kSummaryOffset);
      put_u8(summary, g.opcode);
      put_u64(summary, g.start);
      put_u64(summary, g.length);
      end_record(summary, oat);
    }
    // Footer: its CRC covers the summary, the summary offsets and the footer up to the CRC field (its
    // opcode and length included, so the length is written first, not patched after).
    put_u8(summary, kFooter);
    put_u64(summary, 8 + 8 + 4);
    put_u64(summary, summary_start);
    put_u64(summary, summary_offset_start);
    put_u32(summary, crc32(as_bytes(summary)));
    put_bytes(summary, kMagic);
    write_out(as_bytes(summary));
    if (options_.sync_each_chunk && ::fdatasync(fd_) != 0) {
      throw McapError("cannot sync MCAP file " + path_.string() + ": " + std::strerror(errno));
    }
  } catch (...) {
    ::close(fd_);
    fd_ = -1;
    throw;
  }
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0)
    throw McapError("cannot close MCAP file " + path_.string() + ": " + std::strerror(errno));
}

}  // namespace tendril::record
