#include "tendril/server/foxglove_protobuf.hpp"

#include "protobuf_descriptors.hpp"

namespace tendril::server::protobuf {

namespace {
constexpr std::uint32_t kVarint = 0;
constexpr std::uint32_t kLengthDelimited = 2;

void append_key(std::uint32_t field, std::uint32_t wire_type, std::string& out) {
  append_varint((static_cast<std::uint64_t>(field) << 3) | wire_type, out);
}
}  // namespace

void append_varint(std::uint64_t value, std::string& out) {
  while (value >= 0x80) {
    out.push_back(static_cast<char>((value & 0x7F) | 0x80));
    value >>= 7;
  }
  out.push_back(static_cast<char>(value));
}

void append_length_delimited(std::uint32_t field, std::string_view bytes, std::string& out) {
  append_key(field, kLengthDelimited, out);
  append_varint(bytes.size(), out);
  out.append(bytes);
}

void append_compressed_image(std::uint64_t stamp_ns, std::string_view frame_id,
                             std::span<const std::uint8_t> data, std::string_view format, std::string& out) {
  // google.protobuf.Timestamp {seconds = 1, nanos = 2}; proto3 leaves zero fields out.
  std::string timestamp;
  const std::uint64_t seconds = stamp_ns / 1'000'000'000ULL;
  const std::uint64_t nanos = stamp_ns % 1'000'000'000ULL;
  if (seconds != 0) {
    append_key(1, kVarint, timestamp);
    append_varint(seconds, timestamp);
  }
  if (nanos != 0) {
    append_key(2, kVarint, timestamp);
    append_varint(nanos, timestamp);
  }
  out.reserve(out.size() + data.size() + timestamp.size() + frame_id.size() + format.size() + 24);
  append_length_delimited(1, timestamp, out);
  if (!data.empty())
    append_length_delimited(2, {reinterpret_cast<const char*>(data.data()), data.size()}, out);
  if (!format.empty()) append_length_delimited(3, format, out);
  if (!frame_id.empty()) append_length_delimited(4, frame_id, out);
}

std::string compressed_image_descriptor_set() {
  const auto& bytes = protobuf_descriptors::kCompressedImage;
  return {reinterpret_cast<const char*>(bytes), sizeof bytes};
}

}  // namespace tendril::server::protobuf
