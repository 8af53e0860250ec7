#include "tendril/drivers/input/analog_joystick.hpp"

#include "tendril/drivers/canopen/analog_input_node.hpp"

#include <algorithm>
#include <cmath>

namespace tendril::input {

std::optional<std::array<double, kAnalogJoystickChannels>> decode_analog_joystick_pdo(
    const can::Frame& frame, std::uint8_t node_id) noexcept {
  const auto pdo = canopen::decode_analog_input_pdo(frame, node_id);
  if (!pdo) return std::nullopt;
  return pdo->volts;
}

can::Frame encode_analog_joystick_pdo(std::uint8_t node_id,
                                      const std::array<double, kAnalogJoystickChannels>& volts) noexcept {
  return canopen::encode_analog_input_pdo(node_id, volts);
}

JoystickState analog_joystick_state(const std::array<double, kAnalogJoystickChannels>& volts,
                                    const AnalogJoystickCalibration& calibration, bool deadman,
                                    std::int64_t stamp_ns) noexcept {
  JoystickState state;
  state.stamp_ns = stamp_ns;
  const double supply = calibration.supply_volts;
  for (double v : volts) {
    if (!std::isfinite(v) || v < -calibration.fault_margin_volts ||
        v > supply + calibration.fault_margin_volts) {
      return state;  // wiring fault: not connected, zero outputs
    }
  }
  state.connected = true;
  state.deadman = deadman;
  const AxisMapping base{"", 0, 0.0, supply, calibration.deadband_volts / (0.5 * supply), 1.0, false};
  for (std::size_t i = 0; i < kAnalogJoystickChannels; ++i) {
    AxisMapping axis = base;
    axis.invert = calibration.invert[i];
    state.outputs[i] = normalise_axis(axis, volts[i]);
  }
  return state;
}

AnalogJoystickReceiver::AnalogJoystickReceiver(AnalogJoystickCalibration calibration)
    : calibration_(calibration) {
  const auto& c = calibration_;
  if (c.node_id < 1 || c.node_id > 127) throw JoystickConfigError("analog joystick: node_id must be 1..127");
  if (!std::isfinite(c.supply_volts) || c.supply_volts <= 0.0) {
    throw JoystickConfigError("analog joystick: supply_volts must be positive");
  }
  if (!std::isfinite(c.deadband_volts) || c.deadband_volts < 0.0 ||
      c.deadband_volts >= 0.5 * c.supply_volts) {
    throw JoystickConfigError("analog joystick: deadband_volts must be in [0, supply/2)");
  }
  if (!std::isfinite(c.fault_margin_volts) || c.fault_margin_volts < 0.0) {
    throw JoystickConfigError("analog joystick: fault_margin_volts must not be negative");
  }
  if (c.stale_after_ns <= 0) throw JoystickConfigError("analog joystick: stale_after must be positive");
  if (c.deadman_digital_input < -1 || c.deadman_digital_input > 7)
    throw JoystickConfigError("analog joystick: deadman_digital_input must be -1 (none) or 0..7");
}

bool AnalogJoystickReceiver::handle(const can::Frame& frame, std::int64_t now_ns) noexcept {
  const auto pdo = canopen::decode_analog_input_pdo(frame, calibration_.node_id);
  if (!pdo) return false;
  volts_ = pdo->volts;
  digital_inputs_ = pdo->has_digital_inputs ? pdo->digital_inputs : 0;
  last_ns_ = now_ns;
  seen_ = true;
  ++frames_;
  return true;
}

JoystickState AnalogJoystickReceiver::state(std::int64_t now_ns) const noexcept {
  const int bit = calibration_.deadman_digital_input;
  const bool pedal = bit >= 0 && ((digital_inputs_ >> bit) & 1U) != 0;
  return state(pedal, now_ns);
}

JoystickState AnalogJoystickReceiver::state(bool deadman, std::int64_t now_ns) const noexcept {
  if (!seen_ || now_ns - last_ns_ > calibration_.stale_after_ns) {
    JoystickState stale;
    stale.stamp_ns = last_ns_;
    return stale;
  }
  JoystickState state = analog_joystick_state(volts_, calibration_, deadman, last_ns_);
  state.reports = frames_;
  return state;
}

}  // namespace tendril::input
