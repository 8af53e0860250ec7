// SIMULATED ADC node with the seed's P3America 822 joystick on it (seed 000 §4.7): three
// potentiometers at 0–5 V, sampled by a 12-bit ADC behind an RC anti-alias filter, sent as TPDO1
// (three uint16 millivolts, see tendril/drivers/input/analog_joystick.hpp) every PDO period, with a
// boot-up message, heartbeats and NMT start/stop handling like a CiA 401 I/O node.
//
// It is a Plant, stepped on the simulation thread. Deflections and fault injections are set from
// any thread through lock-free slots.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <random>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/teleop/latest_value.hpp"

namespace tendril::sim {

struct AnalogJoystickNodeParameters {
  std::uint8_t node_id = 0x30;
  std::chrono::microseconds pdo_period{10'000};  // 100 Hz
  std::chrono::microseconds heartbeat_period{100'000};
  double supply_volts = 5.0;
  int adc_bits = 12;
  // The ADC's input range has headroom above the supply so that an input pulled above it (open
  // wiper with a pull-up, short to a higher rail) reads as out of range instead of as +max.
  double adc_full_scale_volts = 6.0;
  double noise_volts = 0.003;             // σ of wiper and ADC noise
  double filter_time_constant_s = 0.004;  // RC anti-alias filter before the ADC
  std::uint32_t seed = 1;
};

class SimulatedAnalogJoystick final : public Plant {
 public:
  using Volts = std::array<double, input::kAnalogJoystickChannels>;

  SimulatedAnalogJoystick(can::Bus& endpoint, AnalogJoystickNodeParameters parameters);

  // Stick deflection per axis in −1..1 (roll, proximal, distal); 0 is the spring-centred stick.
  void set_deflection(const std::array<double, input::kAnalogJoystickChannels>& deflection) noexcept;
  // Forces a channel to a voltage (a shorted or broken wire); NaN clears the fault.
  void inject_channel_voltage(std::size_t channel, double volts) noexcept;
  // A silent node stops sending anything (cable pulled); the receiver must notice.
  void set_silent(bool silent) noexcept { silent_.store(silent); }

  void step(double dt) noexcept override;

  // What the ADC sampled last (for tests).
  Volts last_sample() const noexcept { return sample_.load(); }
  std::uint64_t pdos_sent() const noexcept { return pdos_sent_.load(); }

 private:
  void handle_nmt(const can::Frame& frame) noexcept;

  can::Bus& bus_;
  AnalogJoystickNodeParameters parameters_;
  teleop::LatestValue<std::array<double, input::kAnalogJoystickChannels>> deflection_;
  teleop::LatestValue<Volts> forced_;
  teleop::LatestValue<Volts> sample_;
  std::atomic<bool> silent_{false};
  std::atomic<std::uint64_t> pdos_sent_{0};
  Volts filtered_{};
  std::mt19937 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};
  double time_s_ = 0.0;
  double next_pdo_s_ = 0.0;
  double next_heartbeat_s_ = 0.0;
  bool booted_ = false;
  bool operational_ = false;
};

}  // namespace tendril::sim
