// Foxglove's message schemas in their protobuf encoding, written directly (the few fields tendril
// sends do not justify libprotobuf): the wire format of the messages and the FileDescriptorSet that
// describes them (compiled from server/proto by protoc at build time). Binary messages travel without
// base64 or JSON text around them, so an image costs the server its bytes and nothing more.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace tendril::server::protobuf {

// foxglove.CompressedImage {timestamp = 1, data = 2, format = 3, frame_id = 4} appended to `out`.
void append_compressed_image(std::uint64_t stamp_ns, std::string_view frame_id,
                             std::span<const std::uint8_t> data, std::string_view format, std::string& out);

// The FileDescriptorSet of foxglove.CompressedImage with its import (google/protobuf/timestamp.proto).
std::string compressed_image_descriptor_set();

// foxglove.Color, components 0..1.
struct Rgba {
  double r = 0.0, g = 0.0, b = 0.0, a = 1.0;
};

// foxglove.PointsAnnotation.Type
enum class PointsType : std::uint8_t { kPoints = 1, kLineLoop = 2, kLineStrip = 3, kLineList = 4 };

// One foxglove.PointsAnnotation: pixels [column, row] from the top-left corner of the image.
struct PointsAnnotation {
  PointsType type = PointsType::kLineStrip;
  std::vector<std::array<double, 2>> points;
  Rgba outline;
  double thickness = 1.0;
};

// One foxglove.CircleAnnotation (filled when `fill.a` > 0).
struct CircleAnnotation {
  std::array<double, 2> position{};
  double diameter = 0.0;
  double thickness = 1.0;
  Rgba fill{0.0, 0.0, 0.0, 0.0};
  Rgba outline;
};

// foxglove.ImageAnnotations {circles = 1, points = 2} appended to `out`; every annotation carries
// `stamp_ns`, the frame's time, by which Foxglove pairs it with the image. Non-finite coordinates are
// left out of a points annotation (and a circle with one is left out), never sent as NaN.
void append_image_annotations(std::uint64_t stamp_ns, std::span<const CircleAnnotation> circles,
                              std::span<const PointsAnnotation> points, std::string& out);

// The FileDescriptorSet of foxglove.ImageAnnotations with its imports.
std::string image_annotations_descriptor_set();

// Low-level wire pieces (also used by the tests' own decoder checks).
void append_varint(std::uint64_t value, std::string& out);
void append_length_delimited(std::uint32_t field, std::string_view bytes, std::string& out);

}  // namespace tendril::server::protobuf
