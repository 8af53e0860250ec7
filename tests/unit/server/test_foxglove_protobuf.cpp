// The protobuf wire writer of foxglove.CompressedImage against bytes worked out by hand from the
// protobuf encoding rules, and the embedded descriptor set (what protoc made of server/proto).
#include <gtest/gtest.h>

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
