// The mbcr_vd's part of the control cycle (control thread): the task mode's servo_cv and move_cp, the
// approach to the reference circle's start and the circle itself, each one step of the library's resolved
// rates plus gradient projection per tick (or the fixed-diameter baseline), and the published actuation.
// No allocation, no locks, no exceptions: the library's workspaces are preallocated.
#include <algorithm>
#include <cmath>

#include "mbcr_vd/mbcr_vd_robot.hpp"

namespace tendril::server {

namespace {

using safety::OperatingState;

// Quintic time scaling s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ and its derivative (zero speed at both ends).
double quintic(double tau) noexcept {
  tau = std::clamp(tau, 0.0, 1.0);
  return tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
}
double quintic_rate(double tau) noexcept {
  if (tau <= 0.0 || tau >= 1.0) return 0.0;
  return 30.0 * tau * tau * (1.0 - tau) * (1.0 - tau);
}

double wrap(double angle) noexcept { return std::remainder(angle, 2.0 * 3.14159265358979323846); }

// Only every 10th tick: the statics of the stack (2.30) for the published backbone forces.
constexpr std::uint64_t kActuationEvery = 10;

}  // namespace

MbcrController::MbcrController(MbcrRobot& robot)
    : robot_(robot),
      data_(robot.model().make_data()),
      probe_(robot.model().make_data()),
      variable_(robot.settings().variable_diameter),
      motion_variable_(robot.settings().variable_diameter) {
  for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k)
    state_.configuration[2 * k] = teleop::kStraightTangentAngle;
  state_.diameter_joint = robot.config().joints[6].initial_position;
}

void MbcrController::sync_from_setpoint(const ControlContext& ctx) noexcept {
  double q[kMbcrJoints];
  for (std::size_t i = 0; i < kMbcrJoints; ++i) q[i] = ctx.q_des[i];
  state_.configuration = configuration_from_joints(robot_.model(), q, state_.configuration);
  state_.diameter_joint = q[6];
}

void MbcrController::stop(ControlContext& ctx) noexcept {
  motion_ = MbcrMotion::none;
  for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
}

void MbcrController::write_setpoint(ControlContext& ctx, const teleop::StackJoints& before) noexcept {
  const auto q = robot_.model().joints(state_.configuration, state_.diameter_joint);
  for (std::size_t i = 0; i < kMbcrJoints; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    ctx.q_des[i] = q[k];
    ctx.qd_des[i] = (q[k] - before[k]) / ctx.period;
  }
}

bool MbcrController::task_step(ControlContext& ctx, const Eigen::Isometry3d& target,
                               const teleop::StackTwist& twist, bool guard) noexcept {
  const auto& model = robot_.model();
  const auto before = model.joints(state_.configuration, state_.diameter_joint);
  teleop::VariableDiameterState next = state_;
  report_ = model.step(next, target, twist, robot_.settings().payload, ctx.period, motion_variable_, data_);
  if (report_.status == teleop::VariableDiameterStatus::kNonFinite) return false;
  backbone_limited_ = false;
  interference_limited_ = false;
  if (guard) {
    // An operator's motion stops at a backbone limit and before the segments curl into a bend where no
    // diameter keeps the disks apart (the setpoint stays, as the serial arm's does at its workspace box).
    const auto q = model.joints(next.configuration, next.diameter_joint);
    const auto& p = model.parameters();
    for (Eigen::Index i = 0; i < 6; ++i)
      backbone_limited_ = backbone_limited_ || (q[i] < p.backbone_lower && q[i] < before[i]) ||
                          (q[i] > p.backbone_upper && q[i] > before[i]);
    if (model.diameter_limits(next.configuration).interference_unavoidable) {
      double bend_before = 0.0, bend_after = 0.0;
      for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k) {
        bend_before =
            std::max(bend_before, std::abs(state_.configuration[2 * k] - teleop::kStraightTangentAngle));
        bend_after =
            std::max(bend_after, std::abs(next.configuration[2 * k] - teleop::kStraightTangentAngle));
      }
      interference_limited_ = bend_after > bend_before;
    }
    if (backbone_limited_ || interference_limited_) {
      for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
      return true;
    }
  }
  state_ = next;
  write_setpoint(ctx, before);
  return true;
}

void MbcrController::control(ControlContext& ctx) noexcept {
  if (ctx.mode != kTaskMode) return;
  if (motion_ == MbcrMotion::none) {
    for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
    return;
  }
  const auto& s = robot_.settings();
  const auto& model = robot_.model();
  switch (motion_) {
    case MbcrMotion::servo_cv: {
      // A stream not refreshed within the command timeout ends (the supervisor holds the robot then).
      if (ctx.t - last_stream_ > ctx.limits->servo_timeout_s) {
        stop(ctx);
        return;
      }
      teleop::StackTwist next_twist = twist_;
      Eigen::Isometry3d next = target_;
      next.translation() += twist_.head<3>() * ctx.period;
      const double w = twist_.tail<3>().norm();
      if (w > 0.0)
        next.linear() =
            Eigen::AngleAxisd(w * ctx.period, twist_.tail<3>() / w).toRotationMatrix() * target_.linear();
      if (!task_step(ctx, next, next_twist, true)) {
        stop(ctx);
        return;
      }
      // A stopped step leaves the reference where the robot is, so that it does not run away from it.
      if (!backbone_limited_ && !interference_limited_) target_ = next;
      return;
    }
    case MbcrMotion::move_cp: {
      const double tau = (ctx.t + ctx.period - move_t0_) / move_duration_;
      const double sv = quintic(tau), rate = quintic_rate(tau) / move_duration_;
      Eigen::Isometry3d target = Eigen::Isometry3d::Identity();
      const Eigen::Vector3d line = move_goal_.translation() - move_start_.translation();
      target.translation() = move_start_.translation() + sv * line;
      target.linear() =
          Eigen::AngleAxisd(sv * move_rotation_.angle(), move_rotation_.axis()).toRotationMatrix() *
          move_start_.linear();
      teleop::StackTwist twist;
      twist.head<3>() = rate * line;
      twist.tail<3>() = rate * move_rotation_.angle() * move_rotation_.axis();
      if (!task_step(ctx, target, twist, true)) {
        stop(ctx);
        return;
      }
      if (tau >= 1.0) {
        // Done once on the goal (the closed loop removes what the feed-forward left), or 5 s after.
        const auto e = teleop::pose_error(move_goal_, model.tip_pose(state_.configuration, probe_));
        if ((e.head<3>().norm() <= 0.01 * s.goal_tolerance_mm &&
             e.tail<3>().norm() <= 0.01 * s.goal_tolerance_rad) ||
            ctx.t > move_t0_ + move_duration_ + 5.0 || backbone_limited_ || interference_limited_)
          stop(ctx);
      }
      return;
    }
    case MbcrMotion::approach: {
      // Joint-space approach to the circle's start: ψ and a along a quintic.
      const auto before = model.joints(state_.configuration, state_.diameter_joint);
      const double tau = (ctx.t + ctx.period - approach_t0_) / approach_duration_;
      const double sv = quintic(tau);
      const auto& to = robot_.circle_start();
      for (Eigen::Index i = 0; i < 6; ++i) {
        const double delta = (i % 2 == 1) ? wrap(to[i] - approach_from_[i]) : to[i] - approach_from_[i];
        state_.configuration[i] = approach_from_[i] + sv * delta;
      }
      state_.diameter_joint = approach_a_from_ + sv * (approach_a_to_ - approach_a_from_);
      if (tau >= 1.0) {
        // Exactly the start the library's simulation uses, so the run is the library's run.
        state_.configuration = to;
        state_.diameter_joint = approach_a_to_;
        write_setpoint(ctx, before);
        for (std::size_t i = 0; i < ctx.n; ++i) ctx.qd_des[i] = 0.0;
        motion_ = MbcrMotion::circle;
        circle_index_ = 0;
        circle_samples_ = 0;
        circle_sum_sq_ = 0.0;
        circle_unavoidable_ = 0;
        return;
      }
      write_setpoint(ctx, before);
      return;
    }
    case MbcrMotion::circle: {
      // Sample i steps towards the circle at (i + 1)·dt, as teleop::simulate_circle does; the time is
      // the sample count, so a stalled loop slows the circle rather than jumping along it.
      const auto& c = s.circle;
      const double t_next = (circle_index_ + 1) * ctx.period;
      if (!task_step(ctx, teleop::circle_pose(c, t_next), teleop::circle_twist(c, t_next), false)) {
        stop(ctx);
        return;
      }
      circle_sample_force_ = report_.force_norm;
      circle_sum_sq_ += report_.force_norm * report_.force_norm;
      ++circle_samples_;
      if (report_.status == teleop::VariableDiameterStatus::kInterferenceUnavoidable) ++circle_unavoidable_;
      ++circle_index_;
      if (circle_index_ > static_cast<std::uint32_t>(std::llround(c.period / ctx.period))) {
        // Only a whole circle is comparable with the dissertation's (and with the other diameter's) RMS.
        (motion_variable_ ? last_rms_variable_ : last_rms_fixed_) =
            std::sqrt(circle_sum_sq_ / circle_samples_);
        stop(ctx);
      }
      return;
    }
    case MbcrMotion::none:
      return;
  }
}

void MbcrController::apply(ControlContext& ctx, const PluginCommand& command) noexcept {
  const auto id = static_cast<MbcrCommand>(command.id);
  if (id == MbcrCommand::diameter) {
    variable_ = command.flag != 0;
    if (motion_ == MbcrMotion::servo_cv || motion_ == MbcrMotion::move_cp) motion_variable_ = variable_;
    return;
  }
  if (id == MbcrCommand::circle_stop) {
    if (motion_ == MbcrMotion::approach || motion_ == MbcrMotion::circle) stop(ctx);
    return;
  }
  // Re-checked here: the mode or state may have changed since the network thread looked.
  if (ctx.mode != kTaskMode || ctx.state != OperatingState::kEnabled || !ctx.drives_ready) return;
  const auto& v = command.values;
  const auto& model = robot_.model();
  switch (id) {
    case MbcrCommand::servo_cv:
      if (command.count != 6) return;
      for (Eigen::Index i = 0; i < 6; ++i) twist_[i] = v[static_cast<std::size_t>(i)];
      if (motion_ != MbcrMotion::servo_cv) target_ = model.tip_pose(state_.configuration, probe_);
      motion_ = MbcrMotion::servo_cv;
      motion_variable_ = variable_;
      last_stream_ = ctx.t;
      ctx.supervisor->servo_command_received(ctx.t);
      return;
    case MbcrCommand::move_cp:
      if (command.count != 8) return;
      move_start_ = model.tip_pose(state_.configuration, probe_);
      move_goal_.setIdentity();
      move_goal_.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
      move_goal_.linear() = Eigen::Quaterniond(v[6], v[3], v[4], v[5]).normalized().toRotationMatrix();
      move_rotation_ = Eigen::AngleAxisd(move_goal_.linear() * move_start_.linear().transpose());
      move_t0_ = ctx.t;
      move_duration_ = std::max(v[7], ctx.period);
      motion_ = MbcrMotion::move_cp;
      motion_variable_ = variable_;
      return;
    case MbcrCommand::circle_start: {
      motion_variable_ = command.flag != 0;
      const double a_min = model.linkage().inner_radius_min();
      approach_a_to_ = motion_variable_ ? a_min + robot_.settings().circle.start_offset : a_min;
      approach_from_ = state_.configuration;
      approach_a_from_ = state_.diameter_joint;
      // A straight segment's plane is arbitrary: take the start's, so that only its bend moves.
      const auto& to = robot_.circle_start();
      for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k)
        if (std::abs(approach_from_[2 * k] - teleop::kStraightTangentAngle) < 1e-9)
          approach_from_[2 * k + 1] = to[2 * k + 1];
      MbcrSnapshot from;
      for (int i = 0; i < 6; ++i) from.configuration[static_cast<std::size_t>(i)] = approach_from_[i];
      from.diameter_joint = approach_a_from_;
      approach_duration_ = robot_.approach_duration(from, approach_a_to_);
      approach_t0_ = ctx.t;
      motion_ = MbcrMotion::approach;
      return;
    }
    case MbcrCommand::circle_stop:
    case MbcrCommand::diameter:
      return;
  }
}

void MbcrController::reset(ControlContext& ctx) noexcept {
  // The setpoint was set from outside (enable, pause, a mode switch, a clamp): every motion ends there
  // and the reference restarts from it.
  motion_ = MbcrMotion::none;
  backbone_limited_ = false;
  interference_limited_ = false;
  sync_from_setpoint(ctx);
}

void MbcrController::operator_lost(ControlContext& ctx) noexcept {
  if (motion_ == MbcrMotion::servo_cv) stop(ctx);
}

bool MbcrController::moving(const ControlContext& ctx) const noexcept {
  (void)ctx;
  return motion_ != MbcrMotion::none;
}

void MbcrController::publish(const ControlContext& ctx) noexcept {
  const auto& model = robot_.model();
  // Outside the task mode the reference follows the setpoint (joint mode moves it).
  if (ctx.mode != kTaskMode || motion_ == MbcrMotion::none) sync_from_setpoint(ctx);
  if (ticks_++ % kActuationEvery == 0) {
    if (model.actuation(state_.configuration, state_.diameter_joint, robot_.settings().payload, probe_,
                        actuation_))
      force_norm_ = actuation_.norm();
  }
  MbcrSnapshot s;
  s.tick = ticks_;
  for (std::size_t i = 0; i < 6; ++i) s.configuration[i] = state_.configuration[static_cast<Eigen::Index>(i)];
  const double a = state_.diameter_joint;
  s.diameter_joint = a;
  const auto& linkage = model.linkage();
  const double b = linkage.outer_radius(linkage.configuration_radius(a));
  s.outer_diameter = 2.0 * b;
  s.motion = motion_;
  s.variable_diameter = motion_ == MbcrMotion::none ? variable_ : motion_variable_;
  for (std::size_t i = 0; i < kMbcrBackbones; ++i)
    s.backbone_forces[i] = actuation_[static_cast<Eigen::Index>(i)];
  s.diameter_force = actuation_[12];
  s.force_norm = force_norm_;
  s.force_gradient = report_.force_gradient;
  s.tracking_error = report_.tracking_error;
  s.limits = model.diameter_limits(state_.configuration);
  double margin = INFINITY;
  for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k)
    margin = std::min(
        margin, teleop::interference_outer_radius_limit(
                    model.parameters().disks, state_.configuration[2 * k] - teleop::kStraightTangentAngle) -
                    b);
  s.interference_margin = margin;
  s.interference_unavoidable = s.limits.interference_unavoidable;
  s.diameter_at_limit = a <= s.limits.lower + 0.01 || a >= s.limits.upper - 0.01;
  s.backbone_limited = backbone_limited_;
  s.interference_limited = interference_limited_;
  s.circle_index = circle_index_;
  s.circle_samples = circle_samples_;
  s.circle_sample_force = circle_sample_force_;
  s.circle_rms = circle_samples_ > 0 ? std::sqrt(circle_sum_sq_ / circle_samples_) : 0.0;
  s.circle_unavoidable_steps = circle_unavoidable_;
  s.last_rms_variable = last_rms_variable_;
  s.last_rms_fixed = last_rms_fixed_;
  s.motion_duration = motion_ == MbcrMotion::move_cp ? move_duration_
                      : (motion_ == MbcrMotion::approach || motion_ == MbcrMotion::circle)
                          ? approach_duration_ + robot_.settings().circle.period
                          : 0.0;
  robot_.published_.store(s);
}

}  // namespace tendril::server
