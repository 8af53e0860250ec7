// SafetySupervisor: the per-robot safety state machine every command passes through.
// States DISABLED → ENABLED ⇄ PAUSED, any → FAULT, plus an e-stop latch that only reset_estop()
// clears. It checks goals and velocities against the robot's LimitSet, clamps each tick's setpoint
// into the soft limits, holds the robot when the servo stream stops, and faults on tracking error,
// repeated loop overruns and faults reported from drives or buses. Every transition, refusal,
// fault and hold goes into a lock-free event log.
//
// Threading: the control thread owns the supervisor and is the only caller of the mutating methods
// (request, tick, clamp_setpoint, servo_command_received, report_cycle, fault, estop, reset_estop);
// commands from other threads reach it through the command mailbox. Any thread may call state(),
// estop_latched(), check_goal(), check_velocity(), request_estop() and read the event log.
// All per-tick methods are noexcept and allocation-free.
//
// Fault acknowledgement: `disable` from FAULT acknowledges the fault and returns to DISABLED. A cause
// that persists raises the fault again when it is next reported (drive heartbeat, EMCY, bus-off are
// re-reported by the bus thread) or checked (tracking error on the first tick after enabling).
// From FAULT, enable/pause/resume are refused. While the e-stop is latched every state command is
// refused; reset_estop() clears the latch and any fault and leaves the robot DISABLED.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "tendril/safety/limit_set.hpp"
#include "tendril/safety/safety_event_log.hpp"
#include "tendril/safety/safety_types.hpp"

namespace tendril::safety {

// Control-loop timing policy. A control cycle that runs late is judged by what the loop protects at
// that moment, not by counting late 1 ms ticks:
//   - DISABLED or FAULT: nothing; the drives' power stages are off. Late cycles are counted only.
//   - ENABLED or PAUSED and at rest (no move, no servo stream, no joystick, setpoint still): the
//     drives hold the last setpoint by themselves, so a stalled loop changes nothing physically.
//     Counted only, however long.
//   - moving: while the loop does not run, the setpoint stands still (the drives stop at it) and no
//     safety check runs (servo timeout, tracking error, spring deflection, contact). The gap is
//     tolerated up to max_lost_control_time; a longer one faults (quick stop) with the lost time as
//     the cause, because the robot was moving blind for longer than its own watchdogs allow.
// Lost control time is the time since the previous control cycle ran, beyond one period.
struct SupervisorOptions {
  double command_timeout = 0.150;        // s without servo_command_received() before the servo stream holds
  double max_lost_control_time = 0.075;  // s; see lost_control_bound()
};

// The bound tendril uses for SupervisorOptions::max_lost_control_time: half the smaller of the
// command timeout (the operator's dead-man: the servo stream must hold within it) and the drives'
// heartbeat consumer time (the hardware backstop: a drive quick-stops by itself when the master is
// silent that long). A moving robot may go without control for at most half of either, so that a
// stall never takes more than half of the time those watchdogs promise to act within. With the
// SRMC's 150 ms and 250 ms: 75 ms. (dVRK's FPGA watchdog is 30 ms, at rest or moving, on a dedicated
// real-time PC; on shared machines a bare 1 kHz SCHED_FIFO loop itself stalls 20-35 ms, so tendril
// leaves the always-armed watchdog to the drives' heartbeat consumer and bounds lost time while
// moving.) Both arguments in s; returns s (0 if either is not positive).
double lost_control_bound(double command_timeout, double drive_heartbeat_consumer_time) noexcept;

// First limit violation found by a check; kind == kNone means the input is acceptable.
struct Violation {
  ViolationKind kind = ViolationKind::kNone;
  int joint = -1;      // index of the offending joint, -1 for size errors
  double value = 0.0;  // the offending value (for kWrongSize: the size given)
  double limit = 0.0;  // the limit it broke (for kWrongSize: the size expected)
  explicit operator bool() const noexcept { return kind != ViolationKind::kNone; }
};

struct ClampResult {
  int clamped_joints = 0;   // joints whose position or velocity was changed
  int first_joint = -1;     // first such joint
  bool non_finite = false;  // a non-finite position was found (velocity zeroed); tick() will fault
};

struct FaultInfo {
  FaultCode code = FaultCode::kNone;
  int joint = -1;
  double time = 0.0;
  char text[kSafetyTextSize] = {};
};

struct TickResult {
  OperatingState state = OperatingState::kDisabled;
  bool motion_allowed = false;  // ENABLED and no e-stop: setpoints may move
  bool servo_live = false;      // servo_jv stream refreshed within the timeout
};

class SafetySupervisor {
 public:
  // Throws std::invalid_argument if the options are out of range (a timeout or bound ≤ 0).
  explicit SafetySupervisor(LimitSet limits, SupervisorOptions options = {});

  const LimitSet& limits() const noexcept { return limits_; }
  const SupervisorOptions& options() const noexcept { return options_; }
  std::size_t joints() const noexcept { return limits_.size(); }

  // --- state machine (control thread) ---
  CommandResult request(double t, StateCommand command) noexcept;
  void estop(double t) noexcept;
  // The e-stop as pressed by someone (a session, a script): the event and the fault cause name them.
  // When the latch was already set by request_estop() for the same press, this names who pressed it;
  // when it was latched by an earlier press, the new press is logged as well.
  void estop(double t, const char* actor) noexcept;
  // Clears the latch. presses_seen: estop_presses() when the reset was asked for (on another thread);
  // a press after that (its command may still be queued behind this reset) keeps the latch, and the
  // reset is refused (kRefusedEstopLatched) and logged. kAnyPress: whatever was pressed.
  static constexpr std::uint64_t kAnyPress = ~std::uint64_t{0};
  CommandResult reset_estop(double t, std::uint64_t presses_seen = kAnyPress) noexcept;
  // External fault (drive heartbeat lost, EMCY, bus-off, …). detail may be null.
  void fault(double t, FaultCode code, int joint, const char* detail) noexcept;
  // A limit that needs the robot to stop but not to lose power (spring deflection, a stale contact
  // sensor): ENABLED -> PAUSED with the cause logged as a hold. Returns false (and logs nothing) when
  // the robot was not ENABLED.
  bool hold(double t, FaultCode code, int joint, const char* detail) noexcept;
  // Logs an event that changes no state: a command the runtime refused for a reason the supervisor
  // cannot see (kRefused, e.g. resume while a hold's cause persists) or a way out of a hold that ran
  // (kRecovery).
  void record(double t, EventKind kind, FaultCode code, int joint, const char* text) noexcept;

  // --- any thread ---
  // Latches the e-stop immediately as seen by state()/estop_latched(); the control thread logs it and
  // completes the transition at its next tick() or request().
  void request_estop() noexcept {
    estop_presses_.fetch_add(1, std::memory_order_acq_rel);
    estop_requested_.store(true, std::memory_order_release);
  }
  // How many times request_estop() was called: a reset asked for at count N clears only presses up to N.
  std::uint64_t estop_presses() const noexcept { return estop_presses_.load(std::memory_order_acquire); }
  OperatingState state() const noexcept;
  bool estop_latched() const noexcept;

  // --- checks (any thread; const, no logging) ---
  Violation check_goal(std::span<const double> goal) const noexcept;          // size, finite, [lower, upper]
  Violation check_velocity(std::span<const double> velocity) const noexcept;  // size, finite, |v| ≤ max
  // Writes a message such as "joint 'roll' velocity 3.2 rad/s exceeds the limit 1.5 rad/s" into buf.
  void describe(const Violation& violation, std::span<char> buf) const noexcept;
  std::string describe(const Violation& violation) const;  // allocates: not for the control thread

  // --- per tick (control thread) ---
  // Keeps positions inside [lower + margin, upper − margin] (zeroing velocity that pushes outwards)
  // and velocities within ±max_velocity.
  ClampResult clamp_setpoint(std::span<double> q, std::span<double> qd) const noexcept;
  void servo_command_received(double t) noexcept;
  // Servo timeout, measurement/setpoint validity and tracking error (while ENABLED or PAUSED, when the
  // drives follow a setpoint).
  TickResult tick(double t, std::span<const double> measured, std::span<const double> setpoint) noexcept;
  // Once per control cycle, before the cycle commands anything: `lost` is the time since the previous
  // cycle ran beyond one period (s), `moving` whether the robot was moving when that previous cycle
  // ended. Applies the loop-timing policy above; returns true when it faulted the robot.
  bool report_cycle(double t, double lost, bool moving) noexcept;

  bool servo_live() const noexcept { return servo_live_; }
  bool motion_allowed() const noexcept { return state() == OperatingState::kEnabled; }
  const FaultInfo& fault_cause() const noexcept { return fault_cause_; }  // control thread
  // Loop-timing record (control thread; copied into the robot's snapshot for other threads).
  struct LostControlRecord {
    std::uint64_t stalls_over_bound = 0;          // gaps longer than the bound, in any state
    std::uint64_t stalls_over_bound_at_rest = 0;  // of those, while not moving (counted, no fault)
    double max_lost = 0.0;                        // s, the longest gap beyond one period
    double max_lost_moving = 0.0;                 // s, the longest while moving
  };
  const LostControlRecord& lost_control() const noexcept { return lost_control_; }

  SafetyEventLog& events() noexcept { return events_; }
  const SafetyEventLog& events() const noexcept { return events_; }

 private:
  void transition(double t, OperatingState to, EventKind kind, FaultCode code, int joint,
                  const char* text) noexcept;
  void log(double t, EventKind kind, FaultCode code, int joint, OperatingState from, OperatingState to,
           const char* text) noexcept;
  void raise_fault(double t, FaultCode code, int joint, const char* text) noexcept;
  void process_estop_request(double t) noexcept;
  CommandResult refuse(double t, StateCommand command, CommandResult why) noexcept;

  LimitSet limits_;
  SupervisorOptions options_;
  std::atomic<OperatingState> state_{OperatingState::kDisabled};
  std::atomic<bool> estop_latched_{false};
  std::atomic<bool> estop_requested_{false};
  std::atomic<std::uint64_t> estop_presses_{0};
  bool estop_actor_known_ = false;  // the latched e-stop's event names who pressed it
  FaultInfo fault_cause_{};
  bool servo_live_ = false;
  double last_servo_time_ = 0.0;
  LostControlRecord lost_control_{};
  SafetyEventLog events_;
};

}  // namespace tendril::safety
