// The control cycle: runs on the real-time thread (or from step()). No allocation, no locks, no
// blocking: state arrives through LatestValue slots and the command mailbox, and leaves the same way.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"

namespace tendril::server {

namespace {
using safety::OperatingState;
using Cia = canopen::Cia402State;

// True when every value lies within the operating (possibly tightened) position limits.
bool within_operating_limits(const OperatingLimits& limits, std::span<const double> q) noexcept {
  for (std::size_t i = 0; i < q.size(); ++i)
    if (!(q[i] >= limits.lower[i] && q[i] <= limits.upper[i])) return false;
  return true;
}

bool within_operating_velocity(const OperatingLimits& limits, std::span<const double> v) noexcept {
  for (std::size_t i = 0; i < v.size(); ++i)
    if (!(std::abs(v[i]) <= limits.max_velocity[i])) return false;
  return true;
}

template <std::size_t N>
void text(char (&buf)[N], const char* fmt, const char* a, double b = 0, double c = 0) noexcept {
  std::snprintf(buf, N, fmt, a, b, c);
}
}  // namespace

void RobotRuntime::Impl::control_cycle(std::chrono::steady_clock::time_point now, double lost) noexcept {
  const double t = std::chrono::duration<double>(now - start_time).count();
  now_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
  ticks.fetch_add(1, std::memory_order_relaxed);
  for (auto& r : robots) control_robot(*r, t, lost);
}

void RobotRuntime::Impl::apply_command(RobotUnit& r, const RobotCommand& c, double t) noexcept {
  auto& s = r.rt;
  auto& sup = *r.supervisor;
  const std::span<const double> values(c.values.data(), c.count);
  switch (c.kind) {
    case CommandKind::state:
      // A hold's way out: resume only once its cause has cleared (re-checked here, where the sensors
      // are read; the network thread checked the snapshot), never into an immediate new hold.
      if (c.state == safety::StateCommand::kResume && r.catheter && sup.state() == OperatingState::kPaused &&
          !catheter_may_resume(r, t))
        break;
      if (c.state == safety::StateCommand::kPause) s.withdrawing = false;
      if (c.state == safety::StateCommand::kPause && s.relaxing) {
        s.relaxing = false;  // pause while relaxing: the operator stops the relax
        s.relax_outcome = RelaxOutcome::stopped;
        sup.record(t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1,
                   "relax stopped by the operator");
      }
      if (sup.request(t, c.state) == safety::CommandResult::kAccepted &&
          c.state == safety::StateCommand::kEnable) {
        s.enable_pending = true;
        s.enable_started = t;
        s.drives_ready = false;
      }
      if (c.state == safety::StateCommand::kPause || c.state == safety::StateCommand::kResume) {
        // Pause and resume both start from rest at the current setpoint.
        s.servo_active = false;
        r.interpolator->reset({s.q_des.data(), r.n}, t);
        if (r.catheter)
          r.catheter->configuration->reset(t,
                                           Eigen::Vector4d(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]));
      }
      // Resuming or disabling is the operator's acknowledgement of a hold.
      if (c.state != safety::StateCommand::kPause && sup.state() != OperatingState::kPaused) {
        s.retraction_only = false;
        s.hold_code = safety::FaultCode::kNone;
      }
      break;
    case CommandKind::move_jp:
      // Re-checked here: the state may have changed since the network thread validated it.
      if (s.mode != ControlMode::joint || sup.state() != OperatingState::kEnabled || sup.check_goal(values) ||
          !within_operating_limits(s.limits, values))
        break;
      if (!s.drives_ready) {
        // Enabling: the goal starts as soon as every drive reports operation enabled.
        s.pending_goal = c.values;
        s.goal_pending = true;
        break;
      }
      s.servo_active = false;
      r.interpolator->retarget(t, values, {s.limits.max_velocity.data(), r.n},
                               {r.max_acceleration.data(), r.n});
      break;
    case CommandKind::servo_jv: {
      // Joint mode: every joint. Active compliance: insertion and roll (the bends comply). Held with
      // retraction allowed: insertion backwards only.
      const bool bends_still = c.count == 4 && values[2] == 0.0 && values[3] == 0.0;
      const bool allowed = (s.mode == ControlMode::joint && sup.state() == OperatingState::kEnabled) ||
                           (s.mode == ControlMode::active_compliance &&
                            sup.state() == OperatingState::kEnabled && bends_still) ||
                           (s.retraction_only && sup.state() == OperatingState::kPaused && bends_still &&
                            values[1] == 0.0 && values[0] <= 0.0);
      if (!allowed || !s.drives_ready || sup.check_velocity(values) ||
          !within_operating_velocity(s.limits, values))
        break;
      for (std::size_t i = 0; i < r.n; ++i) s.servo_velocity[i] = values[i];
      s.servo_active = true;
      s.last_servo_time = t;
      sup.servo_command_received(t);
      break;
    }
    case CommandKind::estop:
      sup.estop(t, c.actor);
      s.servo_active = false;
      s.estop_tick = ticks.load(std::memory_order_relaxed);
      break;
    case CommandKind::estop_reset:
      sup.reset_estop(t);
      break;
    case CommandKind::hold:
      s.console_deadman = false;  // the operator is gone: the console joystick lets go
      if (s.servo_active) {
        s.servo_active = false;
        r.interpolator->reset({s.q_des.data(), r.n}, t);
      }
      break;
    case CommandKind::mode: {
      // Only while holding (nothing moving, nothing pending); the setpoint is not touched, so the
      // switch never makes it jump.
      const auto to = static_cast<ControlMode>(c.index);
      const bool catheter_mode = to == ControlMode::configuration || to == ControlMode::active_compliance ||
                                 to == ControlMode::telemanipulation;
      if (holding(r, t) && (!catheter_mode || r.catheter)) {
        s.mode = to;
        s.path_target = s.path_step;
        if (r.catheter) {
          r.catheter->configuration->reset(t,
                                           Eigen::Vector4d(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]));
          s.console_deadman = false;  // a stream for the old mode must not carry over
          s.joystick_deadman = false;
          s.joystick_source = 0;
          s.joystick_axes = {};
        }
      }
      break;
    }
    case CommandKind::move_configuration:
      if (!r.catheter || s.mode != ControlMode::configuration || sup.state() != OperatingState::kEnabled ||
          !s.drives_ready)
        break;
      r.catheter->configuration->retarget(
          t, Eigen::Vector4d(c.values[0], c.values[1], c.values[2], c.values[3]));
      break;
    case CommandKind::joystick:
      for (std::size_t i = 0; i < 4; ++i) s.console_axes[i] = c.values[i];
      s.console_deadman = c.index != 0;
      s.console_time = t;
      break;
    case CommandKind::relax:
      if (r.catheter) catheter_start_relax(r, t);
      break;
    case CommandKind::withdraw:
      // Re-checked here: held with retraction allowed, and only ever backwards.
      if (r.catheter && s.retraction_only && sup.state() == OperatingState::kPaused && s.drives_ready &&
          std::isfinite(c.values[0]) && c.values[0] < s.q_des[0]) {
        s.withdrawing = true;
        s.withdraw_to = c.values[0];
      }
      break;
    case CommandKind::path_loaded:
      s.path_step = -1;
      s.path_target = -1;
      break;
    case CommandKind::path_step:
      if (s.mode != ControlMode::path_following || sup.state() != OperatingState::kEnabled ||
          !s.drives_ready || s.servo_active || sup.check_goal(values) ||
          !within_operating_limits(s.limits, values))
        break;
      s.path_target = c.index;
      s.path_goal = c.values;
      r.interpolator->retarget(t, values, {s.limits.max_velocity.data(), r.n},
                               {r.max_acceleration.data(), r.n});
      break;
  }
  ++s.commands_applied;
}

void RobotRuntime::Impl::control_robot(RobotUnit& r, double t, double lost) noexcept {
  auto& s = r.rt;
  auto& sup = *r.supervisor;
  const std::size_t n = r.n;

  // 1. Read the drives.
  std::array<canopen::DriveFeedback, kMaxJoints> fb;
  bool all_enabled = true;
  for (std::size_t i = 0; i < n; ++i) {
    const auto& b = r.bindings[i];
    fb[i] = b.bus->master->feedback(b.drive).load();
    s.q[i] = fb[i].position;
    s.qd[i] = fb[i].velocity;
    s.effort[i] = fb[i].effort;
    all_enabled = all_enabled && fb[i].state == Cia::operation_enabled;
  }
  if (!s.initialised) {
    for (std::size_t i = 0; i < n; ++i) {
      s.q_des[i] = s.q[i];
      s.heartbeat_was_alive[i] = fb[i].heartbeat_alive;
      s.nmt_was_operational[i] = fb[i].nmt == canopen::NmtState::operational;
      s.emcy_seen[i] = fb[i].emcy_count;
    }
    r.interpolator->reset({s.q_des.data(), n}, t);
    s.initialised = true;
  }

  // 2. Drive watchdogs: heartbeat loss and EMCY fault the robot (edge-triggered, logged once).
  for (std::size_t i = 0; i < n; ++i) {
    const char* joint = r.config.joints[i].name.c_str();
    if (s.heartbeat_was_alive[i] && !fb[i].heartbeat_alive) {
      char detail[96];
      text(detail, "drive '%s' stopped sending heartbeats", joint);
      sup.fault(t, safety::FaultCode::kDriveHeartbeatLost, static_cast<int>(i), detail);
    }
    s.heartbeat_was_alive[i] = fb[i].heartbeat_alive;
    // A drive that leaves NMT operational (it reset, or someone stopped it) has lost its PDO set-up.
    const bool operational = fb[i].nmt == canopen::NmtState::operational;
    if (s.nmt_was_operational[i] && !operational) {
      char detail[96];
      text(detail, "drive '%s' left NMT operational (reset or stopped)", joint);
      sup.fault(t, safety::FaultCode::kExternal, static_cast<int>(i), detail);
    }
    s.nmt_was_operational[i] = operational;
    if (fb[i].emcy_count != s.emcy_seen[i]) {
      s.emcy_seen[i] = fb[i].emcy_count;
      if (fb[i].last_emcy_code != canopen::emcy_code::no_error) {
        char detail[96];
        std::snprintf(detail, sizeof detail, "drive '%s' EMCY 0x%04X, error register 0x%02X", joint,
                      fb[i].last_emcy_code, fb[i].last_emcy_register);
        sup.fault(t, safety::FaultCode::kDriveEmergency, static_cast<int>(i), detail);
      }
    }
  }

  // 2b. Loop timing (safety::SupervisorOptions): a gap while moving beyond the bound faults before
  // anything is commanded; a shorter one delays the running trajectories by the lost time, so that
  // the setpoint continues from where it stood instead of jumping ahead by v·gap.
  if (lost > 0.0) {
    sup.report_cycle(t, lost, s.moving);
    if (s.moving) {
      r.interpolator->delay(lost);
      if (r.catheter) r.catheter->configuration->delay(lost);
    }
  }

  // 3. Operating limits (parameters may have tightened them), then commands from the network threads.
  if (const auto version = r.operating_limits.version(); version != s.limits_version) {
    s.limits = r.operating_limits.load();
    s.limits_version = version;
  }
  RobotCommand command;
  while (r.mailbox.pop(command)) apply_command(r, command, t);

  // 4. Enabling: wait for every drive to reach operation enabled, then start from where they are.
  OperatingState state = sup.state();
  if (state == OperatingState::kEnabled || state == OperatingState::kPaused) {
    if (!s.drives_ready) {
      if (all_enabled) {
        s.drives_ready = true;
        s.enable_pending = false;
        for (std::size_t i = 0; i < n; ++i) s.q_des[i] = s.q[i];
        r.interpolator->reset({s.q_des.data(), n}, t);
        if (s.goal_pending && state == OperatingState::kEnabled)
          r.interpolator->retarget(t, {s.pending_goal.data(), n}, {s.limits.max_velocity.data(), n},
                                   {r.max_acceleration.data(), n});
        s.goal_pending = false;
      } else if (t - s.enable_started > r.config.enable_timeout_ms / 1000.0) {
        for (std::size_t i = 0; i < n; ++i) {
          if (fb[i].state == Cia::operation_enabled) continue;
          char detail[96];
          std::snprintf(detail, sizeof detail, "drive '%s' did not enable within %d ms (it reports %s)",
                        r.config.joints[i].name.c_str(), r.config.enable_timeout_ms,
                        canopen::to_string(fb[i].state));
          sup.fault(t, safety::FaultCode::kExternal, static_cast<int>(i), detail);
          break;
        }
      }
    } else if (!all_enabled) {
      for (std::size_t i = 0; i < n; ++i) {
        if (fb[i].state == Cia::operation_enabled) continue;
        char detail[96];
        std::snprintf(detail, sizeof detail, "drive '%s' left operation enabled (it reports %s)",
                      r.config.joints[i].name.c_str(), canopen::to_string(fb[i].state));
        sup.fault(t, safety::FaultCode::kDriveEmergency, static_cast<int>(i), detail);
        break;
      }
    }
  } else {
    s.drives_ready = false;
    s.enable_pending = false;
    s.goal_pending = false;
  }
  state = sup.state();

  // 5. Mid-level control: joint interpolation or integrated servo velocity.
  const JointArray setpoint_before = s.q_des;
  const std::span<double> q_des(s.q_des.data(), n), qd_des(s.qd_des.data(), n), qdd_des(s.qdd_des.data(), n);
  if (r.catheter) {
    catheter_sensors(r, t, state);
    state = sup.state();
  }
  const bool catheter_mode =
      r.catheter && (s.mode == ControlMode::configuration || s.mode == ControlMode::active_compliance ||
                     s.mode == ControlMode::telemanipulation);
  if (state == OperatingState::kEnabled && s.drives_ready && catheter_mode) {
    catheter_mid_level(r, t);
  } else if (state == OperatingState::kEnabled && s.drives_ready) {
    // The operating servo timeout may be shorter than the supervisor's configured one.
    if (s.servo_active && sup.servo_live() && t - s.last_servo_time <= s.limits.servo_timeout_s) {
      for (std::size_t i = 0; i < n; ++i) {
        s.qd_des[i] = s.servo_velocity[i];
        s.q_des[i] += s.servo_velocity[i] * period;
      }
      r.interpolator->reset(q_des, t);
    } else {
      if (s.servo_active) {  // the stream stopped: hold where the setpoint is
        s.servo_active = false;
        r.interpolator->reset(q_des, t);
      }
      r.interpolator->sample(t, q_des, qd_des, qdd_des);
    }
  } else if (state == OperatingState::kPaused && s.drives_ready) {
    for (std::size_t i = 0; i < n; ++i) s.qd_des[i] = 0.0;  // hold the setpoint
    if (r.catheter && s.retraction_only) catheter_retraction(r, t);
    if (r.catheter) catheter_relax(r, t);
  } else {
    // Not commanding: the setpoint follows the measurement so that enabling never jumps.
    for (std::size_t i = 0; i < n; ++i) {
      s.q_des[i] = s.q[i];
      s.qd_des[i] = 0.0;
    }
    s.servo_active = false;
    r.interpolator->reset(q_des, t);
    if (r.catheter)
      r.catheter->configuration->reset(t, Eigen::Vector4d(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]));
  }
  if ((state == OperatingState::kEnabled ||
       (state == OperatingState::kPaused && (s.retraction_only || s.relaxing))) &&
      s.drives_ready) {
    const JointArray unclamped = s.q_des;
    auto clamp = sup.clamp_setpoint(q_des, qd_des);
    // Tightened operating limits: the setpoint stops at the boundary. A setpoint already outside (the
    // robot was moved while disabled) is never pulled in with a jump: it may only move back inwards.
    for (std::size_t i = 0; i < n; ++i) {
      const double lo = s.limits.lower[i], hi = s.limits.upper[i], before = setpoint_before[i];
      double bounded = q_des[i];
      if (bounded < lo) bounded = before >= lo ? lo : std::max(bounded, before);
      if (bounded > hi) bounded = before <= hi ? hi : std::min(bounded, before);
      if (bounded != q_des[i]) {
        q_des[i] = bounded;
        qd_des[i] = 0.0;
        ++clamp.clamped_joints;
      }
    }
    if (clamp.clamped_joints > 0 && !s.servo_active) {
      // The interpolator must not keep pulling against a clamped setpoint.
      r.interpolator->reset(q_des, t);
      // Only a clamped position stops a configuration move; a clamped velocity (the coupling term of
      // eq. 4.21 on top of a quintic at its bound) leaves the setpoint where the controller put it.
      if (r.catheter && s.mode == ControlMode::configuration && unclamped != s.q_des)
        r.catheter->configuration->reset(t, Eigen::Vector4d(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]));
    }
  }

  // 6. Safety: servo timeout, tracking error.
  const bool tracking = state == OperatingState::kEnabled && s.drives_ready;
  sup.tick(t, {s.q.data(), n},
           tracking ? std::span<const double>(s.q_des.data(), n) : std::span<const double>(s.q.data(), n));
  state = sup.state();

  // 7. Write the drives.
  const bool estop = sup.estop_latched();
  for (std::size_t i = 0; i < n; ++i) {
    const auto& b = r.bindings[i];
    canopen::DriveCommand dc = b.bus->master->command(b.drive).load();
    if (estop || state == OperatingState::kFault) {
      dc.request = canopen::DriveRequest::quick_stop;
    } else if (state == OperatingState::kEnabled || state == OperatingState::kPaused) {
      dc.request = canopen::DriveRequest::enable;
    } else if (fb[i].state == Cia::fault) {
      dc.request = canopen::DriveRequest::fault_reset;  // acknowledged by disable: clear the drive fault
    } else {
      dc.request = canopen::DriveRequest::disable;
    }
    dc.target_position = s.q_des[i];
    ++dc.sequence;
    b.bus->master->set_command(b.drive, dc);  // wakes the bus thread for a quick stop or disable
  }

  // 7b. Path following: a step is reached when its move ends at the step's joint values. A move cut
  // short (pause, clamp, fault, disable) leaves the last reached step as the current one.
  if (s.path_target != s.path_step && r.interpolator->done(t)) {
    bool at_goal = s.drives_ready;
    for (std::size_t i = 0; i < n; ++i) at_goal = at_goal && std::abs(s.q_des[i] - s.path_goal[i]) <= 1e-6;
    if (at_goal) s.path_step = s.path_target;
    s.path_target = s.path_step;
  }

  // What a stall before the next cycle would interrupt (2b).
  bool setpoint_moving = false;
  for (std::size_t i = 0; i < n; ++i) setpoint_moving = setpoint_moving || s.qd_des[i] != 0.0;
  s.moving = (state == OperatingState::kEnabled || state == OperatingState::kPaused) && s.drives_ready &&
             (setpoint_moving || !holding(r, t));

  // 8. Publish.
  RobotSnapshot snap;
  snap.tick = ticks.load(std::memory_order_relaxed);
  snap.time = t;
  snap.joints = static_cast<std::uint32_t>(n);
  for (std::size_t i = 0; i < n; ++i) {
    snap.position[i] = s.q[i];
    snap.velocity[i] = s.qd[i];
    snap.effort[i] = s.effort[i];
    snap.setpoint[i] = s.q_des[i];
    snap.setpoint_velocity[i] = s.qd_des[i];
    snap.drive_state[i] = fb[i].state;
    snap.heartbeat_alive[i] = fb[i].heartbeat_alive;
  }
  snap.state = state;
  snap.estop = estop;
  snap.drives_ready = s.drives_ready;
  snap.busy = s.drives_ready ? !holding(r, t) : (s.enable_pending || s.goal_pending);
  snap.fault = sup.fault_cause();
  snap.lost_control = sup.lost_control();
  snap.estop_tick = s.estop_tick;
  snap.commands_applied = s.commands_applied;
  snap.mailbox_full = r.mailbox_full.load(std::memory_order_relaxed);
  snap.mode = s.mode;
  snap.path_step = s.path_step;
  snap.path_target = s.path_target;
  if (r.catheter) {
    snap.spring_deflection = s.spring_deflection;
    snap.deflection_fresh = s.deflection_fresh;
    snap.retraction_only = s.retraction_only;
    snap.hold_code = s.hold_code;
    const auto goal = r.catheter->configuration->goal();
    for (std::size_t i = 0; i < 4; ++i) snap.configuration_goal[i] = goal[static_cast<Eigen::Index>(i)];
    snap.configuration_moving = s.mode == ControlMode::configuration && !r.catheter->configuration->done(t);
    snap.joystick_source = s.joystick_source;
    snap.joystick_deadman = s.joystick_deadman;
    snap.joystick_conflict = s.joystick_conflict;
    snap.joystick_axes = s.joystick_axes;
    snap.relaxing = s.relaxing;
    snap.relax_outcome = s.relax_outcome;
    snap.withdrawing = s.withdrawing;
  }
  r.snapshot.store(snap);
}

}  // namespace tendril::server
