// SimulatedVelocityArm: a SIMULATED six-joint arm controller (UR5-like) at the hardware seam. A real UR
// is commanded over Ethernet (RTDE), not CAN, so its simulation sits at hardware::JointInterface rather
// than on the virtual CAN bus: the control cycle writes joint velocity commands and power requests and
// reads joint feedback exactly as it would from an RTDE driver.
//
// What is simulated, per controller cycle (default 500 Hz, the UR e-series controller rate):
//  * communication latency: a command is received at the controller's first cycle after it was written
//    and applied one controller period later (latency_periods);
//  * joint response: each joint's velocity follows the (speed-clamped) command as a first-order system
//    (time constant 20 ms) whose rate of change is limited by the joint's acceleration limit, and
//    integrates (trapezoidally) to position; no torque model (effort reads 0);
//  * hard joint limits: a joint that reaches one stops dead there and the arm faults (error 0x02, the
//    joint in error_detail); the other joints brake at their acceleration limits;
//  * a command watchdog: when no fresh command (any write()) arrives for 20 ms while on, the controller
//    brakes every joint at its acceleration limit and reports a protective stop (fault, error 0x01), as
//    a real arm does when its external control link goes quiet;
//  * power: off (brakes on, commands ignored) → switching on (brake release, 0.5 s) → on; quick stop
//    brakes at the acceleration limit and holds (PowerState::stopping) until `on` is requested again at
//    rest; `off` engages the brakes at once (stop category 0); a fault is left only through a
//    fault_reset edge, to off;
//  * encoder noise: Gaussian, seeded, on the reported position and velocity (not on the truth).
// The power request is one for the whole arm, combined from the joints' requests: fault_reset if any
// asks it, else off if any, else quick_stop if any, else on.
//
// Threads: read() and write() are called by the control thread; they only load and store LatestValue
// slots (no lock, no allocation). The simulated controller runs either in its own periodic thread
// (activate(): absolute deadlines with clock_nanosleep, SCHED_FIFO 70 when asked for and permitted) or,
// in stepped simulation, in step(now, period, after_control = false), which runs every controller cycle
// due in that period (four per step at the article's 8 ms, one every other step at 1 ms); the state it
// owns is touched by that one thread only.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <thread>

#include "tendril/drivers/hardware/joint_interface.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulation.hpp"

namespace tendril::sim {

inline constexpr std::size_t kSimulatedArmJoints = 6;

// The simulated controller's own states, reported as JointFeedback::device_state.
enum class ArmControllerState : std::uint8_t {
  power_off,        // brakes engaged
  brake_release,    // switching on
  running,          // following velocity commands
  quick_stop,       // braking at the acceleration limit, then holding at rest
  protective_stop,  // fault: braking, then holding at rest; needs a fault reset
};
const char* to_string(ArmControllerState state) noexcept;

// JointFeedback::error_code values.
inline constexpr std::uint32_t kArmErrorWatchdog = 0x01;  // no fresh command within the timeout
inline constexpr std::uint32_t kArmErrorJointLimit =
    0x02;  // a joint reached its hard limit (detail: joint + 1)

struct SimulatedArmJoint {
  double lower = -6.283185307179586;        // hard limit (rad)
  double upper = 6.283185307179586;         // hard limit (rad)
  double max_velocity = 3.141592653589793;  // rad/s: commands are clamped to it
  double max_acceleration = 8.0;            // rad/s²
  double initial_position = 0.0;            // rad
};

struct SimulatedVelocityArmParameters {
  std::string name = "simulated arm";
  std::array<SimulatedArmJoint, kSimulatedArmJoints> joints{};
  double controller_period = 0.002;      // s: 500 Hz, the UR e-series controller (CB3: 125 Hz)
  int latency_periods = 1;               // controller periods between receiving a command and applying it
  double velocity_time_constant = 0.02;  // s
  double watchdog_timeout = 0.02;        // s without a fresh command → protective stop
  double switch_on_time = 0.5;           // s of brake release (a real UR takes seconds; tests need not)
  double position_noise = 1e-5;          // rad (1σ) on reported positions (≈ 8 µm at the UR5's reach)
  double velocity_noise = 1e-4;          // rad/s (1σ) on reported velocities
  std::uint64_t seed = 0x5EED'A12Bu;
};

// Joints of the UR5 (limits from teleop::ur5_parameters(): ±360°, 180°/s, 8 rad/s²) at `initial`.
SimulatedVelocityArmParameters ur5_simulated_arm(const std::array<double, kSimulatedArmJoints>& initial = {});

// The true state (no noise), for the force sensor, tests and the console's ground truth.
struct ArmTruth {
  std::array<double, kSimulatedArmJoints> position{};
  std::array<double, kSimulatedArmJoints> velocity{};
  ArmControllerState state = ArmControllerState::power_off;
  double time = 0.0;          // simulated seconds since construction
  std::int64_t stamp_ns = 0;  // steady clock of the last cycle
};

class SimulatedVelocityArm final : public hardware::HardwareComponent, public hardware::JointInterface {
 public:
  // Throws SimulationSetupError naming the parameter when one is out of range.
  explicit SimulatedVelocityArm(SimulatedVelocityArmParameters parameters);
  ~SimulatedVelocityArm() override;
  SimulatedVelocityArm(const SimulatedVelocityArm&) = delete;
  SimulatedVelocityArm& operator=(const SimulatedVelocityArm&) = delete;

  const SimulatedVelocityArmParameters& parameters() const noexcept { return parameters_; }

  // hardware::HardwareComponent
  std::string name() const override { return parameters_.name; }
  void configure(const std::function<void()>& idle) override;
  void activate(bool realtime_priority) override;
  void deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) override;
  void step(Clock::time_point now, double period, bool after_control) override;

  // hardware::JointInterface
  std::size_t size() const noexcept override { return kSimulatedArmJoints; }
  hardware::CommandMode command_mode(std::size_t) const noexcept override {
    return hardware::CommandMode::velocity;
  }
  const char* error_source() const noexcept override { return "arm controller"; }
  const char* device_state_text(std::uint8_t state) const noexcept override;
  void read(std::size_t joint, hardware::JointFeedback& out) const noexcept override;
  void write(std::size_t joint, const hardware::JointCommand& command) noexcept override;

  // Thread-safe views.
  ArmTruth truth() const noexcept { return truth_.load(); }
  bool running() const noexcept { return thread_running_.load(); }
  RealtimeStatistics realtime_statistics() const noexcept { return stats_.load(); }

 private:
  struct CommandSlot {
    hardware::JointCommand command{};
    std::uint64_t sequence = 0;
  };
  struct Received {  // one controller cycle's view of the link
    std::array<double, kSimulatedArmJoints> velocity{};
    hardware::PowerRequest request = hardware::PowerRequest::off;
  };
  static constexpr std::size_t kMaxLatency = 16;

  void tick(Clock::time_point now, double dt) noexcept;
  void receive(double now_s) noexcept;
  void advance_power(const Received& applied, double dt) noexcept;
  void move_joints(const Received& applied, double dt) noexcept;
  void fault(std::uint32_t code, std::uint8_t detail) noexcept;
  void publish(Clock::time_point now) noexcept;
  void run(int fifo_priority) noexcept;

  SimulatedVelocityArmParameters parameters_;
  std::array<hardware::LatestValue<CommandSlot>, kSimulatedArmJoints> commands_{};
  std::array<hardware::LatestValue<hardware::JointFeedback>, kSimulatedArmJoints> feedback_{};
  hardware::LatestValue<ArmTruth> truth_;
  std::atomic<bool> configured_{false};

  // Owned by the simulation thread (or the stepping caller).
  std::array<double, kSimulatedArmJoints> position_{};
  std::array<double, kSimulatedArmJoints> velocity_{};
  std::array<std::uint64_t, kSimulatedArmJoints> last_sequence_{};
  std::array<Received, kMaxLatency + 1> delay_line_{};
  std::size_t delay_head_ = 0;
  ArmControllerState state_ = ArmControllerState::power_off;
  hardware::PowerRequest last_request_ = hardware::PowerRequest::off;
  double time_ = 0.0;
  double unsimulated_time_ = 0.0;  // stepped simulation: time stepped but not yet a whole controller cycle
  double last_command_time_ = 0.0;
  double switch_on_elapsed_ = 0.0;
  std::uint32_t error_count_ = 0;
  std::uint32_t error_code_ = 0;
  std::uint8_t error_detail_ = 0;
  std::mt19937_64 rng_;
  std::normal_distribution<double> unit_normal_{0.0, 1.0};

  // The real-time thread.
  std::atomic<bool> thread_running_{false};
  std::atomic<bool> stop_requested_{false};
  std::unique_ptr<std::thread> thread_;
  hardware::LatestValue<RealtimeStatistics> stats_;
};

}  // namespace tendril::sim
