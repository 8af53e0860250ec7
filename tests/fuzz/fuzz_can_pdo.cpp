// Fuzz target: CAN frames from the bus into the analog input nodes' decoder and receiver (the
// joystick's and the spring-deflection sensor's ADC nodes). Input bytes: id (2, LE, 11 bit), flags,
// len, data (8), then a time step; repeated. Anything on the bus must decode to finite volts or be
// ignored, and the receiver must never report a fresh reading it did not get.
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "tendril/drivers/canopen/analog_input_node.hpp"

using namespace tendril;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  canopen::AnalogInputReceiver receiver({0x31, 5.0, 0.25, 100'000'000});
  std::int64_t now = 0;
  std::uint64_t accepted = 0;
  for (std::size_t at = 0; at + 13 <= size; at += 13) {
    can::Frame f;
    f.id = static_cast<std::uint32_t>(data[at] | (data[at + 1] << 8)) & 0x7FFU;
    f.rtr = (data[at + 2] & 1U) != 0;
    f.error = (data[at + 2] & 2U) != 0;
    f.extended = (data[at + 2] & 4U) != 0;
    f.len = static_cast<std::uint8_t>(data[at + 3] % 9);
    for (std::size_t i = 0; i < 8; ++i) f.data[i] = data[at + 4 + i];
    now += static_cast<std::int64_t>(data[at + 12]) * 1'000'000;
    const auto pdo = canopen::decode_analog_input_pdo(f, 0x31);
    if (pdo) {
      for (double v : pdo->volts)
        if (!std::isfinite(v) || v < 0.0 || v > 65.535) std::abort();
      // Round trip: what we decode re-encodes to the same bytes.
      const auto again = canopen::encode_analog_input_pdo(
          0x31, pdo->volts,
          pdo->has_digital_inputs ? std::optional<std::uint8_t>(pdo->digital_inputs) : std::nullopt);
      for (std::size_t i = 0; i < 6; ++i)
        if (again.data[i] != f.data[i]) std::abort();
    }
    const bool handled = receiver.handle(f, now);
    if (handled != pdo.has_value()) std::abort();  // the receiver takes exactly this node's TPDOs
    if (handled) ++accepted;
    const auto r = receiver.reading(now);
    if (r.fresh && accepted == 0) std::abort();
    for (double v : r.volts)
      if (!std::isfinite(v)) std::abort();
  }
  return 0;
}
