// A CiA 401-style analogue input node on the CAN bus (an ADC module): TPDO1 (COB-ID 0x180 + node id)
// carries three channels as unsigned 16-bit millivolts, little-endian (objects 0x6401:1..3), and
// optionally a 7th byte with the node's digital inputs (0x6000:1, bit 0 = input 0). tendril reads two
// such nodes on the SRMC: the dissertation's analog joystick (with a foot pedal on digital input 0) and the
// bend drives' spring-deflection potentiometers. The dissertation gives neither node ids nor scaling.
//
// A reading more than the fault margin outside 0..supply (a shorted or open input with a pull-up)
// is a wiring fault on that channel; no TPDO for stale_after_ns makes the reading stale.
#pragma once

#include <array>
#include <cstdint>
#include <optional>

#include "tendril/drivers/can/frame.hpp"

namespace tendril::canopen {

inline constexpr std::size_t kAnalogInputChannels = 3;

struct AnalogInputPdo {
  std::array<double, kAnalogInputChannels> volts{};
  std::uint8_t digital_inputs = 0;
  bool has_digital_inputs = false;  // the frame carried the 7th byte
};

// This node's TPDO1 decoded, or nothing when the frame is another node's, too short, RTR or error.
std::optional<AnalogInputPdo> decode_analog_input_pdo(const can::Frame& frame, std::uint8_t node_id) noexcept;
// Builds that TPDO; with digital inputs the frame has 7 bytes, else 6.
can::Frame encode_analog_input_pdo(std::uint8_t node_id,
                                   const std::array<double, kAnalogInputChannels>& volts,
                                   std::optional<std::uint8_t> digital_inputs = std::nullopt) noexcept;

struct AnalogInputSetup {
  std::uint8_t node_id = 0x31;
  double supply_volts = 5.0;
  double fault_margin_volts = 0.25;
  std::int64_t stale_after_ns = 100'000'000;
};

struct AnalogInputReading {
  std::array<double, kAnalogInputChannels> volts{};
  std::array<bool, kAnalogInputChannels> wiring_fault{};
  std::uint8_t digital_inputs = 0;
  bool fresh = false;  // a TPDO arrived within stale_after_ns
  std::int64_t stamp_ns = 0;
};

// Frame-by-frame receiver for the bus thread: no allocation, no locks.
class AnalogInputReceiver {
 public:
  // Throws std::invalid_argument for a node id outside 1..127 or a non-positive supply or stale time.
  explicit AnalogInputReceiver(AnalogInputSetup setup);
  // True when the frame was this node's TPDO (and updated the reading).
  bool handle(const can::Frame& frame, std::int64_t now_ns) noexcept;
  AnalogInputReading reading(std::int64_t now_ns) const noexcept;
  const AnalogInputSetup& setup() const noexcept { return setup_; }
  std::uint64_t frames() const noexcept { return frames_; }

 private:
  AnalogInputSetup setup_;
  AnalogInputPdo last_{};
  std::int64_t last_ns_ = 0;
  bool seen_ = false;
  std::uint64_t frames_ = 0;
};

}  // namespace tendril::canopen
