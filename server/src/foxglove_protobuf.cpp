#include "tendril/server/foxglove_protobuf.hpp"

#include <cmath>
#include <cstring>

#include "protobuf_descriptors.hpp"

namespace tendril::server::protobuf {

namespace {
constexpr std::uint32_t kVarint = 0;
constexpr std::uint32_t kFixed64 = 1;
constexpr std::uint32_t kLengthDelimited = 2;

void append_key(std::uint32_t field, std::uint32_t wire_type, std::string& out) {
  append_varint((static_cast<std::uint64_t>(field) << 3) | wire_type, out);
}

// A double field (fixed64, little-endian IEEE 754); proto3 leaves 0 out.
void append_double(std::uint32_t field, double value, std::string& out) {
  if (value == 0.0) return;
  append_key(field, kFixed64, out);
  std::uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<char>((bits >> (8 * i)) & 0xFF));
}

// google.protobuf.Timestamp {seconds = 1, nanos = 2}; proto3 leaves zero fields out.
std::string timestamp_message(std::uint64_t stamp_ns) {
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
  return timestamp;
}

std::string point2_message(const std::array<double, 2>& p) {
  std::string out;
  append_double(1, p[0], out);
  append_double(2, p[1], out);
  return out;
}

std::string color_message(const Rgba& c) {
  std::string out;
  append_double(1, c.r, out);
  append_double(2, c.g, out);
  append_double(3, c.b, out);
  append_double(4, c.a, out);
  return out;
}

bool finite(const std::array<double, 2>& p) { return std::isfinite(p[0]) && std::isfinite(p[1]); }
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
  const std::string timestamp = timestamp_message(stamp_ns);
  out.reserve(out.size() + data.size() + timestamp.size() + frame_id.size() + format.size() + 24);
  append_length_delimited(1, timestamp, out);
  if (!data.empty())
    append_length_delimited(2, {reinterpret_cast<const char*>(data.data()), data.size()}, out);
  if (!format.empty()) append_length_delimited(3, format, out);
  if (!frame_id.empty()) append_length_delimited(4, frame_id, out);
}

void append_image_annotations(std::uint64_t stamp_ns, std::span<const CircleAnnotation> circles,
                              std::span<const PointsAnnotation> points, std::string& out) {
  const std::string timestamp = timestamp_message(stamp_ns);
  std::string item;
  for (const auto& c : circles) {
    if (!finite(c.position) || !std::isfinite(c.diameter) || !std::isfinite(c.thickness)) continue;
    item.clear();
    append_length_delimited(1, timestamp, item);
    append_length_delimited(2, point2_message(c.position), item);
    append_double(3, c.diameter, item);
    append_double(4, c.thickness, item);
    append_length_delimited(5, color_message(c.fill), item);
    append_length_delimited(6, color_message(c.outline), item);
    append_length_delimited(1, item, out);  // ImageAnnotations.circles
  }
  for (const auto& p : points) {
    item.clear();
    append_length_delimited(1, timestamp, item);
    append_key(2, kVarint, item);
    append_varint(static_cast<std::uint64_t>(p.type), item);
    for (const auto& q : p.points)
      if (finite(q)) append_length_delimited(3, point2_message(q), item);
    append_length_delimited(4, color_message(p.outline), item);
    if (std::isfinite(p.thickness)) append_double(7, p.thickness, item);
    append_length_delimited(2, item, out);  // ImageAnnotations.points
  }
}

std::string image_annotations_descriptor_set() {
  const auto& bytes = protobuf_descriptors::kImageAnnotations;
  return {reinterpret_cast<const char*>(bytes), sizeof bytes};
}

std::string compressed_image_descriptor_set() {
  const auto& bytes = protobuf_descriptors::kCompressedImage;
  return {reinterpret_cast<const char*>(bytes), sizeof bytes};
}

}  // namespace tendril::server::protobuf
