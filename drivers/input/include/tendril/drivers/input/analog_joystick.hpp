// The dissertation's bedside joystick: a P3America series 822, three precision potentiometers (roll,
// proximal bend, distal bend) read as 0–5 V each by an ADC node on the CAN bus (Abah 2022, §4.7.4:
// 2.5 V → 0, 5 V → +q̇_max, 0 V → −q̇_max).
//
// The ADC node is modelled as a CiA 401-style analogue input device: TPDO1 (COB-ID 0x180 + node id)
// carries the three channels as unsigned 16-bit millivolts, little-endian (object 0x6401:1..3),
// and the node sends a heartbeat (0x700 + node id). The dissertation gives neither node id nor scaling;
// millivolts keep the frame readable on a bus log.
//
// Safety: a reading outside 0–5 V by more than the fault margin (a shorted or open input with a
// pull-up) is a wiring fault, and so is a stale frame: both read as "not connected" (zero outputs,
// deadman released). A wiper that breaks towards 0 V is indistinguishable from full deflection —
// the reason motion also needs the deadman input (issue 3; the dissertation's device has none).
#pragma once

#include <array>
#include <cstdint>
#include <optional>

#include "tendril/drivers/can/frame.hpp"
#include "tendril/drivers/input/joystick.hpp"

namespace tendril::input {

inline constexpr std::size_t kAnalogJoystickChannels = 3;  // roll, proximal, distal

struct AnalogJoystickCalibration {
  std::uint8_t node_id = 0x30;
  double supply_volts = 5.0;         // full scale; the centre is half of it
  double deadband_volts = 0.1;       // around the centre (the dissertation recommends one; 0.1 V = 4 %)
  double fault_margin_volts = 0.25;  // beyond 0 − margin or supply + margin: wiring fault
  std::int64_t stale_after_ns = 100'000'000;  // no TPDO for this long: not connected
  std::array<bool, kAnalogJoystickChannels> invert{};
  // The node's digital input wired to an operator-presence foot pedal (the 822 has no deadman of its
  // own); -1: none, the deadman must come from elsewhere.
  int deadman_digital_input = 0;
};

// One decoded TPDO: volts per channel, or nothing when the frame is not this node's TPDO1 or is
// too short.
std::optional<std::array<double, kAnalogJoystickChannels>> decode_analog_joystick_pdo(
    const can::Frame& frame, std::uint8_t node_id) noexcept;

// Builds that TPDO (used by the simulated ADC node and by tests).
can::Frame encode_analog_joystick_pdo(std::uint8_t node_id,
                                      const std::array<double, kAnalogJoystickChannels>& volts) noexcept;

// Volts → JoystickState with outputs [roll, proximal, distal] in −1..1 (2.5 V → 0, 5 V → +1, 0 V → −1, with
// deadband). `deadman` is the operator-presence input from elsewhere (pedal, console): the 822 has none.
JoystickState analog_joystick_state(const std::array<double, kAnalogJoystickChannels>& volts,
                                    const AnalogJoystickCalibration& calibration, bool deadman,
                                    std::int64_t stamp_ns) noexcept;

// Frame-by-frame receiver for the bus thread: no allocation, no locks.
class AnalogJoystickReceiver {
 public:
  explicit AnalogJoystickReceiver(AnalogJoystickCalibration calibration);  // throws JoystickConfigError

  // Returns true when the frame was this node's TPDO (and updated the reading).
  bool handle(const can::Frame& frame, std::int64_t now_ns) noexcept;
  // The newest reading, turned "not connected" when it is older than stale_after_ns.
  JoystickState state(bool deadman, std::int64_t now_ns) const noexcept;
  // The same with the deadman read from the node's digital input (deadman_digital_input).
  JoystickState state(std::int64_t now_ns) const noexcept;
  std::uint64_t frames() const noexcept { return frames_; }

 private:
  AnalogJoystickCalibration calibration_;
  std::array<double, kAnalogJoystickChannels> volts_{};
  std::uint8_t digital_inputs_ = 0;
  std::int64_t last_ns_ = 0;
  bool seen_ = false;
  std::uint64_t frames_ = 0;
};

}  // namespace tendril::input
