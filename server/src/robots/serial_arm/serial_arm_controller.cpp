// The serial arm's part of the control cycle (control thread): the force sensor's watchdog and F_max
// (hard limits), the Cartesian mode's move_cp / servo_cp / servo_cv on the joint setpoint, and
// the way out of a force hold (retraction at ≤ 10 mm/s: retract along the contact force at ≤ 10 mm/s). No
// allocation, no locks, no exceptions: the kinematic workspaces are preallocated.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "serial_arm/serial_arm_robot.hpp"

namespace tendril::server {

namespace {
using safety::OperatingState;
}  // namespace

SerialArmController::SerialArmController(SerialArm& robot)
    : robot_(robot), data_(robot.model().make_data()), probe_(robot.model().make_data()) {}

Eigen::Vector3d SerialArmController::force_base(const ControlContext& ctx) noexcept {
  // The sensor reports in the tool frame (the arm's measured pose turns it into the base frame).
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q[i];
  if (!robot_.model().forward_kinematics(q_, probe_)) return Eigen::Vector3d::Zero();
  return probe_.tool.linear() * Eigen::Vector3d(force_.force_n[0], force_.force_n[1], force_.force_n[2]);
}

Eigen::Isometry3d SerialArmController::limb_in_base(const LimbPoseSample& limb) const noexcept {
  Eigen::Isometry3d tracked = to_isometry(limb.pose);
  if (!base_calibrated_ || !robot_.tracker_settings_) return tracked;
  // The tracker reports the limb in {G}; the calibrated H_B^G brings it into the base frame, so the
  // calibration's error shows in where the sweep and the reconstruction put the limb.
  return global_T_base_.inverse() * robot_.tracker_settings_->global_T_base * tracked;
}

void SerialArmController::sense(ControlContext& ctx) noexcept {
  if (robot_.tracker_) {
    const auto b = robot_.base_calibration_.load();
    base_calibrated_ = b.valid;
    if (b.valid) global_T_base_ = to_isometry(b.global_T_base);
    // The SIMULATED optical tracker samples the probe where the measured joints put it.
    for (std::size_t i = 0; i < teleop::kArmJoints; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q[i];
    robot_.tracker_->set_silent(robot_.marker_hidden_.load(std::memory_order_relaxed));
    if (robot_.model().forward_kinematics(q_, probe_)) robot_.tracker_->step(ctx.t, q_, probe_.tool);
  }
  const hardware::ForceReading reading = robot_.sensor_->read();
  if (reading.valid) force_ = reading;
  force_age_s_ = force_.valid ? static_cast<double>(ctx.now_ns - force_.stamp_ns) * 1e-9 : 0.0;
  force_fresh_ = force_.valid && force_age_s_ <= robot_.settings_.force_stale_s;
  if (ctx.state != OperatingState::kEnabled || !ctx.drives_ready) return;
  const auto& s = robot_.settings_;
  char detail[safety::kSafetyTextSize];
  if (!force_fresh_) {
    // The sensor's silence, measured against the control loop's own clock; the loop's lateness this
    // cycle beside it, so that a busy computer is told from a sensor that stopped answering.
    std::snprintf(detail, sizeof detail,
                  "%s sent nothing for %.0f ms (bound %.0f ms): the device went silent; the control loop "
                  "%s%.0f ms late this cycle)",
                  robot_.sensor_name_.c_str(), force_age_s_ * 1e3, s.force_stale_s * 1e3,
                  ctx.lost * 1e3 < 1.0 ? "kept time (" : "was also late (", ctx.lost * 1e3);
    ctx.hold(safety::FaultCode::kSensorStale, -1, detail);
    return;
  }
  const double f = Eigen::Vector3d(force_.force_n[0], force_.force_n[1], force_.force_n[2]).norm();
  if (f > s.max_contact_force_n) {
    std::snprintf(detail, sizeof detail, "contact force %.2f N over F_max %.2f N; retracting", f,
                  s.max_contact_force_n);
    if (ctx.hold(safety::FaultCode::kExternal, -1, detail)) {
      force_hold_ = true;
      retracting_ = true;
      retracted_mm_ = 0.0;
    }
  }
}

void SerialArmController::stop(ControlContext& ctx) noexcept {
  motion_ = ArmMotion::none;
  twist_limited_ = false;
  for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
}

void SerialArmController::integrate(ControlContext& ctx,
                                    const teleop::CartesianCommandResult& result) noexcept {
  twist_limited_ = result.twist_limited || result.joints.velocity_limited || result.joints.position_limited;
  if (!result.joints.valid) {
    stop(ctx);
    return;
  }
  teleop::ArmVector next = q_ + result.joints.joint_velocity * ctx.period;
  // The workspace box: a setpoint whose tool would leave it does not move.
  const auto& s = robot_.settings_;
  workspace_limited_ = false;
  if (robot_.model().forward_kinematics(next, probe_)) {
    const Eigen::Vector3d p = probe_.tool.translation();
    const Eigen::Vector3d now = data_.tool.translation();
    for (Eigen::Index i = 0; i < 3; ++i) {
      const bool outward =
          (p[i] < s.workspace_min[i] && p[i] < now[i]) || (p[i] > s.workspace_max[i] && p[i] > now[i]);
      workspace_limited_ = workspace_limited_ || outward;
    }
  }
  if (workspace_limited_) {
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return;
  }
  for (std::size_t i = 0; i < ctx.n; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    ctx.qd_des[i] = result.joints.joint_velocity[k];
    ctx.q_des[i] = next[k];
  }
}

void SerialArmController::sweep(ControlContext& ctx) noexcept {
  UltrasoundSweep& sweep = *robot_.sweep_;
  for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
  UltrasoundSweep::Inputs in;
  in.q = q_;
  in.force = Eigen::Vector3d(force_.force_n[0], force_.force_n[1], force_.force_n[2]);
  in.force_valid = force_fresh_;
  const LimbPoseSample limb = robot_.limb_->tracked();
  in.world_T_limb = limb_in_base(limb);
  in.limb_t = limb.t;
  in.t = ctx.t;
  in.dt = ctx.period;
  teleop::CartesianCommandResult result;
  if (!sweep.step(robot_.model(), data_, in, result)) {
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return;
  }
  // integrate() checks the workspace box against data_'s tool: the sweep's law left it at q_.
  integrate(ctx, result);
}

void SerialArmController::calibrate(ControlContext& ctx) noexcept {
  CalibrationMotion& motion = *robot_.calibration_motion_;
  for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
  // The pair's kinematic pose is that of the measured joints (where the arm is, as it reports it).
  teleop::ArmVector measured;
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) measured[static_cast<Eigen::Index>(i)] = ctx.q[i];
  Eigen::Isometry3d measured_tool = Eigen::Isometry3d::Identity();
  if (robot_.model().forward_kinematics(measured, probe_)) measured_tool = probe_.tool;
  teleop::CartesianCommandResult result;
  if (!motion.step(robot_.model(), data_, q_, measured_tool, robot_.tracker_->latest(), ctx.t, ctx.period,
                   result)) {
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return;
  }
  integrate(ctx, result);
}

void SerialArmController::control(ControlContext& ctx) noexcept {
  if (ctx.mode == kSweepMode && robot_.sweep_) {
    sweep(ctx);
    return;
  }
  if (ctx.mode != kCartesianMode) return;
  if (robot_.calibration_motion_ && robot_.calibration_motion_->running()) {
    calibrate(ctx);
    return;
  }
  for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
  const auto& s = robot_.settings_;
  if (motion_ == ArmMotion::none) {
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return;
  }
  // Streams end when they are not refreshed within the command timeout (the supervisor holds the
  // robot then, as for servo_jv).
  if ((motion_ == ArmMotion::servo_cv || motion_ == ArmMotion::servo_cp) &&
      ctx.t - last_stream_ > ctx.limits->servo_timeout_s) {
    stop(ctx);
    return;
  }
  robot_.model().update(q_, data_);
  teleop::CartesianCommandResult result;
  switch (motion_) {
    case ArmMotion::servo_cv:
      result = teleop::servo_cv(robot_.model(), data_, q_, twist_, s.cartesian, ctx.period);
      break;
    case ArmMotion::servo_cp:
      result = teleop::servo_cp(robot_.model(), data_, q_, goal_, s.gains, s.cartesian, ctx.period);
      break;
    case ArmMotion::move_cp: {
      const double t = ctx.t - trajectory_delay_;
      result =
          teleop::track(robot_.model(), data_, q_, trajectory_.sample(t), s.gains, s.cartesian, ctx.period);
      if (trajectory_.done(t)) {
        // Done once the setpoint's tool is on the goal (the pose law closes what the feed-forward left).
        const double e = (data_.tool.translation() - trajectory_.goal_position()).norm();
        const double a = Eigen::AngleAxisd(data_.tool.linear().transpose() *
                                           trajectory_.goal_orientation().toRotationMatrix())
                             .angle();
        // Within a hundredth of the goal tolerance, or 5 s after the trajectory (the pose law's last
        // approach is exponential: it is well inside the tolerance by then).
        if ((e <= 0.01 * s.goal_tolerance_mm && a <= 0.01 * s.goal_tolerance_rad) ||
            t > trajectory_.start_time() + trajectory_.duration() + 5.0) {
          stop(ctx);
          return;
        }
      }
      break;
    }
    case ArmMotion::none:
      break;
  }
  integrate(ctx, result);
}

bool SerialArmController::while_held(ControlContext& ctx) noexcept {
  if (robot_.sweep_) robot_.sweep_->interrupt("the robot is held (see its hold); resume it first");
  if (robot_.calibration_motion_) robot_.calibration_motion_->fail("the robot was held (see its hold)");
  // Retraction at ≤ 10 mm/s: out of a force hold, back away along the contact force (the push the tissue
  // gives the tool) at the retract speed until the force is under the resume bound, for at most
  // retract_max_mm.
  if (!retracting_) return false;
  const auto& s = robot_.settings_;
  const Eigen::Vector3d f = force_base(ctx);
  // The target is 80 % of the resume bound: the reading's noise (0.02 N) must not leave the force on it.
  if (!force_fresh_ || f.norm() <= 0.8 * s.resume_contact_force_n || retracted_mm_ >= s.retract_max_mm) {
    retracting_ = false;
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return false;
  }
  for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
  robot_.model().update(q_, data_);
  teleop::Twist twist = teleop::Twist::Zero();
  twist.head<3>() = s.retract_speed_mm_s * f.normalized();
  const auto result = teleop::servo_cv(robot_.model(), data_, q_, twist, s.cartesian, ctx.period);
  if (!result.joints.valid) {
    retracting_ = false;
    return false;
  }
  for (std::size_t i = 0; i < ctx.n; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    ctx.qd_des[i] = result.joints.joint_velocity[k];
    ctx.q_des[i] += result.joints.joint_velocity[k] * ctx.period;
  }
  retracted_mm_ += result.twist.head<3>().norm() * ctx.period;
  return true;
}

void SerialArmController::apply(ControlContext& ctx, const PluginCommand& command) noexcept {
  if (static_cast<ArmCommand>(command.id) == ArmCommand::sweep_load) {
    // Data only: taken in any mode and state (the sweep ignores it while one runs).
    if (robot_.sweep_) robot_.sweep_->load(robot_.plan_slot_.load());
    return;
  }
  if (static_cast<ArmCommand>(command.id) == ArmCommand::calibration_abort) {
    if (robot_.calibration_motion_) robot_.calibration_motion_->fail("aborted by the operator");
    return;
  }
  if (static_cast<ArmCommand>(command.id) == ArmCommand::calibration_start) {
    if (!robot_.calibration_motion_ || command.count != 1) return;
    // Re-checked here: the network thread looked a moment ago. A start that cannot be taken is dropped;
    // the worker sees no run begin and reports it.
    if (ctx.mode != kCartesianMode || ctx.state != OperatingState::kEnabled || !ctx.drives_ready ||
        motion_ != ArmMotion::none || (robot_.sweep_ && robot_.sweep_->running()))
      return;
    const CalibrationPosesData poses = robot_.calibration_poses_.load();
    if (static_cast<double>(poses.run) != command.values[0]) return;
    for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
    if (!robot_.model().forward_kinematics(q_, data_)) return;
    robot_.calibration_motion_->start(poses, data_.tool, ctx.t);
    pairs_published_ = false;
    return;
  }
  if (static_cast<ArmCommand>(command.id) == ArmCommand::sweep_action) {
    if (!robot_.sweep_ || ctx.mode != kSweepMode || command.count != 1) return;
    const auto action = static_cast<SweepAction>(static_cast<int>(command.values[0]));
    // Abort and pause are always taken; the moving actions only while ENABLED with the drives ready.
    if (action != SweepAction::abort && action != SweepAction::pause &&
        (ctx.state != OperatingState::kEnabled || !ctx.drives_ready))
      return;
    robot_.sweep_->command(action, ctx.t);
    return;
  }
  // Re-checked here: the mode or state may have changed since the network thread looked.
  if (ctx.mode != kCartesianMode || ctx.state != OperatingState::kEnabled || !ctx.drives_ready) return;
  // An operator's Cartesian command takes the arm: a running calibration ends.
  if (robot_.calibration_motion_) robot_.calibration_motion_->fail("a Cartesian command took the arm");
  const auto& v = command.values;
  switch (static_cast<ArmCommand>(command.id)) {
    case ArmCommand::servo_cv:
      if (command.count != 6) return;
      for (Eigen::Index i = 0; i < 6; ++i) twist_[i] = v[static_cast<std::size_t>(i)];
      motion_ = ArmMotion::servo_cv;
      last_stream_ = ctx.t;
      ctx.supervisor->servo_command_received(ctx.t);
      return;
    case ArmCommand::sweep_load:
    case ArmCommand::sweep_action:
    case ArmCommand::calibration_start:
    case ArmCommand::calibration_abort:
      return;
    case ArmCommand::servo_cp:
    case ArmCommand::move_cp: {
      if (command.count != 8) return;
      goal_.setIdentity();
      goal_.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
      goal_.linear() = Eigen::Quaterniond(v[6], v[3], v[4], v[5]).normalized().toRotationMatrix();
      if (static_cast<ArmCommand>(command.id) == ArmCommand::servo_cp) {
        motion_ = ArmMotion::servo_cp;
        last_stream_ = ctx.t;
        ctx.supervisor->servo_command_received(ctx.t);
        return;
      }
      for (std::size_t i = 0; i < ctx.n; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q_des[i];
      if (!robot_.model().forward_kinematics(q_, data_)) return;
      // The network thread's dry run chose the duration; keep it so the answer's duration_s holds.
      if (!trajectory_.plan(data_.tool, goal_, robot_.settings_.cartesian, ctx.t, v[7])) return;
      trajectory_delay_ = 0.0;
      motion_ = ArmMotion::move_cp;
      return;
    }
  }
}

void SerialArmController::delay(ControlContext& ctx, double lost) noexcept {
  (void)ctx;
  if (motion_ == ArmMotion::move_cp) trajectory_delay_ += lost;
  if (robot_.calibration_motion_) robot_.calibration_motion_->delay(lost);
}

void SerialArmController::reset(ControlContext& ctx) noexcept {
  // The setpoint was set from outside (enable, pause, a mode switch, a clamp): every motion ends there.
  motion_ = ArmMotion::none;
  twist_limited_ = false;
  workspace_limited_ = false;
  // A running sweep stops for a mode switch or when the robot is not enabled (disable, e-stop; a pause
  // or a hold comes through state_command() and while_held()). A clamp at a joint limit also resets
  // the setpoint: the sweep's law runs on the setpoint, so it simply continues from the clamped one.
  if (robot_.sweep_) {
    if (ctx.state != OperatingState::kEnabled)
      robot_.sweep_->interrupt("the robot is not enabled");
    else if (ctx.mode != kSweepMode)
      robot_.sweep_->interrupt("the mode changed");
  }
  if (robot_.calibration_motion_) {
    if (ctx.state != OperatingState::kEnabled)
      robot_.calibration_motion_->fail("the robot is not enabled");
    else if (ctx.mode != kCartesianMode)
      robot_.calibration_motion_->fail("the mode changed");
  }
}

void SerialArmController::state_command(ControlContext& ctx, safety::StateCommand command) noexcept {
  (void)ctx;
  if (robot_.sweep_ && command == safety::StateCommand::kPause)
    robot_.sweep_->interrupt("the robot was paused (state_command pause); resume it first");
  if (robot_.calibration_motion_ && command == safety::StateCommand::kPause)
    robot_.calibration_motion_->fail("the robot was paused");
}

void SerialArmController::operator_lost(ControlContext& ctx) noexcept {
  if (motion_ == ArmMotion::servo_cv || motion_ == ArmMotion::servo_cp) stop(ctx);
  // A sweep is not the operator's stream, but nobody watches it any more: it pauses, in contact.
  if (robot_.sweep_) robot_.sweep_->command(SweepAction::pause, ctx.t);
  if (robot_.calibration_motion_) robot_.calibration_motion_->fail("the operator's connection was lost");
}

bool SerialArmController::moving(const ControlContext& ctx) const noexcept {
  (void)ctx;
  return motion_ != ArmMotion::none || retracting_ || (robot_.sweep_ && robot_.sweep_->running()) ||
         (robot_.calibration_motion_ && robot_.calibration_motion_->running());
}

bool SerialArmController::hold_cleared(const ControlContext& ctx, char* why,
                                       std::size_t why_size) const noexcept {
  (void)ctx;
  const auto& s = robot_.settings_;
  const double f = Eigen::Vector3d(force_.force_n[0], force_.force_n[1], force_.force_n[2]).norm();
  const char* reason = nullptr;
  if (!force_fresh_) {
    reason = "resume refused: the force sensor is silent";
  } else if (force_hold_ && (retracting_ || f > s.resume_contact_force_n)) {
    reason = "resume refused: the contact force is still over the resume bound";
  }
  if (reason && why && why_size > 0) std::snprintf(why, why_size, "%s", reason);
  return reason == nullptr;
}

void SerialArmController::hold_ended(ControlContext& ctx) noexcept {
  (void)ctx;
  force_hold_ = false;
  retracting_ = false;
  retracted_mm_ = 0.0;
}

void SerialArmController::publish(const ControlContext& ctx) noexcept {
  ArmSnapshot s;
  for (std::size_t i = 0; i < ctx.n && i < s.setpoint.size(); ++i) s.setpoint[i] = ctx.q_des[i];
  s.force_n = force_.force_n;
  s.force_valid = force_.valid;
  s.force_fresh = force_fresh_;
  s.force_age_s = force_age_s_;
  s.motion = motion_;
  const Eigen::Quaterniond o(goal_.linear());
  s.goal = {
      goal_.translation().x(), goal_.translation().y(), goal_.translation().z(), o.x(), o.y(), o.z(), o.w()};
  s.twist_limited = twist_limited_;
  s.workspace_limited = workspace_limited_;
  s.force_hold = force_hold_;
  s.retracting = retracting_;
  robot_.published_.store(s);

  UltrasoundProbeSample u;
  u.tick = ++ticks_;
  u.t = ctx.t;
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) q_[static_cast<Eigen::Index>(i)] = ctx.q[i];
  if (robot_.model().forward_kinematics(q_, probe_)) u.world_T_probe = to_array(probe_.tool);
  u.world_T_limb = to_array(Eigen::Isometry3d::Identity());
  u.world_T_limb_true = u.world_T_limb;
  if (robot_.limb_) {
    u.world_T_limb = to_array(limb_in_base(robot_.limb_->tracked()));
    u.world_T_limb_true = robot_.limb_->truth().pose;
  }
  if (robot_.sweep_) {
    const SweepSnapshot& sw = robot_.sweep_->snapshot();
    u.acquiring = robot_.sweep_->acquiring();
    u.via_point = sw.phase == SweepPhase::idle || sw.phase == SweepPhase::planned ? -1 : sw.via_point;
    robot_.sweep_published_.store(sw);
  }
  // F_n: the tissue pushes the probe back along its axis, which reads as negative z in the tool frame.
  u.normal_force_n = force_.valid ? -force_.force_n[2] : 0.0;
  u.in_contact = u.normal_force_n > 0.1;
  robot_.probe_published_.store(u);
  if (robot_.calibration_motion_) {
    const CalibrationMotion& c = *robot_.calibration_motion_;
    // The pairs go out once per run, before the snapshot says "collected": the worker reads them then.
    if (c.snapshot().phase == CalibrationPhase::collected && !pairs_published_) {
      robot_.calibration_pairs_.store(c.pairs());
      pairs_published_ = true;
    }
    robot_.calibration_published_.store(c.snapshot());
  }
}

}  // namespace tendril::server
