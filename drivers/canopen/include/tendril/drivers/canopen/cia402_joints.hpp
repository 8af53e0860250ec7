// Cia402Joints: the joints of one robot that are CiA 402 drives on CANopen buses, behind the hardware
// seam. Each bus's CanopenMaster (which may serve several robots' drives) owns the protocol; this class
// only maps the control cycle's JointCommand/JointFeedback onto the masters' per-drive LatestValue
// slots, so read() and write() never lock or block.
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

#include "tendril/drivers/canopen/master.hpp"
#include "tendril/drivers/hardware/joint_interface.hpp"

namespace tendril::canopen {

hardware::PowerState power_state(Cia402State state) noexcept;

class Cia402Joints final : public hardware::JointInterface {
 public:
  // `drives[i]` is the master and its index of the drive behind joint i.
  explicit Cia402Joints(std::vector<std::pair<CanopenMaster*, std::size_t>> drives);

  std::size_t size() const noexcept override { return drives_.size(); }
  hardware::CommandMode command_mode(std::size_t joint) const noexcept override;
  const char* error_source() const noexcept override { return "EMCY"; }
  const char* device_state_text(std::uint8_t state) const noexcept override;
  void read(std::size_t joint, hardware::JointFeedback& out) const noexcept override;
  void write(std::size_t joint, const hardware::JointCommand& command) noexcept override;

 private:
  std::vector<std::pair<CanopenMaster*, std::size_t>> drives_;
};

}  // namespace tendril::canopen
