// The control cycle: runs on the real-time thread (or from step()). No allocation, no locks, no
// blocking: state arrives through the hardware interfaces' LatestValue slots and the command mailbox,
// and leaves the same way. Robot-type behaviour comes in through RobotController, never by name.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "runtime_impl.hpp"

namespace tendril::server {

namespace {
using hardware::PowerState;
using safety::OperatingState;

template <std::size_t N>
void text(char (&buf)[N], const char* fmt, const char* a) noexcept {
  std::snprintf(buf, N, fmt, a);
}
}  // namespace

// ---- UnitContext: what a robot type's controller may do ----------------------------------------

bool UnitContext::servo_live() const noexcept {
  const auto& s = unit_.rt;
  // While ENABLED the supervisor's servo timeout applies as well (it holds the robot when it expires).
  return s.servo_active && t - s.last_servo_time <= s.limits.servo_timeout_s &&
         (state != safety::OperatingState::kEnabled || unit_.supervisor->servo_live());
}
std::span<const double> UnitContext::servo_velocity() const noexcept {
  return {unit_.rt.servo_velocity.data(), n};
}
void UnitContext::stop_servo() noexcept { unit_.rt.servo_active = false; }
bool UnitContext::hold(safety::FaultCode code, int joint, const char* detail) noexcept {
  if (!unit_.supervisor->hold(t, code, joint, detail)) return false;
  auto& s = unit_.rt;
  s.hold_code = code;
  s.servo_active = false;
  unit_.interpolator->reset({s.q_des.data(), n}, t);
  unit_.controller->reset(*this);
  return true;
}
safety::FaultCode UnitContext::hold_cause() const noexcept { return unit_.rt.hold_code; }
void UnitContext::setpoint_moved() noexcept { unit_.interpolator->reset({unit_.rt.q_des.data(), n}, t); }

// ---- the cycle ------------------------------------------------------------------------------------

void RobotRuntime::Impl::control_cycle(std::chrono::steady_clock::time_point now, double lost) noexcept {
  const double t = std::chrono::duration<double>(now - start_time).count();
  now_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
  ticks.fetch_add(1, std::memory_order_relaxed);
  for (auto& r : robots) control_robot(*r, t, lost);
}

void RobotRuntime::Impl::end_hold(RobotUnit& r) noexcept {
  if (r.rt.hold_code == safety::FaultCode::kNone) return;
  r.rt.hold_code = safety::FaultCode::kNone;
  r.controller->hold_ended(*r.context);
}

void RobotRuntime::Impl::apply_command(RobotUnit& r, const RobotCommand& c, double t) noexcept {
  auto& s = r.rt;
  auto& sup = *r.supervisor;
  auto& ctx = *r.context;
  const std::span<const double> values(c.values.data(), c.count);
  switch (c.kind) {
    case CommandKind::state: {
      // Resume ends a hold only when the robot type says its cause has cleared (the network thread
      // refused it already; the state may have changed since).
      // A hold's way out: resume only once its cause has cleared (re-checked here, where the sensors
      // are read; the network thread checked the snapshot), never into an immediate new hold.
      if (c.state == safety::StateCommand::kResume && sup.state() == OperatingState::kPaused) {
        char why[96] = {};
        if (!r.controller->hold_cleared(ctx, why, sizeof why)) {
          sup.record(t, safety::EventKind::kRefused, s.hold_code, -1,
                     why[0] ? why : "resume refused: the hold's cause persists");
          break;
        }
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
        r.controller->reset(ctx);
      }
      // Resuming or disabling is the operator's acknowledgement of a hold.
      if (c.state != safety::StateCommand::kPause && sup.state() != OperatingState::kPaused) end_hold(r);
      ctx.state = sup.state();
      r.controller->state_command(ctx, c.state);
      break;
    }
    case CommandKind::move_jp:
      // Re-checked here: the state may have changed since the network thread checked it.
      if (s.mode != kJointMode || sup.state() != OperatingState::kEnabled || sup.check_goal(values) ||
          !s.limits.within_position(values))
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
      const bool allowed = (s.mode == kJointMode && sup.state() == OperatingState::kEnabled) ||
                           r.controller->servo_allowed(ctx, values);
      if (!allowed || !s.drives_ready || sup.check_velocity(values) || !s.limits.within_velocity(values))
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
      sup.reset_estop(t, c.estop_presses);
      end_hold(r);
      break;
    case CommandKind::hold:
      r.controller->operator_lost(ctx);
      if (s.servo_active) {
        s.servo_active = false;
        r.interpolator->reset({s.q_des.data(), r.n}, t);
      }
      break;
    case CommandKind::mode:
      // Only while holding (nothing moving, nothing pending); the setpoint is not touched, so the
      // switch never makes it jump.
      if (holding(r, t) && c.index >= 0 && static_cast<std::size_t>(c.index) < r.modes.size()) {
        s.mode = static_cast<ModeId>(c.index);
        s.path_target = s.path_step;
        ctx.mode = s.mode;
        r.controller->reset(ctx);
      }
      break;
    case CommandKind::path_loaded:
      s.path_step = -1;
      s.path_target = -1;
      break;
    case CommandKind::path_step:
      if (s.mode != kPathFollowingMode || sup.state() != OperatingState::kEnabled || !s.drives_ready ||
          s.servo_active || sup.check_goal(values) || !s.limits.within_position(values))
        break;
      s.path_target = c.index;
      s.path_goal = c.values;
      r.interpolator->retarget(t, values, {s.limits.max_velocity.data(), r.n},
                               {r.max_acceleration.data(), r.n});
      break;
    case CommandKind::plugin:
      r.controller->apply(ctx, c.plugin);
      break;
    case CommandKind::warning:
      sup.record(t, safety::EventKind::kWarning, c.code, -1, c.text);
      break;
  }
  ++s.commands_applied;
}

bool RobotRuntime::Impl::holding(RobotUnit& r, double t) noexcept {
  const auto& s = r.rt;
  if (s.enable_pending || s.goal_pending || s.servo_active || !r.interpolator->done(t)) return false;
  return !r.controller->moving(*r.context);
}

void RobotRuntime::Impl::control_robot(RobotUnit& r, double t, double lost) noexcept {
  auto& s = r.rt;
  auto& sup = *r.supervisor;
  auto& ctx = *r.context;
  auto& joints = *r.joints;
  const std::size_t n = r.n;
  ctx.t = t;
  ctx.now_ns = now_ns;
  ctx.lost = lost;

  // 1. Read the joints.
  std::array<hardware::JointFeedback, kMaxJoints> fb;
  bool all_on = true;
  for (std::size_t i = 0; i < n; ++i) {
    joints.read(i, fb[i]);
    s.q[i] = fb[i].position;
    s.qd[i] = fb[i].velocity;
    s.effort[i] = fb[i].effort;
    all_on = all_on && fb[i].power == PowerState::on;
  }
  if (!s.initialised) {
    for (std::size_t i = 0; i < n; ++i) {
      s.q_des[i] = s.q[i];
      s.link_was_alive[i] = fb[i].link_alive;
      s.link_was_operational[i] = fb[i].link_operational;
      s.errors_seen[i] = fb[i].error_count;
    }
    r.interpolator->reset({s.q_des.data(), n}, t);
    s.initialised = true;
  }

  // 2. Link watchdogs: a device that goes silent, leaves operation or reports an error faults the
  // robot (edge-triggered, logged once).
  for (std::size_t i = 0; i < n; ++i) {
    const char* joint = r.config.joints[i].name().c_str();
    if (s.link_was_alive[i] && !fb[i].link_alive) {
      // The drive's own silence, measured by the heartbeat consumer against the bus's timeout; the
      // control loop's lateness this cycle is named beside it, so a busy computer is told from a
      // broken device.
      char detail[safety::kSafetyTextSize];
      std::snprintf(detail, sizeof detail,
                    "drive '%s' sent no heartbeat for over %d ms (its bus's drive_heartbeat_timeout_ms): "
                    "the device went silent; the control loop %s%.0f ms late this cycle)",
                    joint, r.heartbeat_timeout_ms[i], lost * 1e3 < 1.0 ? "kept time (" : "was also late (",
                    lost * 1e3);
      sup.fault(t, safety::FaultCode::kDriveHeartbeatLost, static_cast<int>(i), detail);
    }
    s.link_was_alive[i] = fb[i].link_alive;
    // A device that leaves operation (it reset, or someone stopped it) has lost its cyclic set-up.
    if (s.link_was_operational[i] && !fb[i].link_operational) {
      char detail[96];
      text(detail, "drive '%s' left NMT operational (reset or stopped)", joint);
      sup.fault(t, safety::FaultCode::kExternal, static_cast<int>(i), detail);
    }
    s.link_was_operational[i] = fb[i].link_operational;
    if (fb[i].error_count != s.errors_seen[i]) {
      s.errors_seen[i] = fb[i].error_count;
      if (fb[i].error_code != 0) {
        char detail[96];
        std::snprintf(detail, sizeof detail, "drive '%s' %s 0x%04X, error register 0x%02X", joint,
                      joints.error_source(), fb[i].error_code, fb[i].error_detail);
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
      r.controller->delay(ctx, lost);
    }
  }

  // 3. Operating limits (parameters may have tightened them), then commands from the network threads.
  if (const auto version = r.operating_limits.version(); version != s.limits_version) {
    s.limits = r.operating_limits.load();
    s.limits_version = version;
  }
  ctx.limits = &s.limits;
  ctx.q = {s.q.data(), n};
  ctx.qd = {s.qd.data(), n};
  ctx.effort = {s.effort.data(), n};
  ctx.q_des = {s.q_des.data(), n};
  ctx.qd_des = {s.qd_des.data(), n};
  ctx.state = sup.state();
  ctx.drives_ready = s.drives_ready;
  ctx.mode = s.mode;
  RobotCommand command;
  while (r.mailbox.pop(command)) apply_command(r, command, t);

  // 4. Enabling: wait for every joint to reach "on", then start from where they are.
  OperatingState state = sup.state();
  if (state == OperatingState::kEnabled || state == OperatingState::kPaused) {
    if (!s.drives_ready) {
      if (all_on) {
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
          if (fb[i].power == PowerState::on) continue;
          char detail[96];
          std::snprintf(detail, sizeof detail, "drive '%s' did not enable within %d ms (it reports %s)",
                        r.config.joints[i].name().c_str(), r.config.enable_timeout_ms,
                        joints.device_state_text(fb[i].device_state));
          sup.fault(t, safety::FaultCode::kExternal, static_cast<int>(i), detail);
          break;
        }
      }
    } else if (!all_on) {
      for (std::size_t i = 0; i < n; ++i) {
        if (fb[i].power == PowerState::on) continue;
        char detail[96];
        std::snprintf(detail, sizeof detail, "drive '%s' left operation enabled (it reports %s)",
                      r.config.joints[i].name().c_str(), joints.device_state_text(fb[i].device_state));
        sup.fault(t, safety::FaultCode::kDriveEmergency, static_cast<int>(i), detail);
        break;
      }
    }
  } else {
    s.drives_ready = false;
    s.enable_pending = false;
    s.goal_pending = false;
  }
  ctx.state = sup.state();
  ctx.drives_ready = s.drives_ready;
  ctx.mode = s.mode;

  // 5. The robot type's sensors (they may hold the robot), then the mid-level controller.
  r.controller->sense(ctx);
  state = sup.state();
  ctx.state = state;
  const JointArray setpoint_before = s.q_des;
  bool held_motion = false;  // PAUSED, and the robot type moves the setpoint out of the hold
  const std::span<double> q_des(s.q_des.data(), n), qd_des(s.qd_des.data(), n), qdd_des(s.qdd_des.data(), n);
  if (state == OperatingState::kEnabled && s.drives_ready && s.mode >= kFirstPluginMode) {
    r.controller->control(ctx);
    r.interpolator->reset(q_des, t);  // joint mode takes over from wherever the type's mode left it
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
    held_motion = r.controller->while_held(ctx);
  } else {
    // Not commanding: the setpoint follows the measurement so that enabling never jumps.
    for (std::size_t i = 0; i < n; ++i) {
      s.q_des[i] = s.q[i];
      s.qd_des[i] = 0.0;
    }
    s.servo_active = false;
    r.interpolator->reset(q_des, t);
    r.controller->reset(ctx);
  }
  if ((state == OperatingState::kEnabled || held_motion) && s.drives_ready) {
    // The type's safety filter sees every mode's step (robot_type.hpp limit_step).
    const double kept = r.controller->limit_step(ctx, {setpoint_before.data(), n});
    if (kept < 1.0) {
      if (state == OperatingState::kEnabled && s.mode < kFirstPluginMode && !s.servo_active)
        r.interpolator->delay((1.0 - kept) * period);
      else
        r.interpolator->reset(q_des, t);
    }
  }
  if ((state == OperatingState::kEnabled || held_motion) && s.drives_ready) {
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
      // The interpolator must not keep pulling against a clamped setpoint. Only a clamped position
      // stops the type's own trajectory; a clamped velocity leaves the setpoint where it was put.
      r.interpolator->reset(q_des, t);
      if (s.mode >= kFirstPluginMode && unclamped != s.q_des) r.controller->reset(ctx);
    }
  }

  // 6. Safety: servo timeout, tracking error.
  const bool tracking = state == OperatingState::kEnabled && s.drives_ready;
  sup.tick(t, {s.q.data(), n},
           tracking ? std::span<const double>(s.q_des.data(), n) : std::span<const double>(s.q.data(), n));
  state = sup.state();

  // 7. Write the joints. Velocity joints get the setpoint velocity plus a proportional correction of
  // the position error, so that they track the same setpoint position joints are given.
  const bool estop = sup.estop_latched();
  for (std::size_t i = 0; i < n; ++i) {
    hardware::JointCommand jc;
    if (estop || state == OperatingState::kFault) {
      jc.request = hardware::PowerRequest::quick_stop;
    } else if (state == OperatingState::kEnabled || state == OperatingState::kPaused) {
      jc.request = hardware::PowerRequest::on;
    } else if (fb[i].power == PowerState::fault) {
      jc.request = hardware::PowerRequest::fault_reset;  // acknowledged by disable: clear the drive fault
    } else {
      jc.request = hardware::PowerRequest::off;
    }
    jc.position = s.q_des[i];
    jc.velocity = s.qd_des[i];
    if (joints.command_mode(i) == hardware::CommandMode::velocity) {
      const double v = s.qd_des[i] + r.velocity_gain * (s.q_des[i] - s.q[i]);
      const double limit = s.limits.max_velocity[i];
      jc.velocity =
          s.drives_ready && jc.request == hardware::PowerRequest::on ? std::clamp(v, -limit, limit) : 0.0;
    }
    joints.write(i, jc);
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
  ctx.state = state;
  ctx.drives_ready = s.drives_ready;
  ctx.mode = s.mode;
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
    snap.power[i] = fb[i].power;
    snap.device_state[i] = fb[i].device_state;
    snap.link_alive[i] = fb[i].link_alive;
  }
  snap.state = state;
  snap.estop = estop;
  snap.drives_ready = s.drives_ready;
  snap.busy = s.drives_ready ? !holding(r, t) : (s.enable_pending || s.goal_pending);
  snap.fault = sup.fault_cause();
  snap.lost_control = sup.lost_control();
  snap.hold_code = s.hold_code;
  snap.hold_can_resume = state != OperatingState::kPaused || r.controller->hold_cleared(ctx, nullptr, 0);
  snap.estop_tick = s.estop_tick;
  snap.commands_applied = s.commands_applied;
  snap.mailbox_full = r.mailbox_full.load(std::memory_order_relaxed);
  snap.mode = s.mode;
  snap.path_step = s.path_step;
  snap.path_target = s.path_target;
  r.snapshot.store(snap);
  r.controller->publish(ctx);
}

}  // namespace tendril::server
