// Foxglove's message schemas in their protobuf encoding, written directly (the few fields tendril
// sends do not justify libprotobuf): the wire format of the messages and the FileDescriptorSet that
// describes them (compiled from server/proto by protoc at build time). Binary messages travel without
// base64 or JSON text around them, so an image costs the server its bytes and nothing more.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>

namespace tendril::server::protobuf {

// foxglove.CompressedImage {timestamp = 1, data = 2, format = 3, frame_id = 4} appended to `out`.
void append_compressed_image(std::uint64_t stamp_ns, std::string_view frame_id,
                             std::span<const std::uint8_t> data, std::string_view format, std::string& out);

// The FileDescriptorSet of foxglove.CompressedImage with its import (google/protobuf/timestamp.proto).
std::string compressed_image_descriptor_set();

// Low-level wire pieces (also used by the tests' own decoder checks).
void append_varint(std::uint64_t value, std::string& out);
void append_length_delimited(std::uint32_t field, std::string_view bytes, std::string& out);

}  // namespace tendril::server::protobuf
