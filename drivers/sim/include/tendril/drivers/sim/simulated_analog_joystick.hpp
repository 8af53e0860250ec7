// SIMULATED ADC node with the dissertation's P3America 822 joystick on it (Abah 2022, §4.7.4): three
// potentiometers at 0–5 V (see SimulatedAnalogInputNode for the ADC, filter, noise and NMT) and a
// foot pedal on digital input 0. Deflections, the pedal and fault injections are set from any thread.
#pragma once

#include <array>

#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"

namespace tendril::sim {

using AnalogJoystickNodeParameters = AnalogInputNodeParameters;

// The dissertation's joystick on an ADC node: three centred potentiometers, and a foot pedal on digital
// input 0 as the operator-presence input.
class SimulatedAnalogJoystick final : public SimulatedAnalogInputNode {
 public:
  using SimulatedAnalogInputNode::SimulatedAnalogInputNode;
  // Stick deflection per axis in −1..1 (roll, proximal, distal); 0 is the spring-centred stick.
  void set_deflection(const std::array<double, input::kAnalogJoystickChannels>& deflection) noexcept;
  void set_pedal(bool pressed) noexcept { set_digital_inputs(pressed ? 0x01 : 0x00); }
};

}  // namespace tendril::sim
