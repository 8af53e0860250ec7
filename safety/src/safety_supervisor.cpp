#include "tendril/safety/safety_supervisor.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>

namespace tendril::safety {
namespace {

void copy_text(char (&dst)[kSafetyTextSize], const char* src) noexcept {
  std::snprintf(dst, sizeof(dst), "%s", src != nullptr ? src : "");
}

}  // namespace

SafetySupervisor::SafetySupervisor(LimitSet limits, SupervisorOptions options)
    : limits_(std::move(limits)), options_(options) {
  if (!std::isfinite(options.command_timeout) || options.command_timeout <= 0.0)
    throw std::invalid_argument("SafetySupervisor: command_timeout must be > 0 s, got " +
                                std::to_string(options.command_timeout));
  if (!std::isfinite(options.max_lost_control_time) || options.max_lost_control_time <= 0.0)
    throw std::invalid_argument("SafetySupervisor: max_lost_control_time must be > 0 s, got " +
                                std::to_string(options.max_lost_control_time));
}

double lost_control_bound(double command_timeout, double drive_heartbeat_consumer_time) noexcept {
  if (!(command_timeout > 0.0) || !(drive_heartbeat_consumer_time > 0.0)) return 0.0;
  return 0.5 * std::min(command_timeout, drive_heartbeat_consumer_time);
}

OperatingState SafetySupervisor::state() const noexcept {
  if (estop_requested_.load(std::memory_order_acquire)) return OperatingState::kFault;
  return state_.load(std::memory_order_acquire);
}

bool SafetySupervisor::estop_latched() const noexcept {
  return estop_latched_.load(std::memory_order_acquire) || estop_requested_.load(std::memory_order_acquire);
}

void SafetySupervisor::log(double t, EventKind kind, FaultCode code, int joint, OperatingState from,
                           OperatingState to, const char* text) noexcept {
  SafetyEvent e;
  e.time = t;
  e.kind = kind;
  e.code = code;
  e.from = from;
  e.to = to;
  e.joint = joint;
  copy_text(e.text, text);
  events_.push(e);
}

void SafetySupervisor::transition(double t, OperatingState to, EventKind kind, FaultCode code, int joint,
                                  const char* text) noexcept {
  const OperatingState from = state_.load(std::memory_order_relaxed);
  state_.store(to, std::memory_order_release);
  if (to != OperatingState::kEnabled) servo_live_ = false;  // a new enable needs a fresh servo stream
  log(t, kind, code, joint, from, to, text);
}

void SafetySupervisor::raise_fault(double t, FaultCode code, int joint, const char* text) noexcept {
  const OperatingState from = state_.load(std::memory_order_relaxed);
  if (from == OperatingState::kFault) {
    // Already faulted: record a new cause once, not on every re-report of the same one.
    if (code != fault_cause_.code || joint != fault_cause_.joint)
      log(t, EventKind::kFault, code, joint, from, from, text);
    return;
  }
  fault_cause_.code = code;
  fault_cause_.joint = joint;
  fault_cause_.time = t;
  copy_text(fault_cause_.text, text);
  transition(t, OperatingState::kFault, EventKind::kFault, code, joint, text);
}

void SafetySupervisor::process_estop_request(double t) noexcept {
  if (estop_requested_.load(std::memory_order_acquire)) estop(t);
}

void SafetySupervisor::estop(double t) noexcept { estop(t, nullptr); }

void SafetySupervisor::estop(double t, const char* actor) noexcept {
  const bool named = actor != nullptr && actor[0] != '\0';
  char text[96];
  if (estop_latched_.load(std::memory_order_relaxed)) {
    estop_requested_.store(false, std::memory_order_release);
    if (!named) return;
    const OperatingState s = state_.load(std::memory_order_relaxed);
    if (!estop_actor_known_) {
      std::snprintf(text, sizeof(text), "e-stop pressed by %s", actor);
      copy_text(fault_cause_.text, text);
    } else {
      std::snprintf(text, sizeof(text), "e-stop pressed again by %s (already latched)", actor);
    }
    estop_actor_known_ = true;
    log(t, EventKind::kEstop, FaultCode::kEstop, -1, s, s, text);
    return;
  }
  estop_latched_.store(true, std::memory_order_release);
  // This press may be the one request_estop() announced: it is taken here (the latch is already set,
  // so state() never shows the old state in between).
  estop_requested_.store(false, std::memory_order_release);
  estop_actor_known_ = named;
  const OperatingState from = state_.load(std::memory_order_relaxed);
  fault_cause_.code = FaultCode::kEstop;
  fault_cause_.joint = -1;
  fault_cause_.time = t;
  if (named)
    std::snprintf(text, sizeof(text), "e-stop pressed by %s", actor);
  else
    std::snprintf(text, sizeof(text), "e-stop pressed");
  copy_text(fault_cause_.text, text);
  state_.store(OperatingState::kFault, std::memory_order_release);
  servo_live_ = false;
  if (named)
    std::snprintf(text, sizeof(text), "e-stop latched by %s; motion stopped", actor);
  else
    std::snprintf(text, sizeof(text), "e-stop latched; motion stopped");
  log(t, EventKind::kEstop, FaultCode::kEstop, -1, from, OperatingState::kFault, text);
}

void SafetySupervisor::record(double t, EventKind kind, FaultCode code, int joint,
                              const char* text) noexcept {
  process_estop_request(t);
  const OperatingState s = state_.load(std::memory_order_relaxed);
  log(t, kind, code, joint, s, s, text);
}

CommandResult SafetySupervisor::reset_estop(double t, std::uint64_t presses_seen) noexcept {
  process_estop_request(t);
  if (!estop_latched_.load(std::memory_order_relaxed)) return CommandResult::kAlreadyInState;
  if (presses_seen != kAnyPress && estop_presses_.load(std::memory_order_acquire) != presses_seen) {
    // Pressed again after this reset was asked for: that press stands.
    const OperatingState s = state_.load(std::memory_order_relaxed);
    log(t, EventKind::kRefused, FaultCode::kEstop, -1, s, s,
        "e-stop reset refused: the e-stop was pressed again after the reset was asked for");
    return CommandResult::kRefusedEstopLatched;
  }
  estop_latched_.store(false, std::memory_order_release);
  fault_cause_ = FaultInfo{};
  transition(t, OperatingState::kDisabled, EventKind::kEstopReset, FaultCode::kEstop, -1,
             "e-stop reset; robot is DISABLED");
  return CommandResult::kAccepted;
}

void SafetySupervisor::fault(double t, FaultCode code, int joint, const char* detail) noexcept {
  process_estop_request(t);
  char text[kSafetyTextSize];
  if (joint >= 0 && static_cast<std::size_t>(joint) < limits_.size())
    std::snprintf(text, sizeof(text), "%s on joint '%s'%s%s", to_string(code), limits_[joint].name.c_str(),
                  detail ? ": " : "", detail ? detail : "");
  else
    std::snprintf(text, sizeof(text), "%s%s%s", to_string(code), detail ? ": " : "", detail ? detail : "");
  raise_fault(t, code == FaultCode::kNone ? FaultCode::kExternal : code, joint, text);
}

bool SafetySupervisor::hold(double t, FaultCode code, int joint, const char* detail) noexcept {
  process_estop_request(t);
  if (state_.load(std::memory_order_relaxed) != OperatingState::kEnabled) return false;
  char text[kSafetyTextSize];
  if (joint >= 0 && static_cast<std::size_t>(joint) < limits_.size())
    std::snprintf(text, sizeof(text), "hold: %s on joint '%s'%s%s", to_string(code),
                  limits_[joint].name.c_str(), detail ? ": " : "", detail ? detail : "");
  else
    std::snprintf(text, sizeof(text), "hold: %s%s%s", to_string(code), detail ? ": " : "",
                  detail ? detail : "");
  transition(t, OperatingState::kPaused, EventKind::kHold, code, joint, text);
  return true;
}

CommandResult SafetySupervisor::refuse(double t, StateCommand command, CommandResult why) noexcept {
  char text[96];
  std::snprintf(text, sizeof(text), "%s %s", to_string(command), to_string(why));
  const OperatingState s = state_.load(std::memory_order_relaxed);
  log(t, EventKind::kRefused, fault_cause_.code, -1, s, s, text);
  return why;
}

CommandResult SafetySupervisor::request(double t, StateCommand command) noexcept {
  process_estop_request(t);
  if (estop_latched_.load(std::memory_order_relaxed))
    return refuse(t, command, CommandResult::kRefusedEstopLatched);

  const OperatingState s = state_.load(std::memory_order_relaxed);
  auto go = [&](OperatingState to) {
    char text[96];
    std::snprintf(text, sizeof(text), "%s: %s -> %s", to_string(command), to_string(s), to_string(to));
    if (s == OperatingState::kFault) {
      std::snprintf(text, sizeof(text), "%s: fault '%s' acknowledged, FAULT -> %s", to_string(command),
                    to_string(fault_cause_.code), to_string(to));
      fault_cause_ = FaultInfo{};
    }
    transition(t, to, EventKind::kTransition, FaultCode::kNone, -1, text);
    return CommandResult::kAccepted;
  };

  switch (command) {
    case StateCommand::kEnable:
      if (s == OperatingState::kDisabled) return go(OperatingState::kEnabled);
      if (s == OperatingState::kEnabled) return CommandResult::kAlreadyInState;
      if (s == OperatingState::kFault) return refuse(t, command, CommandResult::kRefusedInFault);
      return refuse(t, command, CommandResult::kRefusedInvalidTransition);  // PAUSED: use resume
    case StateCommand::kDisable:
      if (s == OperatingState::kDisabled) return CommandResult::kAlreadyInState;
      return go(OperatingState::kDisabled);
    case StateCommand::kPause:
      if (s == OperatingState::kEnabled) return go(OperatingState::kPaused);
      if (s == OperatingState::kPaused) return CommandResult::kAlreadyInState;
      if (s == OperatingState::kFault) return refuse(t, command, CommandResult::kRefusedInFault);
      return refuse(t, command, CommandResult::kRefusedInvalidTransition);
    case StateCommand::kResume:
      if (s == OperatingState::kPaused) return go(OperatingState::kEnabled);
      if (s == OperatingState::kEnabled) return CommandResult::kAlreadyInState;
      if (s == OperatingState::kFault) return refuse(t, command, CommandResult::kRefusedInFault);
      return refuse(t, command, CommandResult::kRefusedInvalidTransition);
  }
  return refuse(t, command, CommandResult::kRefusedInvalidTransition);
}

Violation SafetySupervisor::check_goal(std::span<const double> goal) const noexcept {
  if (goal.size() != limits_.size())
    return {ViolationKind::kWrongSize, -1, static_cast<double>(goal.size()),
            static_cast<double>(limits_.size())};
  for (std::size_t i = 0; i < goal.size(); ++i) {
    const JointLimit& j = limits_[i];
    const int joint = static_cast<int>(i);
    if (!std::isfinite(goal[i])) return {ViolationKind::kNotFinite, joint, goal[i], 0.0};
    if (goal[i] < j.lower) return {ViolationKind::kBelowLower, joint, goal[i], j.lower};
    if (goal[i] > j.upper) return {ViolationKind::kAboveUpper, joint, goal[i], j.upper};
  }
  return {};
}

Violation SafetySupervisor::check_velocity(std::span<const double> velocity) const noexcept {
  if (velocity.size() != limits_.size())
    return {ViolationKind::kWrongSize, -1, static_cast<double>(velocity.size()),
            static_cast<double>(limits_.size())};
  for (std::size_t i = 0; i < velocity.size(); ++i) {
    const int joint = static_cast<int>(i);
    if (!std::isfinite(velocity[i])) return {ViolationKind::kNotFinite, joint, velocity[i], 0.0};
    if (std::abs(velocity[i]) > limits_[i].max_velocity)
      return {ViolationKind::kAboveMaxVelocity, joint, velocity[i], limits_[i].max_velocity};
  }
  return {};
}

void SafetySupervisor::describe(const Violation& v, std::span<char> buf) const noexcept {
  if (buf.empty()) return;
  const bool has_joint = v.joint >= 0 && static_cast<std::size_t>(v.joint) < limits_.size();
  const char* name = has_joint ? limits_[v.joint].name.c_str() : "";
  const char* unit = has_joint ? limits_[v.joint].unit.c_str() : "";
  switch (v.kind) {
    case ViolationKind::kNone:
      std::snprintf(buf.data(), buf.size(), "ok");
      break;
    case ViolationKind::kWrongSize:
      std::snprintf(buf.data(), buf.size(), "expected %.0f values (one per joint), got %.0f", v.limit,
                    v.value);
      break;
    case ViolationKind::kNotFinite:
      std::snprintf(buf.data(), buf.size(), "joint '%s' value is not a finite number", name);
      break;
    case ViolationKind::kBelowLower:
      std::snprintf(buf.data(), buf.size(), "joint '%s' position %.4g %s is below the lower limit %.4g %s",
                    name, v.value, unit, v.limit, unit);
      break;
    case ViolationKind::kAboveUpper:
      std::snprintf(buf.data(), buf.size(), "joint '%s' position %.4g %s is above the upper limit %.4g %s",
                    name, v.value, unit, v.limit, unit);
      break;
    case ViolationKind::kAboveMaxVelocity:
      std::snprintf(buf.data(), buf.size(), "joint '%s' velocity %.4g %s/s exceeds the limit %.4g %s/s", name,
                    std::abs(v.value), unit, v.limit, unit);
      break;
  }
}

std::string SafetySupervisor::describe(const Violation& violation) const {
  char buf[160];
  describe(violation, std::span<char>(buf));
  return buf;
}

ClampResult SafetySupervisor::clamp_setpoint(std::span<double> q, std::span<double> qd) const noexcept {
  ClampResult r;
  const std::size_t n = std::min({q.size(), qd.size(), limits_.size()});
  for (std::size_t i = 0; i < n; ++i) {
    const JointLimit& j = limits_[i];
    const double lo = j.lower + j.soft_margin, hi = j.upper - j.soft_margin;
    bool changed = false;
    if (!std::isfinite(qd[i])) {
      qd[i] = 0.0;
      changed = true;
    }
    if (!std::isfinite(q[i])) {
      // Nothing safe to clamp to here; stop the joint and let tick() fault on the setpoint.
      r.non_finite = true;
      qd[i] = 0.0;
      changed = true;
    } else if (q[i] < lo) {
      q[i] = lo;
      qd[i] = std::max(qd[i], 0.0);
      changed = true;
    } else if (q[i] > hi) {
      q[i] = hi;
      qd[i] = std::min(qd[i], 0.0);
      changed = true;
    }
    if (std::abs(qd[i]) > j.max_velocity) {
      qd[i] = std::clamp(qd[i], -j.max_velocity, j.max_velocity);
      changed = true;
    }
    if (changed) {
      if (r.first_joint < 0) r.first_joint = static_cast<int>(i);
      ++r.clamped_joints;
    }
  }
  return r;
}

void SafetySupervisor::servo_command_received(double t) noexcept {
  if (!std::isfinite(t)) return;
  last_servo_time_ = t;
  servo_live_ = true;
}

TickResult SafetySupervisor::tick(double t, std::span<const double> measured,
                                  std::span<const double> setpoint) noexcept {
  process_estop_request(t);

  if (servo_live_ && t - last_servo_time_ > options_.command_timeout) {
    servo_live_ = false;
    char text[96];
    std::snprintf(text, sizeof(text), "servo_jv not refreshed for %.0f ms (timeout %.0f ms); holding",
                  (t - last_servo_time_) * 1e3, options_.command_timeout * 1e3);
    const OperatingState s = state_.load(std::memory_order_relaxed);
    log(t, EventKind::kHold, FaultCode::kCommandTimeout, -1, s, s, text);
  }

  const OperatingState s = state_.load(std::memory_order_relaxed);
  if (s == OperatingState::kEnabled || s == OperatingState::kPaused) {
    char text[96];
    if (measured.size() != limits_.size() || setpoint.size() != limits_.size()) {
      std::snprintf(text, sizeof(text), "expected %zu measured and setpoint values, got %zu and %zu",
                    limits_.size(), measured.size(), setpoint.size());
      raise_fault(
          t, measured.size() != limits_.size() ? FaultCode::kInvalidMeasurement : FaultCode::kInvalidSetpoint,
          -1, text);
    } else {
      for (std::size_t i = 0; i < limits_.size(); ++i) {
        const JointLimit& j = limits_[i];
        const int joint = static_cast<int>(i);
        if (!std::isfinite(measured[i])) {
          std::snprintf(text, sizeof(text), "joint '%s' measured position is not a finite number",
                        j.name.c_str());
          raise_fault(t, FaultCode::kInvalidMeasurement, joint, text);
          break;
        }
        if (!std::isfinite(setpoint[i])) {
          std::snprintf(text, sizeof(text), "joint '%s' setpoint is not a finite number", j.name.c_str());
          raise_fault(t, FaultCode::kInvalidSetpoint, joint, text);
          break;
        }
        const double error = std::abs(measured[i] - setpoint[i]);
        if (error > j.max_tracking_error) {
          std::snprintf(text, sizeof(text), "joint '%s' tracking error %.4g %s exceeds the limit %.4g %s",
                        j.name.c_str(), error, j.unit.c_str(), j.max_tracking_error, j.unit.c_str());
          raise_fault(t, FaultCode::kTrackingError, joint, text);
          break;
        }
      }
    }
  }

  TickResult r;
  r.state = state();
  r.motion_allowed = r.state == OperatingState::kEnabled;
  r.servo_live = servo_live_;
  return r;
}

bool SafetySupervisor::report_cycle(double t, double lost, bool moving) noexcept {
  if (!(lost > 0.0)) return false;  // on time (or a non-finite report, which only the clock can make)
  auto& r = lost_control_;
  const OperatingState s = state_.load(std::memory_order_relaxed);
  const bool protecting = s == OperatingState::kEnabled || s == OperatingState::kPaused;
  r.max_lost = std::max(r.max_lost, lost);
  // Motion counts only with the power stages on: a setpoint that changes while DISABLED moves nothing.
  if (moving && protecting) r.max_lost_moving = std::max(r.max_lost_moving, lost);
  if (lost <= options_.max_lost_control_time) return false;
  ++r.stalls_over_bound;
  if (!moving || !protecting) {
    // At rest or powered off: the drives hold (or are off) without the loop. Counted, not faulted.
    if (protecting) ++r.stalls_over_bound_at_rest;
    return false;
  }
  // Measured by the loop's own clock (the time since its previous cycle), not by a device: the
  // computer did not run the loop in time. A device that went silent has a fault of its own that names it.
  char text[kSafetyTextSize];
  std::snprintf(text, sizeof(text),
                "the control loop ran %.0f ms late while moving (bound %.0f ms, measured by its own clock): "
                "the computer was too busy, not a device going silent; quick stop",
                lost * 1e3, options_.max_lost_control_time * 1e3);
  raise_fault(t, FaultCode::kLostControlTime, -1, text);
  return true;
}

}  // namespace tendril::safety
