#include "tendril/drivers/input/joystick.hpp"

#include <algorithm>
#include <cmath>
#include <set>

namespace tendril::input {

void JoystickMapping::validate() const {
  if (axes.size() > kMaxJoystickOutputs) {
    throw JoystickConfigError("a joystick maps at most " + std::to_string(kMaxJoystickOutputs) +
                              " axes, not " + std::to_string(axes.size()));
  }
  if (buttons.size() > 32) throw JoystickConfigError("a joystick maps at most 32 buttons");
  std::set<std::string> outputs;
  for (const auto& axis : axes) {
    const std::string where =
        "joystick axis \"" + axis.output + "\" (code " + std::to_string(axis.code) + ")";
    if (axis.output.empty())
      throw JoystickConfigError("joystick axis with code " + std::to_string(axis.code) +
                                " has no output name");
    if (!outputs.insert(axis.output).second) throw JoystickConfigError(where + " is mapped twice");
    if (axis.code < 0) throw JoystickConfigError(where + ": code must not be negative");
    if (!std::isfinite(axis.minimum) || !std::isfinite(axis.maximum) || !(axis.maximum > axis.minimum)) {
      throw JoystickConfigError(where + ": minimum must be below maximum, both finite");
    }
    if (!std::isfinite(axis.deadband) || axis.deadband < 0.0 || axis.deadband >= 1.0) {
      throw JoystickConfigError(where + ": deadband must be in [0, 1)");
    }
    if (!std::isfinite(axis.scale) || axis.scale <= 0.0 || axis.scale > 10.0) {
      throw JoystickConfigError(where + ": scale must be in (0, 10]; use invert to flip the direction");
    }
  }
}

int JoystickMapping::output_index(const std::string& output) const noexcept {
  for (std::size_t i = 0; i < axes.size(); ++i) {
    if (axes[i].output == output) return static_cast<int>(i);
  }
  return -1;
}

double normalise_axis(const AxisMapping& axis, double raw) noexcept {
  if (!std::isfinite(raw)) return 0.0;
  const double half = 0.5 * (axis.maximum - axis.minimum);
  if (!(half > 0.0)) return 0.0;
  const double centre = 0.5 * (axis.maximum + axis.minimum);
  double x = std::clamp((raw - centre) / half, -1.0, 1.0);
  const double magnitude = std::abs(x);
  if (magnitude <= axis.deadband) return 0.0;
  x = std::copysign((magnitude - axis.deadband) / (1.0 - axis.deadband), x);
  x *= axis.scale;
  if (axis.invert) x = -x;
  return std::clamp(x, -1.0, 1.0);
}

}  // namespace tendril::input
