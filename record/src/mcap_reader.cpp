#include "tendril/record/mcap_reader.hpp"

#include <fcntl.h>
#include <lz4frame.h>
#include <sys/stat.h>
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

constexpr std::uint8_t kHeader = 0x01, kFooter = 0x02, kSchema = 0x03, kChannel = 0x04, kMessage = 0x05,
                       kChunk = 0x06, kChunkIndex = 0x08, kStatistics = 0x0B, kMetadata = 0x0C,
                       kMetadataIndex = 0x0D, kDataEnd = 0x0F;
constexpr std::array<std::uint8_t, 8> kMagic = {0x89, 'M', 'C', 'A', 'P', 0x30, '\r', '\n'};
constexpr std::uint64_t kRecordHead = 9;                          // opcode + uint64 length
constexpr std::uint64_t kFooterRecord = kRecordHead + 8 + 8 + 4;  // summary_start, offset_start, crc

std::string hex(std::uint8_t op) {
  static constexpr char kDigits[] = "0123456789abcdef";
  return std::string("0x") + kDigits[op >> 4] + kDigits[op & 0xF];
}

// Reads little-endian fields from a span; a field that runs past the end throws Short, which the
// reader turns into a McapFormatError naming the record.
struct Short {};
class Fields {
 public:
  Fields(const std::uint8_t* p, std::uint64_t n) : p_(p), n_(n) {}
  std::uint64_t left() const { return n_ - at_; }
  std::uint64_t at() const { return at_; }
  const std::uint8_t* here() const { return p_ + at_; }
  std::uint64_t uint(int bytes) {
    need(static_cast<std::uint64_t>(bytes));
    std::uint64_t v = 0;
    for (int i = 0; i < bytes; ++i) v |= std::uint64_t{p_[at_ + static_cast<std::uint64_t>(i)]} << (8 * i);
    at_ += static_cast<std::uint64_t>(bytes);
    return v;
  }
  std::uint8_t u8() { return static_cast<std::uint8_t>(uint(1)); }
  std::uint16_t u16() { return static_cast<std::uint16_t>(uint(2)); }
  std::uint32_t u32() { return static_cast<std::uint32_t>(uint(4)); }
  std::uint64_t u64() { return uint(8); }
  void skip(std::uint64_t k) {
    need(k);
    at_ += k;
  }
  std::string string() {
    const std::uint32_t k = u32();
    need(k);
    std::string s(reinterpret_cast<const char*>(p_ + at_), k);
    at_ += k;
    return s;
  }
  std::vector<std::uint8_t> bytes(std::uint64_t k) {
    need(k);
    std::vector<std::uint8_t> v(p_ + at_, p_ + at_ + k);
    at_ += k;
    return v;
  }
  std::map<std::string, std::string> string_map() {
    const std::uint32_t k = u32();
    need(k);
    Fields inner(p_ + at_, k);
    std::map<std::string, std::string> m;
    while (inner.left() > 0) {
      std::string key = inner.string();
      m[std::move(key)] = inner.string();
    }
    at_ += k;
    return m;
  }

 private:
  void need(std::uint64_t k) const {
    if (k > n_ - at_) throw Short{};
  }
  const std::uint8_t* p_;
  std::uint64_t n_;
  std::uint64_t at_ = 0;
};

McapSchema parse_schema(Fields& f) {
  McapSchema s;
  s.id = f.u16();
  s.name = f.string();
  s.encoding = f.string();
  s.data = f.bytes(f.u32());
  return s;
}

McapChannel parse_channel(Fields& f) {
  McapChannel c;
  c.id = f.u16();
  c.schema_id = f.u16();
  c.topic = f.string();
  c.message_encoding = f.string();
  c.metadata = f.string_map();
  return c;
}

}  // namespace

// Where the bytes come from: the file (pread, so a large recording is never read whole) or memory.
struct McapReader::Source {
  int fd = -1;
  std::vector<std::uint8_t> memory;
  std::uint64_t size = 0;

  ~Source() {
    if (fd >= 0) ::close(fd);
  }
  // Exactly n bytes at offset; the caller has checked offset + n <= size.
  void read(std::uint64_t offset, std::uint8_t* out, std::uint64_t n, const std::string& name) const {
    if (n == 0) return;  // an empty record's body: out may be null
    if (fd < 0) {
      std::memcpy(out, memory.data() + offset, n);
      return;
    }
    while (n > 0) {
      const ssize_t got = ::pread(fd, out, n, static_cast<off_t>(offset));
      if (got < 0) {
        if (errno == EINTR) continue;
        throw McapError("cannot read MCAP file " + name + ": " + std::strerror(errno));
      }
      if (got == 0) throw McapError("MCAP file " + name + " became shorter while it was read");
      out += got;
      offset += static_cast<std::uint64_t>(got);
      n -= static_cast<std::uint64_t>(got);
    }
  }
  std::vector<std::uint8_t> read(std::uint64_t offset, std::uint64_t n, const std::string& name) const {
    std::vector<std::uint8_t> v(n);
    read(offset, v.data(), n, name);
    return v;
  }
};

McapReader::McapReader(const std::filesystem::path& path, McapReaderOptions options)
    : name_(path.string()), options_(options), source_(std::make_unique<Source>()) {
  source_->fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (source_->fd < 0) throw McapError("cannot open MCAP file " + name_ + ": " + std::strerror(errno));
  struct stat st {};
  if (::fstat(source_->fd, &st) != 0) throw McapError("cannot stat " + name_ + ": " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) throw McapError(name_ + " is not a regular file");
  source_->size = static_cast<std::uint64_t>(st.st_size);
  open();
}

McapReader::McapReader(std::vector<std::uint8_t> bytes, std::string name, McapReaderOptions options)
    : name_(std::move(name)), options_(options), source_(std::make_unique<Source>()) {
  source_->memory = std::move(bytes);
  source_->size = source_->memory.size();
  open();
}

McapReader::~McapReader() = default;
McapReader::McapReader(McapReader&&) noexcept = default;
McapReader& McapReader::operator=(McapReader&&) noexcept = default;

void McapReader::fail(std::uint64_t offset, const std::string& what) const {
  throw McapFormatError("MCAP file " + name_ + ", byte " + std::to_string(offset) + ": " + what);
}

const McapSchema* McapReader::schema_of(const McapChannel& channel) const {
  if (channel.schema_id == 0) return nullptr;
  const auto it = schemas_.find(channel.schema_id);
  return it == schemas_.end() ? nullptr : &it->second;
}

void McapReader::open() {
  const std::uint64_t size = source_->size;
  if (size < kMagic.size()) fail(0, "too short for an MCAP file (" + std::to_string(size) + " bytes)");
  std::array<std::uint8_t, 8> magic{};
  source_->read(0, magic.data(), magic.size(), name_);
  if (magic != kMagic)
    fail(0, "not an MCAP file (the magic bytes \\x89MCAP0\\r\\n are missing at the start)");
  // The Header comes first, in finalised and cut files alike.
  std::array<std::uint8_t, kRecordHead> head{};
  if (size - kMagic.size() < kRecordHead) fail(kMagic.size(), "no Header record after the magic");
  source_->read(kMagic.size(), head.data(), head.size(), name_);
  Fields h(head.data(), head.size());
  const std::uint8_t op = h.u8();
  const std::uint64_t len = h.u64();
  if (op != kHeader) fail(kMagic.size(), "the first record is " + hex(op) + ", not the Header");
  if (len > size - kMagic.size() - kRecordHead) fail(kMagic.size(), "the Header record is cut short");
  if (len > (std::uint64_t{1} << 20))
    fail(kMagic.size(), "a Header record of " + std::to_string(len) + " bytes");
  const std::vector<std::uint8_t> header = source_->read(kMagic.size() + kRecordHead, len, name_);
  Fields body(header.data(), header.size());
  try {
    profile_ = body.string();
    library_ = body.string();
  } catch (const Short&) {
    fail(kMagic.size(), "the Header record is shorter than its fields");
  }
  if (!read_summary()) stream();
}

bool McapReader::read_summary() {
  const std::uint64_t size = source_->size;
  if (size < 2 * kMagic.size() + kFooterRecord) return false;
  const std::uint64_t footer_at = size - kMagic.size() - kFooterRecord;
  std::array<std::uint8_t, kFooterRecord + 8> tail{};
  source_->read(footer_at, tail.data(), tail.size(), name_);
  if (!std::equal(kMagic.begin(), kMagic.end(), tail.end() - 8)) return false;  // unfinished: stream
  Fields footer(tail.data(), kFooterRecord);
  // The magic without a Footer before it: the end of a cut file that happens to look like the magic.
  if (footer.u8() != kFooter || footer.u64() != kFooterRecord - kRecordHead) return false;
  const std::uint64_t summary_start = footer.u64();
  footer.u64();  // summary_offset_start: the groups are found by reading the whole summary
  const std::uint32_t summary_crc = footer.u32();
  finalised_ = true;
  if (summary_start == 0) return false;  // no summary: index by streaming
  if (summary_start < kMagic.size() + kRecordHead || summary_start > footer_at) {
    fail(footer_at, "the Footer's summary_start " + std::to_string(summary_start) + " is outside the file");
  }
  // The summary, the summary offsets and the footer up to its CRC field.
  const std::vector<std::uint8_t> summary =
      source_->read(summary_start, footer_at + kFooterRecord - 4 - summary_start, name_);
  if (summary_crc != 0 && crc32(summary) != summary_crc) {
    fail(summary_start, "summary CRC mismatch (the summary section is damaged)");
  }

  // The Data End record ends the data section, just before the summary.
  const std::uint64_t data_end_at = summary_start - kRecordHead - 4;
  std::array<std::uint8_t, kRecordHead + 4> data_end{};
  if (summary_start < kMagic.size() + data_end.size()) fail(summary_start, "no Data End record");
  source_->read(data_end_at, data_end.data(), data_end.size(), name_);
  Fields de(data_end.data(), data_end.size());
  if (de.u8() != kDataEnd || de.u64() != 4) {
    fail(data_end_at, "expected the Data End record just before the summary (summary_start " +
                          std::to_string(summary_start) + ")");
  }
  const std::uint32_t data_crc = de.u32();
  if (options_.check_data_crc && data_crc != 0) {
    std::uint32_t crc = 0;
    std::vector<std::uint8_t> block(std::uint64_t{1} << 20);
    for (std::uint64_t at = 0; at < data_end_at;) {
      const std::uint64_t n = std::min<std::uint64_t>(block.size(), data_end_at - at);
      source_->read(at, block.data(), n, name_);
      crc = crc32({block.data(), n}, crc);
      at += n;
    }
    if (crc != data_crc) fail(data_end_at, "data section CRC mismatch (the recording's data is damaged)");
  }

  bool have_statistics = false, have_chunk_index = false;
  std::vector<std::pair<std::uint64_t, std::uint64_t>> metadata_at;        // offset, length
  const std::uint64_t records_end = summary.size() - (kFooterRecord - 4);  // the footer is not a group
  Fields f(summary.data(), records_end);
  while (f.left() > 0) {
    const std::uint64_t at = summary_start + f.at();
    std::uint8_t op = 0;
    std::uint64_t len = 0;
    try {
      op = f.u8();
      len = f.u64();
    } catch (const Short&) {
      fail(at, "a summary record's header runs past the summary");
    }
    if (len > f.left()) fail(at, "summary record " + hex(op) + " runs past the summary");
    Fields body(f.here(), len);
    try {
      switch (op) {
        case kSchema: {
          McapSchema s = parse_schema(body);
          if (s.id == 0) fail(at, "schema id 0 is reserved (it means: no schema)");
          schemas_.try_emplace(s.id, std::move(s));
          break;
        }
        case kChannel: {
          McapChannel c = parse_channel(body);
          channels_.try_emplace(c.id, std::move(c));
          break;
        }
        case kChunkIndex: {
          ChunkRef ref;
          ref.start_time = body.u64();
          ref.end_time = body.u64();
          ref.offset = body.u64();
          ref.length = body.u64();
          if (ref.start_time > ref.end_time) fail(at, "a Chunk Index whose start time is after its end");
          if (ref.offset < kMagic.size() || ref.length < kRecordHead || ref.offset > data_end_at ||
              ref.length > data_end_at - ref.offset) {
            fail(at, "a Chunk Index points outside the data section (offset " + std::to_string(ref.offset) +
                         ", length " + std::to_string(ref.length) + ")");
          }
          chunks_.push_back(ref);
          have_chunk_index = true;
          break;
        }
        case kStatistics:
          message_count_ = body.u64();
          body.u16();
          body.u32();
          body.u32();
          body.u32();
          body.u32();
          start_time_ = body.u64();
          end_time_ = body.u64();
          have_statistics = true;
          break;
        case kMetadataIndex: {
          const std::uint64_t offset = body.u64(), length = body.u64();
          if (offset < kMagic.size() || length < kRecordHead || offset > data_end_at ||
              length > data_end_at - offset) {
            fail(at, "a Metadata Index points outside the data section");
          }
          metadata_at.emplace_back(offset, length);
          break;
        }
        default:
          break;  // Summary Offsets, Attachment Indexes, and records of later spec versions
      }
    } catch (const Short&) {
      fail(at, "summary record " + hex(op) + " is shorter than its fields");
    }
    f.skip(len);
  }
  if (!have_statistics || (!have_chunk_index && message_count_ > 0)) {
    // A summary without what the index needs (another writer's choice): read the file by streaming.
    schemas_.clear();
    channels_.clear();
    chunks_.clear();
    message_count_ = start_time_ = end_time_ = 0;
    return false;
  }
  for (const auto& [id, channel] : channels_) {
    if (channel.schema_id != 0 && schemas_.count(channel.schema_id) == 0) {
      fail(summary_start, "channel " + std::to_string(id) + " ('" + channel.topic + "') names schema " +
                              std::to_string(channel.schema_id) + ", which the summary does not hold");
    }
  }
  std::sort(chunks_.begin(), chunks_.end(),
            [](const ChunkRef& a, const ChunkRef& b) { return a.offset < b.offset; });
  for (const auto& [offset, length] : metadata_at) {
    const std::vector<std::uint8_t> record = source_->read(offset, length, name_);
    Fields m(record.data(), record.size());
    try {
      if (m.u8() != kMetadata || m.u64() != length - kRecordHead) {
        fail(offset, "the Metadata Index does not point at a Metadata record");
      }
      std::string name = m.string();
      metadata_[std::move(name)] = m.string_map();
    } catch (const Short&) {
      fail(offset, "a Metadata record is shorter than its fields");
    }
  }
  return true;
}

void McapReader::stream() {
  const std::uint64_t size = source_->size;
  std::uint64_t pos = kMagic.size();
  bool first = true;
  bool have_times = false;
  while (true) {
    if (size - pos < kRecordHead) {
      truncated_bytes_ = size - pos;
      break;
    }
    std::array<std::uint8_t, kRecordHead> head{};
    source_->read(pos, head.data(), head.size(), name_);
    Fields h(head.data(), head.size());
    const std::uint8_t op = h.u8();
    const std::uint64_t len = h.u64();
    if (len > size - pos - kRecordHead) {
      // The record runs past the end: the process stopped while writing it. Everything before is whole.
      truncated_bytes_ = size - pos;
      break;
    }
    if (first && op != kHeader) fail(pos, "the first record is " + hex(op) + ", not the Header");
    first = false;
    if (op == kChunk) {
      ChunkRef ref;
      const std::vector<std::uint8_t> records = chunk_records(pos, kRecordHead + len, &ref);
      Fields r(records.data(), records.size());
      while (r.left() > 0) {
        const std::uint64_t inner_at = r.at();
        try {
          const std::uint8_t iop = r.u8();
          const std::uint64_t ilen = r.u64();
          if (ilen > r.left()) throw Short{};
          Fields body(r.here(), ilen);
          if (iop == kSchema) {
            McapSchema s = parse_schema(body);
            if (s.id == 0) fail(pos, "schema id 0 is reserved (it means: no schema)");
            schemas_.try_emplace(s.id, std::move(s));
          } else if (iop == kChannel) {
            McapChannel c = parse_channel(body);
            if (c.schema_id != 0 && schemas_.count(c.schema_id) == 0) {
              fail(pos, "channel '" + c.topic + "' comes before its schema " + std::to_string(c.schema_id));
            }
            channels_.try_emplace(c.id, std::move(c));
          } else if (iop == kMessage) {
            const std::uint16_t channel = body.u16();
            body.u32();
            const std::uint64_t log_time = body.u64();
            if (channels_.count(channel) == 0) {
              fail(pos,
                   "a message on channel " + std::to_string(channel) + " before that channel is defined");
            }
            if (log_time < ref.start_time || log_time > ref.end_time) {
              fail(pos, "a message's log time is outside its chunk's time range");
            }
            if (!have_times || log_time < start_time_) start_time_ = log_time;
            if (!have_times || log_time > end_time_) end_time_ = log_time;
            have_times = true;
            ++message_count_;
          } else {
            fail(pos,
                 "record " + hex(iop) + " inside a chunk (only Schema, Channel and Message belong there)");
          }
          r.skip(ilen);
        } catch (const Short&) {
          fail(pos, "the chunk's record at " + std::to_string(inner_at) + " is shorter than its fields");
        }
      }
      chunks_.push_back(ref);
    } else {
      const std::vector<std::uint8_t> record = source_->read(pos + kRecordHead, len, name_);
      Fields body(record.data(), record.size());
      try {
        switch (op) {
          case kHeader:
            break;  // read by open()
          case kSchema: {
            McapSchema s = parse_schema(body);
            if (s.id == 0) fail(pos, "schema id 0 is reserved (it means: no schema)");
            schemas_.try_emplace(s.id, std::move(s));
            break;
          }
          case kChannel: {
            McapChannel c = parse_channel(body);
            channels_.try_emplace(c.id, std::move(c));
            break;
          }
          case kMessage:
            fail(pos, "a Message outside any chunk; this reader reads chunked MCAP files only");
          case kMetadata: {
            std::string name = body.string();
            metadata_[std::move(name)] = body.string_map();
            break;
          }
          default:
            break;  // Message Indexes (the reader sorts each chunk itself), attachments, later records
        }
      } catch (const Short&) {
        fail(pos, "record " + hex(op) + " is shorter than its fields");
      }
      if (op == kDataEnd) break;  // the summary follows; what it indexes has been read
    }
    pos += kRecordHead + len;
  }
  if (first) fail(pos, "no Header record after the magic");
}

std::vector<std::uint8_t> McapReader::chunk_records(std::uint64_t offset, std::uint64_t length,
                                                    ChunkRef* ref_out) const {
  if (offset > source_->size || length > source_->size - offset || length < kRecordHead) {
    fail(offset, "a chunk outside the file");
  }
  // Compressed data can be a little larger than the records (lz4 and zstd framing of incompressible
  // bytes); anything far beyond the limit is refused before it is read.
  if (length > options_.max_chunk_bytes + options_.max_chunk_bytes / 8 + 4096) {
    fail(offset, "a chunk record of " + std::to_string(length) + " bytes, more than this reader accepts");
  }
  const std::vector<std::uint8_t> record = source_->read(offset, length, name_);
  Fields f(record.data(), record.size());
  std::uint64_t start = 0, end = 0, size = 0, n = 0;
  std::uint32_t crc = 0;
  std::string compression;
  try {
    if (f.u8() != kChunk) fail(offset, "expected a Chunk record here (the chunk index points elsewhere)");
    if (f.u64() != length - kRecordHead) fail(offset, "the Chunk record's length disagrees with its index");
    start = f.u64();
    end = f.u64();
    size = f.u64();
    crc = f.u32();
    compression = f.string();
    n = f.u64();
    if (n > f.left()) throw Short{};
  } catch (const Short&) {
    fail(offset, "the Chunk record is shorter than its fields");
  }
  if (start > end) fail(offset, "a chunk whose start time is after its end time");
  if (size > options_.max_chunk_bytes) {
    fail(offset, "a chunk of " + std::to_string(size) + " bytes uncompressed, more than the " +
                     std::to_string(options_.max_chunk_bytes) + " this reader accepts");
  }
  const std::uint8_t* p = f.here();
  std::vector<std::uint8_t> out(size);
  if (compression.empty()) {
    if (n != size) fail(offset, "an uncompressed chunk whose size differs from its uncompressed_size");
    std::copy(p, p + n, out.begin());
  } else if (compression == "zstd") {
    const std::size_t r = ZSTD_decompress(out.data(), out.size(), p, n);
    if (ZSTD_isError(r) != 0U)
      fail(offset, std::string("the zstd chunk does not decompress: ") + ZSTD_getErrorName(r));
    if (r != size)
      fail(offset,
           "the zstd chunk decompresses to " + std::to_string(r) + " bytes, not " + std::to_string(size));
  } else if (compression == "lz4") {
    LZ4F_dctx* ctx = nullptr;
    if (LZ4F_isError(LZ4F_createDecompressionContext(&ctx, LZ4F_VERSION)) != 0U) {
      throw McapError("MCAP: lz4 could not allocate a decompression context");
    }
    std::size_t in = 0, produced = 0, hint = 1;
    std::string error;
    while (hint != 0) {
      std::size_t dst = out.size() - produced, src = n - in;
      hint = LZ4F_decompress(ctx, out.data() + produced, &dst, p + in, &src, nullptr);
      if (LZ4F_isError(hint) != 0U) {
        error = LZ4F_getErrorName(hint);
        break;
      }
      produced += dst;
      in += src;
      if (dst == 0 && src == 0 && hint != 0) {
        error = "the frame does not end where the chunk does";
        break;
      }
    }
    LZ4F_freeDecompressionContext(ctx);
    if (!error.empty()) fail(offset, "the lz4 chunk does not decompress: " + error);
    if (produced != size || in != n) {
      fail(offset, "the lz4 chunk decompresses to " + std::to_string(produced) + " bytes from " +
                       std::to_string(in) + " of " + std::to_string(n) + ", expected " +
                       std::to_string(size));
    }
  } else {
    fail(offset, "chunk compression '" + compression + "' is not one this reader knows (zstd, lz4 or none)");
  }
  if (crc != 0 && crc32(out) != crc) fail(offset, "chunk CRC mismatch (the chunk is damaged)");
  if (ref_out != nullptr) *ref_out = ChunkRef{offset, length, start, end};
  return out;
}

std::vector<McapMessage> McapReader::read_chunk(std::size_t i) const {
  if (i >= chunks_.size()) {
    throw std::out_of_range("chunk " + std::to_string(i) + " of " + std::to_string(chunks_.size()) + " in " +
                            name_);
  }
  const ChunkRef& ref = chunks_[i];
  const std::vector<std::uint8_t> records = chunk_records(ref.offset, ref.length, nullptr);
  std::vector<McapMessage> messages;
  Fields r(records.data(), records.size());
  while (r.left() > 0) {
    const std::uint64_t inner_at = r.at();
    try {
      const std::uint8_t op = r.u8();
      const std::uint64_t len = r.u64();
      if (len > r.left()) throw Short{};
      if (op == kMessage) {
        Fields body(r.here(), len);
        McapMessage m;
        m.channel_id = body.u16();
        m.sequence = body.u32();
        m.log_time = body.u64();
        m.publish_time = body.u64();
        m.data = body.bytes(body.left());
        if (channels_.count(m.channel_id) == 0) {
          fail(ref.offset,
               "a message on channel " + std::to_string(m.channel_id) + ", which the file does not define");
        }
        if (m.log_time < ref.start_time || m.log_time > ref.end_time) {
          fail(ref.offset, "a message's log time is outside its chunk's time range");
        }
        messages.push_back(std::move(m));
      } else if (op != kSchema && op != kChannel) {
        fail(ref.offset,
             "record " + hex(op) + " inside a chunk (only Schema, Channel and Message belong there)");
      }
      r.skip(len);
    } catch (const Short&) {
      fail(ref.offset, "the chunk's record at " + std::to_string(inner_at) + " is shorter than its fields");
    }
  }
  std::stable_sort(messages.begin(), messages.end(),
                   [](const McapMessage& a, const McapMessage& b) { return a.log_time < b.log_time; });
  return messages;
}

// ---- McapMessageCursor ----------------------------------------------------------------------------

namespace {
// std heap functions build a max-heap: "greater" puts the earliest message on top.
struct Later {
  template <typename P>
  bool operator()(const P& a, const P& b) const {
    if (a.log_time != b.log_time) return a.log_time > b.log_time;
    if (a.chunk_order != b.chunk_order) return a.chunk_order > b.chunk_order;
    return a.index > b.index;
  }
};
}  // namespace

McapMessageCursor::McapMessageCursor(std::vector<const McapReader*> readers, std::uint64_t start_time)
    : readers_(std::move(readers)) {
  for (std::size_t r = 0; r < readers_.size(); ++r) {
    const auto& chunks = readers_[r]->chunks();
    for (std::size_t c = 0; c < chunks.size(); ++c) {
      slots_.push_back(ChunkSlot{r, c, chunks[c].start_time, chunks[c].end_time, {}});
    }
  }
  std::stable_sort(slots_.begin(), slots_.end(),
                   [](const ChunkSlot& a, const ChunkSlot& b) { return a.start_time < b.start_time; });
  seek(start_time);
}

void McapMessageCursor::seek(std::uint64_t start_time) {
  start_time_ = start_time;
  heap_.clear();
  for (auto& slot : slots_) slot.messages = {};
  next_slot_ = 0;
}

void McapMessageCursor::load(std::size_t slot_index) {
  ChunkSlot& slot = slots_[slot_index];
  if (slot.end_time < start_time_) return;  // wholly before the start: never decompressed
  slot.messages = readers_[slot.reader]->read_chunk(slot.chunk);
  const auto first = std::lower_bound(slot.messages.begin(), slot.messages.end(), start_time_,
                                      [](const McapMessage& m, std::uint64_t t) { return m.log_time < t; });
  if (first == slot.messages.end()) {
    slot.messages = {};
    return;
  }
  heap_.push_back(
      Pending{first->log_time, slot_index, static_cast<std::size_t>(first - slot.messages.begin())});
  std::push_heap(heap_.begin(), heap_.end(), Later{});
}

bool McapMessageCursor::next(Item& out) {
  // Decompress every chunk that starts no later than the earliest pending message: one of its messages
  // may come first.
  while (next_slot_ < slots_.size() &&
         (heap_.empty() || slots_[next_slot_].start_time <= heap_.front().log_time)) {
    load(next_slot_++);
  }
  if (heap_.empty()) return false;
  std::pop_heap(heap_.begin(), heap_.end(), Later{});
  const Pending top = heap_.back();
  heap_.pop_back();
  ChunkSlot& slot = slots_[top.chunk_order];
  const McapReader& reader = *readers_[slot.reader];
  out.reader = slot.reader;
  out.message = std::move(slot.messages[top.index]);
  const auto channel = reader.channels().find(out.message.channel_id);
  out.channel = &channel->second;  // read_chunk checked that the channel exists
  out.schema = reader.schema_of(channel->second);
  if (top.index + 1 < slot.messages.size()) {
    heap_.push_back(Pending{slot.messages[top.index + 1].log_time, top.chunk_order, top.index + 1});
    std::push_heap(heap_.begin(), heap_.end(), Later{});
  } else {
    slot.messages = {};  // done with this chunk
  }
  return true;
}

std::vector<std::filesystem::path> mcap_files(const std::filesystem::path& file_or_folder) {
  std::error_code ec;
  const auto status = std::filesystem::status(file_or_folder, ec);
  if (ec || !std::filesystem::exists(status)) {
    throw McapError("no such MCAP file or folder: " + file_or_folder.string());
  }
  if (std::filesystem::is_regular_file(status)) return {file_or_folder};
  std::vector<std::filesystem::path> files;
  if (std::filesystem::is_directory(status)) {
    for (const auto& entry : std::filesystem::directory_iterator(file_or_folder, ec)) {
      if (entry.is_regular_file() && entry.path().extension() == ".mcap") files.push_back(entry.path());
    }
    if (ec) throw McapError("cannot list " + file_or_folder.string() + ": " + ec.message());
  }
  if (files.empty()) throw McapError("no .mcap files in " + file_or_folder.string());
  std::sort(files.begin(), files.end());
  return files;
}

}  // namespace tendril::record
