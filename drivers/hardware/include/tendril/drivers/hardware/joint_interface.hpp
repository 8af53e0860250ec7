// The hardware seam for joints (in the spirit of ros2_control's SystemInterface): the control cycle
// reads every joint's feedback and writes its command through JointInterface, whatever carries them —
// CiA 402 drives over CANopen (canopen::Cia402Joints), an arm controller over Ethernet, or a simulator
// at this interface (sim::SimulatedVelocityArm). A HardwareComponent is what owns the link: it is
// configured and activated before the control loop starts and deactivated after it stops.
//
// Real-time contract: read() and write() are called from the control thread only; they never
// allocate, lock or block (implementations hand data over through LatestValue slots).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>

namespace tendril::hardware {

// What a joint is commanded with. A position joint follows `position` (the drive closes the loop);
// a velocity joint follows `velocity`; an effort joint `effort`.
enum class CommandMode : std::uint8_t { position, velocity, effort };

// The power stage of a joint, in the words of every drive profile (CiA 402's eight states map onto it).
enum class PowerState : std::uint8_t {
  off,           // not ready / switch on disabled / ready to switch on / switched on
  switching_on,  // on its way to `on`
  on,            // operation enabled: follows commands
  stopping,      // quick stop active: braking to rest, ignores commands
  fault,         // fault reaction active or fault: needs a fault reset
};
const char* to_string(PowerState state) noexcept;

// What the control cycle asks of a joint's power stage. Level-triggered: the interface steps the
// device toward it every cycle (a fault reset is sent as an edge by the implementation).
enum class PowerRequest : std::uint8_t { off, on, quick_stop, fault_reset };

struct JointFeedback {
  double position = 0.0;  // joint units (mm or rad)
  double velocity = 0.0;  // joint units / s
  double effort = 0.0;    // device units (CiA 402: per mille of rated torque; N or N·m where known)
  PowerState power = PowerState::off;
  std::uint8_t device_state = 0;  // the device's own state, named by JointInterface::device_state_text
  bool link_alive = false;        // the device is heard from (heartbeat, keep-alive)
  bool link_operational = false;  // the device takes cyclic commands (NMT operational, session open)
  std::uint32_t error_count = 0;  // grows by one with every error the device reports
  std::uint32_t error_code = 0;   // the last one (device specific: an EMCY code, a controller code)
  std::uint8_t error_detail = 0;  // more about it (CiA 402: the error register)
};

struct JointCommand {
  PowerRequest request = PowerRequest::off;
  double position = 0.0;  // used by position joints
  double velocity = 0.0;  // used by velocity joints; feed-forward for position joints
  double effort = 0.0;    // used by effort joints
};

// A group of joints reached through one link, indexed 0..size()-1 in the order the robot file lists
// them.
class JointInterface {
 public:
  virtual ~JointInterface() = default;
  virtual std::size_t size() const noexcept = 0;
  virtual CommandMode command_mode(std::size_t joint) const noexcept = 0;
  // What reports errors, for messages ("EMCY" for CANopen drives).
  virtual const char* error_source() const noexcept { return "error"; }
  // JointFeedback::device_state in the device profile's words ("quick stop active"), for messages.
  virtual const char* device_state_text(std::uint8_t state) const noexcept {
    return to_string(static_cast<PowerState>(state));
  }
  virtual void read(std::size_t joint, JointFeedback& out) const noexcept = 0;
  virtual void write(std::size_t joint, const JointCommand& command) noexcept = 0;
};

// Set-up failure of a hardware component (a drive that does not boot, a link that does not open).
class HardwareError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A link and the devices behind it (a CAN bus with its CANopen master and simulated nodes, an arm
// controller connection, a simulator). Lifecycle: configure() (blocking set-up), activate() (its own
// threads start), deactivate() (orderly stop: power stages off, threads joined). In stepped
// simulation nothing is activated: the runtime calls step() once per control period instead.
class HardwareComponent {
 public:
  using Clock = std::chrono::steady_clock;
  virtual ~HardwareComponent() = default;
  virtual std::string name() const = 0;
  // `idle` runs while a blocking exchange waits (stepped simulation advances simulated devices there).
  virtual void configure(const std::function<void()>& idle) = 0;
  virtual void activate(bool realtime_priority) = 0;
  virtual void deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) = 0;
  // Stepped simulation: advance devices and link by one control period. Called before the control
  // cycle (inputs) with `after_control` false and after it (urgent outputs) with true.
  virtual void step(Clock::time_point now, double period, bool after_control) = 0;
  // A blocking exchange's idle function in stepped mode (advances simulated devices), else empty.
  virtual std::function<void()> stepped_idle() { return {}; }
};

}  // namespace tendril::hardware
