// A minimal MCAP reader for the record tests only, written from the specification (mcap.dev/spec)
// independently of the writer: it walks the records from the start, checks every CRC the file
// carries (chunk uncompressed CRC, Data End, Footer summary CRC), checks that each Message Index
// entry points at a message of its channel with its log time, that each Chunk Index points at its
// chunk and message indexes, and that the Statistics agree with what it read. Throws
// std::runtime_error on anything malformed. A file that stops early (no footer) is read up to its
// last complete record, and complete == false says so.
#pragma once

#include <lz4frame.h>
#include <zstd.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "tendril/record/crc32.hpp"

namespace tendril::record::test {

struct ReadMessage {
  std::uint16_t channel_id = 0;
  std::string topic;
  std::uint32_t sequence = 0;
  std::uint64_t log_time = 0;
  std::uint64_t publish_time = 0;
  std::vector<std::uint8_t> data;
};

struct ReadChannel {
  std::uint16_t id = 0, schema_id = 0;
  std::string topic, message_encoding;
};

struct ReadSchema {
  std::uint16_t id = 0;
  std::string name, encoding;
  std::vector<std::uint8_t> data;
};

struct ReadFile {
  bool complete = false;  // footer and trailing magic present, summary checked
  std::string profile, library;
  std::vector<ReadMessage> messages;  // in file order
  std::map<std::uint16_t, ReadChannel> channels;
  std::map<std::uint16_t, ReadSchema> schemas;
  std::vector<std::string> chunk_compressions;
  std::map<std::string, std::map<std::string, std::string>> metadata;
  std::uint64_t statistics_messages = 0;
  std::map<std::uint16_t, std::uint64_t> statistics_channel_counts;
};

class Cursor {
 public:
  Cursor(const std::uint8_t* p, std::size_t n) : p_(p), n_(n) {}
  bool has(std::size_t k) const { return n_ - at_ >= k; }
  std::size_t at() const { return at_; }
  std::size_t left() const { return n_ - at_; }
  std::uint64_t uint(int bytes) {
    need(static_cast<std::size_t>(bytes));
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= std::uint64_t{p_[at_ + i]} << (8 * i);
    at_ += static_cast<std::size_t>(bytes);
    return v;
  }
  std::uint8_t u8() { return static_cast<std::uint8_t>(uint(1)); }
  std::uint16_t u16() { return static_cast<std::uint16_t>(uint(2)); }
  std::uint32_t u32() { return static_cast<std::uint32_t>(uint(4)); }
  std::uint64_t u64() { return uint(8); }
  std::vector<std::uint8_t> bytes(std::size_t k) {
    need(k);
    std::vector<std::uint8_t> v(p_ + at_, p_ + at_ + k);
    at_ += k;
    return v;
  }
  std::string string() {
    const std::uint32_t k = u32();
    need(k);
    std::string s(reinterpret_cast<const char*>(p_ + at_), k);
    at_ += k;
    return s;
  }
  std::map<std::string, std::string> string_map() {
    const std::uint32_t k = u32();
    need(k);
    Cursor inner(p_ + at_, k);
    std::map<std::string, std::string> m;
    while (inner.left() > 0) {
      std::string key = inner.string();
      m[key] = inner.string();
    }
    at_ += k;
    return m;
  }
  const std::uint8_t* here() const { return p_ + at_; }
  void skip(std::size_t k) {
    need(k);
    at_ += k;
  }

 private:
  void need(std::size_t k) const {
    if (!has(k)) throw std::runtime_error("MCAP record field runs past its record");
  }
  const std::uint8_t* p_;
  std::size_t n_;
  std::size_t at_ = 0;
};

inline std::vector<std::uint8_t> decompress(const std::string& compression, const std::uint8_t* p,
                                            std::size_t n, std::uint64_t size) {
  std::vector<std::uint8_t> out(size);
  if (compression.empty()) {
    if (n != size) throw std::runtime_error("uncompressed chunk whose size differs from uncompressed_size");
    out.assign(p, p + n);
  } else if (compression == "zstd") {
    const std::size_t r = ZSTD_decompress(out.data(), out.size(), p, n);
    if (ZSTD_isError(r) != 0U || r != size) throw std::runtime_error("zstd chunk does not decompress");
  } else if (compression == "lz4") {
    LZ4F_dctx* ctx = nullptr;
    LZ4F_createDecompressionContext(&ctx, LZ4F_VERSION);
    std::size_t dst = out.size(), src = n;
    const std::size_t r = LZ4F_decompress(ctx, out.data(), &dst, p, &src, nullptr);
    LZ4F_freeDecompressionContext(ctx);
    if (LZ4F_isError(r) != 0U || dst != size || r != 0)
      throw std::runtime_error("lz4 chunk does not decompress");
  } else {
    throw std::runtime_error("unknown chunk compression '" + compression + "'");
  }
  return out;
}

inline ReadFile read_mcap_bytes(const std::vector<std::uint8_t>& file) {
  static constexpr std::array<std::uint8_t, 8> kMagic = {0x89, 'M', 'C', 'A', 'P', 0x30, '\r', '\n'};
  ReadFile out;
  if (file.size() < 8 || !std::equal(kMagic.begin(), kMagic.end(), file.begin())) {
    throw std::runtime_error("no MCAP magic at the start");
  }
  Cursor c(file.data(), file.size());
  c.skip(8);
  bool in_summary = false;
  std::uint64_t summary_start = 0;
  struct Chunk {
    std::uint64_t offset, length;
    std::vector<std::uint8_t> records;
    std::map<std::uint64_t, std::size_t> message_at;  // offset in records -> index in out.messages
  };
  std::vector<Chunk> chunks;
  std::map<std::uint64_t, std::size_t> chunk_by_offset;
  std::map<std::uint64_t, std::uint16_t> message_index_at;  // file offset of each Message Index -> channel

  auto read_inner = [&](Chunk& chunk) {
    Cursor r(chunk.records.data(), chunk.records.size());
    while (r.left() > 0) {
      const std::size_t record_at = r.at();
      const std::uint8_t op = r.u8();
      const std::uint64_t len = r.u64();
      if (r.left() < len) throw std::runtime_error("chunk record runs past the chunk");
      Cursor body(r.here(), len);
      if (op == 0x03) {
        ReadSchema s;
        s.id = body.u16();
        s.name = body.string();
        s.encoding = body.string();
        s.data = body.bytes(body.u32());
        out.schemas[s.id] = s;
      } else if (op == 0x04) {
        ReadChannel ch;
        ch.id = body.u16();
        ch.schema_id = body.u16();
        ch.topic = body.string();
        ch.message_encoding = body.string();
        body.string_map();
        if (ch.schema_id != 0 && out.schemas.count(ch.schema_id) == 0) {
          throw std::runtime_error("channel before its schema");
        }
        out.channels[ch.id] = ch;
      } else if (op == 0x05) {
        ReadMessage m;
        m.channel_id = body.u16();
        m.sequence = body.u32();
        m.log_time = body.u64();
        m.publish_time = body.u64();
        m.data = body.bytes(body.left());
        const auto ch = out.channels.find(m.channel_id);
        if (ch == out.channels.end()) throw std::runtime_error("message before its channel");
        m.topic = ch->second.topic;
        chunk.message_at[record_at] = out.messages.size();
        out.messages.push_back(std::move(m));
      } else {
        throw std::runtime_error("unexpected record " + std::to_string(op) + " in a chunk");
      }
      r.skip(len);
    }
  };

  while (c.has(9)) {
    const std::size_t record_at = c.at();
    const std::uint8_t op = c.u8();
    const std::uint64_t len = c.u64();
    if (c.left() < len) break;  // cut short: a streaming reader stops here
    Cursor body(c.here(), len);
    switch (op) {
      case 0x01:
        out.profile = body.string();
        out.library = body.string();
        break;
      case 0x06: {
        if (in_summary) throw std::runtime_error("chunk after Data End");
        const std::uint64_t start = body.u64(), end = body.u64(), size = body.u64();
        const std::uint32_t crc = body.u32();
        const std::string compression = body.string();
        const std::uint64_t n = body.u64();
        if (body.left() < n) throw std::runtime_error("chunk records run past the chunk");
        Chunk chunk{record_at, 9 + len, decompress(compression, body.here(), n, size), {}};
        if (crc != 0 && crc32(chunk.records) != crc) throw std::runtime_error("chunk CRC mismatch");
        const std::size_t first = out.messages.size();
        read_inner(chunk);
        for (std::size_t i = first; i < out.messages.size(); ++i) {
          if (out.messages[i].log_time < start || out.messages[i].log_time > end) {
            throw std::runtime_error("message outside its chunk's time range");
          }
        }
        out.chunk_compressions.push_back(compression);
        chunk_by_offset[record_at] = chunks.size();
        chunks.push_back(std::move(chunk));
        break;
      }
      case 0x07: {
        if (chunks.empty()) throw std::runtime_error("message index before any chunk");
        const Chunk& chunk = chunks.back();
        const std::uint16_t channel = body.u16();
        const std::uint32_t n = body.u32();
        std::uint64_t previous = 0;
        std::size_t count = 0;
        for (std::uint32_t i = 0; i < n / 16; ++i) {
          const std::uint64_t time = body.u64(), offset = body.u64();
          const auto m = chunk.message_at.find(offset);
          if (m == chunk.message_at.end()) throw std::runtime_error("message index points at no message");
          const ReadMessage& message = out.messages[m->second];
          if (message.channel_id != channel || message.log_time != time || time < previous) {
            throw std::runtime_error("message index entry does not match its message");
          }
          previous = time;
          ++count;
        }
        std::size_t expected = 0;
        for (const auto& [offset, index] : chunk.message_at)
          expected += out.messages[index].channel_id == channel;
        if (count != expected) throw std::runtime_error("message index misses messages of its channel");
        message_index_at[record_at] = channel;
        break;
      }
      case 0x0C: {
        const std::string name = body.string();
        out.metadata[name] = body.string_map();
        break;
      }
      case 0x0F: {
        const std::uint32_t crc = body.u32();
        if (crc != 0 && crc != crc32({file.data(), record_at}))
          throw std::runtime_error("data section CRC mismatch");
        in_summary = true;
        summary_start = record_at + 9 + len;
        break;
      }
      case 0x08: {
        const std::uint64_t start = body.u64(), end = body.u64(), offset = body.u64(), length = body.u64();
        (void)start;
        (void)end;
        const auto it = chunk_by_offset.find(offset);
        if (it == chunk_by_offset.end() || chunks[it->second].length != length) {
          throw std::runtime_error("chunk index does not point at its chunk");
        }
        const std::uint32_t map_len = body.u32();
        for (std::uint32_t i = 0; i < map_len / 10; ++i) {
          const std::uint16_t channel = body.u16();
          const std::uint64_t at = body.u64();
          const auto mi = message_index_at.find(at);
          if (mi == message_index_at.end() || mi->second != channel) {
            throw std::runtime_error("chunk index names a message index that is not there");
          }
        }
        break;
      }
      case 0x0B: {
        out.statistics_messages = body.u64();
        body.u16();
        body.u32();
        body.u32();
        body.u32();
        const std::uint32_t chunk_count = body.u32();
        if (chunk_count != chunks.size()) throw std::runtime_error("statistics chunk count is wrong");
        body.u64();
        body.u64();
        const std::uint32_t map_len = body.u32();
        for (std::uint32_t i = 0; i < map_len / 10; ++i) {
          const std::uint16_t channel = body.u16();
          out.statistics_channel_counts[channel] = body.u64();
        }
        break;
      }
      case 0x02: {
        const std::uint64_t summary_at = body.u64();
        body.u64();
        const std::uint32_t crc = body.u32();
        if (summary_at != summary_start) throw std::runtime_error("footer summary_start is wrong");
        if (crc != 0 && crc != crc32({file.data() + summary_start, record_at + 1 + 8 + 16 - summary_start})) {
          throw std::runtime_error("summary CRC mismatch");
        }
        c.skip(len);
        if (!c.has(8) || !std::equal(kMagic.begin(), kMagic.end(), c.here())) {
          throw std::runtime_error("no MCAP magic after the footer");
        }
        out.complete = true;
        if (out.statistics_messages != out.messages.size())
          throw std::runtime_error("statistics message count");
        return out;
      }
      default:
        break;  // Schema/Channel duplicates, indexes and offsets of the summary
    }
    c.skip(len);
  }
  return out;
}

inline ReadFile read_mcap(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return read_mcap_bytes(bytes);
}

}  // namespace tendril::record::test
