// CRC-32 as MCAP uses it (the IEEE 802.3 / zlib CRC: reflected polynomial 0xEDB88320, initial value
// and final XOR 0xFFFFFFFF). Incremental: feed the previous result back in to extend a checksum.
#pragma once

#include <cstdint>
#include <span>

namespace tendril::record {

// crc32(b, crc32(a)) == crc32(a ++ b); crc32({}) == 0.
std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t previous = 0) noexcept;

}  // namespace tendril::record
