#include "tendril/drivers/sim/simulated_analog_input_node.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

namespace tendril::sim {
namespace {
constexpr double kNoFault = std::numeric_limits<double>::quiet_NaN();
}

SimulatedAnalogInputNode::SimulatedAnalogInputNode(can::Bus& endpoint, AnalogInputNodeParameters parameters)
    : bus_(endpoint), parameters_(parameters), rng_(parameters.seed) {
  filtered_.fill(0.5 * parameters_.supply_volts);
  input_.store(filtered_);
  forced_.store({kNoFault, kNoFault, kNoFault});
  sample_.store(filtered_);
}

void SimulatedAnalogInputNode::set_input_volts(const Volts& volts) noexcept {
  auto v = volts;
  for (auto& x : v) x = std::isfinite(x) ? x : 0.5 * parameters_.supply_volts;
  input_.store(v);
}

void SimulatedAnalogInputNode::inject_channel_voltage(std::size_t channel, double volts) noexcept {
  if (channel >= canopen::kAnalogInputChannels) return;
  auto forced = forced_.load();
  forced[channel] = volts;
  forced_.store(forced);
}

void SimulatedAnalogInputNode::handle_nmt(const can::Frame& frame) noexcept {
  if (frame.id != 0 || frame.len < 2) return;
  if (frame.data[1] != 0 && frame.data[1] != parameters_.node_id) return;
  switch (frame.data[0]) {
    case 0x01:  // start
      operational_ = true;
      break;
    case 0x02:  // stop
    case 0x80:  // enter pre-operational: no PDOs in either state
      operational_ = false;
      break;
    case 0x81:  // reset node
    case 0x82:  // reset communication: boot again
      booted_ = false;
      break;
    default:
      break;
  }
}

void SimulatedAnalogInputNode::step(double dt) noexcept {
  if (!(dt > 0.0)) return;
  time_s_ += dt;
  while (auto frame = bus_.receive(std::chrono::nanoseconds(0))) handle_nmt(*frame);

  const auto input = input_.load();
  const auto forced = forced_.load();
  const double alpha = 1.0 - std::exp(-dt / parameters_.filter_time_constant_s);
  const double full_scale = parameters_.adc_full_scale_volts;
  const double lsb = full_scale / static_cast<double>((1 << parameters_.adc_bits) - 1);
  Volts sampled{};
  for (std::size_t i = 0; i < sampled.size(); ++i) {
    const double wiper = std::isfinite(forced[i]) ? forced[i] : input[i];
    filtered_[i] += alpha * (wiper - filtered_[i]);
    const double noisy = filtered_[i] + parameters_.noise_volts * noise_(rng_);
    sampled[i] = std::round(std::clamp(noisy, 0.0, full_scale) / lsb) * lsb;
  }
  sample_.store(sampled);

  if (silent_.load()) return;
  if (!booted_) {
    bus_.send(can::Frame::make(0x700U + parameters_.node_id, {0x00}));  // boot-up
    booted_ = true;
    operational_ = true;  // simple I/O nodes start on their own (NMT start-up behaviour 0x1F80)
    next_pdo_s_ = time_s_;
    next_heartbeat_s_ = time_s_;
  }
  const double pdo_period = std::chrono::duration<double>(parameters_.pdo_period).count();
  const double heartbeat_period = std::chrono::duration<double>(parameters_.heartbeat_period).count();
  if (time_s_ >= next_heartbeat_s_) {
    bus_.send(can::Frame::make(0x700U + parameters_.node_id,
                               {static_cast<std::uint8_t>(operational_ ? 0x05 : 0x7F)}));
    next_heartbeat_s_ += heartbeat_period;
    if (next_heartbeat_s_ < time_s_) next_heartbeat_s_ = time_s_ + heartbeat_period;
  }
  if (operational_ && time_s_ >= next_pdo_s_) {
    const auto digital =
        parameters_.digital_inputs ? std::optional<std::uint8_t>(digital_.load()) : std::nullopt;
    if (bus_.send(canopen::encode_analog_input_pdo(parameters_.node_id, sampled, digital)) ==
        can::SendResult::ok) {
      pdos_sent_.fetch_add(1, std::memory_order_relaxed);
    }
    next_pdo_s_ += pdo_period;
    if (next_pdo_s_ < time_s_) next_pdo_s_ = time_s_ + pdo_period;
  }
}

}  // namespace tendril::sim
