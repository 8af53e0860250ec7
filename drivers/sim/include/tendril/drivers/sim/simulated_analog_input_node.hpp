// SIMULATED CiA 401 analogue input node (an ADC module on the CAN bus): three 0–5 V inputs sampled by
// a 12-bit ADC behind an RC anti-alias filter, a byte of digital inputs, sent as TPDO1 (see
// tendril/drivers/canopen/analog_input_node.hpp) every PDO period, with a boot-up message,
// heartbeats and NMT start/stop handling.
//
// It is a Plant, stepped on the simulation thread. Input voltages, digital inputs and fault
// injections are set from any thread through lock-free slots.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <random>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/canopen/analog_input_node.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulation.hpp"

namespace tendril::sim {

struct AnalogInputNodeParameters {
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
  bool digital_inputs = true;             // send the 7th byte
  std::uint32_t seed = 1;
};

class SimulatedAnalogInputNode : public Plant {
 public:
  using Volts = std::array<double, canopen::kAnalogInputChannels>;
  // Inputs start at supply/2 (a centred potentiometer).
  SimulatedAnalogInputNode(can::Bus& endpoint, AnalogInputNodeParameters parameters);

  // What the three inputs see (V); non-finite values read as supply/2.
  void set_input_volts(const Volts& volts) noexcept;
  void set_digital_inputs(std::uint8_t bits) noexcept { digital_.store(bits); }
  // Forces a channel to a voltage (a shorted or broken wire); NaN clears the fault.
  void inject_channel_voltage(std::size_t channel, double volts) noexcept;
  // A silent node stops sending anything (cable pulled); the receiver must notice.
  void set_silent(bool silent) noexcept { silent_.store(silent); }

  void step(double dt) noexcept override;

  // What the ADC sampled last (for tests).
  Volts last_sample() const noexcept { return sample_.load(); }
  std::uint64_t pdos_sent() const noexcept { return pdos_sent_.load(); }
  const AnalogInputNodeParameters& parameters() const noexcept { return parameters_; }

 private:
  void handle_nmt(const can::Frame& frame) noexcept;

  can::Bus& bus_;
  AnalogInputNodeParameters parameters_;
  hardware::LatestValue<Volts> input_;
  hardware::LatestValue<Volts> forced_;
  hardware::LatestValue<Volts> sample_;
  std::atomic<std::uint8_t> digital_{0};
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
