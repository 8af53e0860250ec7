// The protobuf wire writer of foxglove.CompressedImage against bytes worked out by hand from the
// protobuf encoding rules, and the embedded descriptor set (what protoc made of server/proto).
#include <gtest/gtest.h>

#include <cmath>
#include <span>
#include <string>
#include <vector>

#include "tendril/server/foxglove_protobuf.hpp"

using namespace tendril::server;

namespace {
std::string bytes(std::initializer_list<int> values) {
  std::string out;
  for (const int v : values) out.push_back(static_cast<char>(v));
  return out;
}
}  // namespace

TEST(FoxgloveProtobuf, VarintsUseSevenBitGroupsLowFirst) {
  std::string out;
  protobuf::append_varint(0, out);
  protobuf::append_varint(1, out);
  protobuf::append_varint(127, out);
  protobuf::append_varint(128, out);
  protobuf::append_varint(300, out);
  EXPECT_EQ(out, bytes({0x00, 0x01, 0x7F, 0x80, 0x01, 0xAC, 0x02}));
  out.clear();
  protobuf::append_varint(~0ULL, out);  // ten bytes, the last holding the top bit
  EXPECT_EQ(out, bytes({0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01}));
}

TEST(FoxgloveProtobuf, CompressedImageFieldsByNumber) {
  const std::vector<std::uint8_t> data = {0xFF, 0xD8, 0xFF};
  std::string out;
  // 1.5 s: Timestamp {seconds = 1, nanos = 500000000}.
  protobuf::append_compressed_image(1'500'000'000ULL, "f", data, "jpeg", out);
  const std::string expected =
      bytes({0x0A, 0x08, 0x08, 0x01, 0x10, 0x80, 0xCA, 0xB5, 0xEE, 0x01}) +  // 1: timestamp (LEN 8)
      bytes({0x12, 0x03, 0xFF, 0xD8, 0xFF}) +                                // 2: data
      bytes({0x1A, 0x04}) + "jpeg" +                                         // 3: format
      bytes({0x22, 0x01}) + "f";                                             // 4: frame_id
  EXPECT_EQ(out, expected);
  // Zero values are left out (proto3), the timestamp field stays (empty message).
  out.clear();
  protobuf::append_compressed_image(0, "", {}, "", out);
  EXPECT_EQ(out, bytes({0x0A, 0x00}));
}

TEST(FoxgloveProtobuf, TheDescriptorSetHoldsTheSchemaAndItsImport) {
  const std::string set = protobuf::compressed_image_descriptor_set();
  ASSERT_GT(set.size(), 100u);
  EXPECT_EQ(static_cast<unsigned char>(set[0]), 0x0A) << "FileDescriptorSet.file, field 1, length-delimited";
  // The import first (--include_imports orders dependencies first), then foxglove's file.
  const auto timestamp = set.find("google/protobuf/timestamp.proto");
  const auto image = set.find("foxglove/CompressedImage.proto");
  ASSERT_NE(timestamp, std::string::npos);
  ASSERT_NE(image, std::string::npos);
  EXPECT_LT(timestamp, image);
  for (const char* name : {"CompressedImage", "frame_id", "format", "data", ".google.protobuf.Timestamp"})
    EXPECT_NE(set.find(name), std::string::npos) << name;
}

// foxglove.ImageAnnotations by hand: one circle and one line strip at t = 2 s. Doubles are fixed64
// little-endian (1.0 = 00 00 00 00 00 00 F0 3F); proto3 leaves zero doubles out.
TEST(FoxgloveProtobuf, ImageAnnotationsFieldsByNumber) {
  const std::string one = bytes({0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xF0, 0x3F});
  const std::string two = bytes({0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x40});
  const std::string stamp = bytes({0x0A, 0x02, 0x08, 0x02});  // 1: Timestamp {seconds = 2}
  protobuf::CircleAnnotation circle;
  circle.position = {1.0, 2.0};
  circle.diameter = 2.0;
  circle.thickness = 1.0;
  circle.fill = {0.0, 0.0, 0.0, 0.0};
  circle.outline = {1.0, 0.0, 0.0, 1.0};
  protobuf::PointsAnnotation line;
  line.type = protobuf::PointsType::kLineStrip;
  line.points = {{0.0, 1.0}, {std::nan(""), 3.0}, {2.0, 0.0}};  // the NaN point is left out
  line.outline = {0.0, 0.0, 1.0, 1.0};
  line.thickness = 2.0;
  std::string out;
  protobuf::append_image_annotations(2'000'000'000ULL, std::span(&circle, 1), std::span(&line, 1), out);

  const std::string position = bytes({0x09}) + one + bytes({0x11}) + two;   // Point2 {x = 1, y = 2}
  const std::string circle_body = stamp + bytes({0x12, 0x12}) + position +  // 2: position
                                  bytes({0x19}) + two +                     // 3: diameter
                                  bytes({0x21}) + one +                     // 4: thickness
                                  bytes({0x2A, 0x00}) +                     // 5: fill (all zero)
                                  bytes({0x32, 0x12, 0x09}) + one + bytes({0x21}) + one;  // 6: r = a = 1
  const std::string line_body = stamp + bytes({0x10, 0x03}) +                             // 2: LINE_STRIP
                                bytes({0x1A, 0x09, 0x11}) + one +                         // 3: Point2 {y = 1}
                                bytes({0x1A, 0x09, 0x09}) + two +                         // 3: Point2 {x = 2}
                                bytes({0x22, 0x12, 0x19}) + one + bytes({0x21}) + one +   // 4: b = a = 1
                                bytes({0x39}) + two;                                      // 7: thickness
  ASSERT_LT(circle_body.size(), 128u);
  ASSERT_LT(line_body.size(), 128u);
  const std::string expected = bytes({0x0A, static_cast<int>(circle_body.size())}) + circle_body +
                               bytes({0x12, static_cast<int>(line_body.size())}) + line_body;
  EXPECT_EQ(out, expected);

  // A circle at a non-finite position is not sent at all.
  circle.position = {std::nan(""), 1.0};
  out.clear();
  protobuf::append_image_annotations(0, std::span(&circle, 1), {}, out);
  EXPECT_TRUE(out.empty());
}

TEST(FoxgloveProtobuf, TheAnnotationsDescriptorSetHoldsEveryImport) {
  const std::string set = protobuf::image_annotations_descriptor_set();
  for (const char* file : {"google/protobuf/timestamp.proto", "foxglove/Point2.proto", "foxglove/Color.proto",
                           "foxglove/PointsAnnotation.proto", "foxglove/CircleAnnotation.proto",
                           "foxglove/ImageAnnotations.proto"})
    EXPECT_NE(set.find(file), std::string::npos) << file;
  EXPECT_LT(set.find("foxglove/Point2.proto"), set.find("foxglove/ImageAnnotations.proto"));
  for (const char* name :
       {"ImageAnnotations", "circles", "points", "LINE_STRIP", "outline_color", "thickness"})
    EXPECT_NE(set.find(name), std::string::npos) << name;
}
