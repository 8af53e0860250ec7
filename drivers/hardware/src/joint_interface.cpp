#include "tendril/drivers/hardware/joint_interface.hpp"

namespace tendril::hardware {

const char* to_string(PowerState state) noexcept {
  switch (state) {
    case PowerState::off:
      return "off";
    case PowerState::switching_on:
      return "switching on";
    case PowerState::on:
      return "on";
    case PowerState::stopping:
      return "stopping";
    case PowerState::fault:
      return "fault";
  }
  return "unknown";
}

}  // namespace tendril::hardware
