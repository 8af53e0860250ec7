#include "tendril/drivers/canopen/cia402_joints.hpp"

namespace tendril::canopen {

hardware::PowerState power_state(Cia402State state) noexcept {
  using hardware::PowerState;
  switch (state) {
    case Cia402State::operation_enabled:
      return PowerState::on;
    case Cia402State::quick_stop_active:
      return PowerState::stopping;
    case Cia402State::fault_reaction_active:
    case Cia402State::fault:
      return PowerState::fault;
    case Cia402State::switched_on:
      return PowerState::switching_on;
    case Cia402State::not_ready_to_switch_on:
    case Cia402State::switch_on_disabled:
    case Cia402State::ready_to_switch_on:
      break;
  }
  return PowerState::off;
}

Cia402Joints::Cia402Joints(std::vector<std::pair<CanopenMaster*, std::size_t>> drives)
    : drives_(std::move(drives)) {}

// The master maps RPDO1 to controlword + target position (cyclic synchronous position), so every
// drive it runs is a position joint.
hardware::CommandMode Cia402Joints::command_mode(std::size_t) const noexcept {
  return hardware::CommandMode::position;
}

const char* Cia402Joints::device_state_text(std::uint8_t state) const noexcept {
  return to_string(static_cast<Cia402State>(state));
}

void Cia402Joints::read(std::size_t joint, hardware::JointFeedback& out) const noexcept {
  const auto& [master, drive] = drives_[joint];
  const DriveFeedback fb = master->feedback(drive).load();
  out.position = fb.position;
  out.velocity = fb.velocity;
  out.effort = fb.effort;
  out.power = power_state(fb.state);
  out.device_state = static_cast<std::uint8_t>(fb.state);
  out.link_alive = fb.heartbeat_alive;
  out.link_operational = fb.nmt == NmtState::operational;
  out.error_count = fb.emcy_count;
  out.error_code = fb.last_emcy_code;
  out.error_detail = fb.last_emcy_register;
}

void Cia402Joints::write(std::size_t joint, const hardware::JointCommand& command) noexcept {
  const auto& [master, drive] = drives_[joint];
  DriveCommand dc = master->command(drive).load();
  switch (command.request) {
    case hardware::PowerRequest::on:
      dc.request = DriveRequest::enable;
      break;
    case hardware::PowerRequest::quick_stop:
      dc.request = DriveRequest::quick_stop;
      break;
    case hardware::PowerRequest::fault_reset:
      dc.request = DriveRequest::fault_reset;
      break;
    case hardware::PowerRequest::off:
      dc.request = DriveRequest::disable;
      break;
  }
  dc.target_position = command.position;
  ++dc.sequence;
  master->set_command(drive, dc);  // wakes the bus thread for a quick stop or disable
}

}  // namespace tendril::canopen
