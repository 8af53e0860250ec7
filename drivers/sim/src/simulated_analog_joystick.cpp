#include "tendril/drivers/sim/simulated_analog_joystick.hpp"

#include <algorithm>
#include <cmath>

namespace tendril::sim {

void SimulatedAnalogJoystick::set_deflection(
    const std::array<double, input::kAnalogJoystickChannels>& deflection) noexcept {
  // The potentiometer wiper: supply/2 at rest, linear in deflection (5 V = +max, 0 V = −max).
  Volts volts{};
  for (std::size_t i = 0; i < volts.size(); ++i) {
    const double d = std::isfinite(deflection[i]) ? std::clamp(deflection[i], -1.0, 1.0) : 0.0;
    volts[i] = 0.5 * parameters().supply_volts * (1.0 + d);
  }
  set_input_volts(volts);
}

}  // namespace tendril::sim
