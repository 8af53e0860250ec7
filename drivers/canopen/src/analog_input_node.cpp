#include "tendril/drivers/canopen/analog_input_node.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace tendril::canopen {

std::optional<AnalogInputPdo> decode_analog_input_pdo(const can::Frame& frame,
                                                      std::uint8_t node_id) noexcept {
  if (frame.extended || frame.rtr || frame.error) return std::nullopt;
  if (frame.id != 0x180U + node_id || frame.len < 2 * kAnalogInputChannels) return std::nullopt;
  AnalogInputPdo pdo;
  for (std::size_t i = 0; i < kAnalogInputChannels; ++i) {
    const auto millivolts = static_cast<std::uint16_t>(frame.data[2 * i] | (frame.data[2 * i + 1] << 8));
    pdo.volts[i] = millivolts / 1000.0;
  }
  if (frame.len > 2 * kAnalogInputChannels) {
    pdo.digital_inputs = frame.data[2 * kAnalogInputChannels];
    pdo.has_digital_inputs = true;
  }
  return pdo;
}

can::Frame encode_analog_input_pdo(std::uint8_t node_id,
                                   const std::array<double, kAnalogInputChannels>& volts,
                                   std::optional<std::uint8_t> digital_inputs) noexcept {
  can::Frame frame;
  frame.id = 0x180U + node_id;
  frame.len = 2 * kAnalogInputChannels;
  for (std::size_t i = 0; i < kAnalogInputChannels; ++i) {
    const double mv = std::isfinite(volts[i]) ? std::clamp(std::round(volts[i] * 1000.0), 0.0, 65535.0) : 0.0;
    const auto value = static_cast<std::uint16_t>(mv);
    frame.data[2 * i] = static_cast<std::uint8_t>(value & 0xFFU);
    frame.data[2 * i + 1] = static_cast<std::uint8_t>(value >> 8);
  }
  if (digital_inputs) {
    frame.data[2 * kAnalogInputChannels] = *digital_inputs;
    frame.len = 2 * kAnalogInputChannels + 1;
  }
  return frame;
}

AnalogInputReceiver::AnalogInputReceiver(AnalogInputSetup setup) : setup_(setup) {
  if (setup_.node_id < 1 || setup_.node_id > 127)
    throw std::invalid_argument("analog input node: node_id must be 1..127");
  if (!std::isfinite(setup_.supply_volts) || setup_.supply_volts <= 0.0)
    throw std::invalid_argument("analog input node: supply_volts must be positive");
  if (!std::isfinite(setup_.fault_margin_volts) || setup_.fault_margin_volts < 0.0)
    throw std::invalid_argument("analog input node: fault_margin_volts must not be negative");
  if (setup_.stale_after_ns <= 0)
    throw std::invalid_argument("analog input node: stale_after must be positive");
}

bool AnalogInputReceiver::handle(const can::Frame& frame, std::int64_t now_ns) noexcept {
  const auto pdo = decode_analog_input_pdo(frame, setup_.node_id);
  if (!pdo) return false;
  last_ = *pdo;
  last_ns_ = now_ns;
  seen_ = true;
  ++frames_;
  return true;
}

AnalogInputReading AnalogInputReceiver::reading(std::int64_t now_ns) const noexcept {
  AnalogInputReading r;
  r.volts = last_.volts;
  r.digital_inputs = last_.digital_inputs;
  r.stamp_ns = last_ns_;
  r.fresh = seen_ && now_ns - last_ns_ <= setup_.stale_after_ns;
  for (std::size_t i = 0; i < kAnalogInputChannels; ++i) {
    const double v = r.volts[i];
    r.wiring_fault[i] = !std::isfinite(v) || v < -setup_.fault_margin_volts ||
                        v > setup_.supply_volts + setup_.fault_margin_volts;
  }
  return r;
}

}  // namespace tendril::canopen
