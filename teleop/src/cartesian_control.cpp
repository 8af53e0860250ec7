#include "tendril/teleop/cartesian_control.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

namespace {

// Peaks of the quintic time scaling s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ over a duration T: ṡ ≤ 15/(8T) at τ = ½,
// s̈ ≤ 10/(√3·T²) at τ = ½ ∓ √3/6.
constexpr double kPeakVelocity = 15.0 / 8.0;
const double kPeakAcceleration = 10.0 / std::sqrt(3.0);

bool is_rotation(const Eigen::Matrix3d& r) noexcept {
  return r.allFinite() && (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         r.determinant() > 0.0;
}

bool is_pose(const Eigen::Isometry3d& pose) noexcept {
  return pose.translation().allFinite() && is_rotation(pose.linear());
}

CartesianCommandResult resolve(const SerialArmKinematics& model, SerialArmData& data, Twist twist,
                               const CartesianLimits& limits, double dt) noexcept {
  CartesianCommandResult r;
  if (!twist.allFinite()) return r;
  r.twist_limited = limit_twist(twist, limits.max_linear_speed, limits.max_angular_speed);
  r.twist = twist;
  r.joints = resolve_twist(model, data, twist, limits.max_linear_speed, limits.max_angular_speed, dt);
  if (!r.joints.valid) r.twist.setZero();
  return r;
}

bool step_ok(double dt) noexcept { return std::isfinite(dt) && dt > 0.0; }

}  // namespace

void validate(const CartesianLimits& limits) {
  const auto check = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0.0)) {
      throw std::invalid_argument(std::string("Cartesian limits: ") + name +
                                  " must be finite and positive (got " + std::to_string(v) + ")");
    }
  };
  check(limits.max_linear_speed, "max_linear_speed");
  check(limits.max_angular_speed, "max_angular_speed");
  check(limits.max_linear_acceleration, "max_linear_acceleration");
  check(limits.max_angular_acceleration, "max_angular_acceleration");
}

bool measured_cp(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                 Eigen::Isometry3d& pose) noexcept {
  if (!model.forward_kinematics(q, data)) return false;
  pose = data.tool;
  return true;
}

bool measured_cv(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                 const ArmVector& joint_velocity, Twist& twist) noexcept {
  if (!joint_velocity.allFinite() || !model.update(q, data)) return false;
  twist.noalias() = data.jacobian * joint_velocity;
  return true;
}

CartesianCommandResult servo_cv(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                                const Twist& twist, const CartesianLimits& limits, double dt) noexcept {
  if (!step_ok(dt) || !model.update(q, data)) return {};
  return resolve(model, data, twist, limits, dt);
}

CartesianCommandResult servo_cp(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                                const Eigen::Isometry3d& goal, const TaskSpaceGains& gains,
                                const CartesianLimits& limits, double dt) noexcept {
  if (!step_ok(dt) || !is_pose(goal) || !model.update(q, data)) return {};
  return resolve(model, data, pose_tracking_twist(data.tool, goal, gains, dt), limits, dt);
}

bool CartesianTrajectory::plan(const Eigen::Isometry3d& start, const Eigen::Isometry3d& goal,
                               const CartesianLimits& limits, double t0, double min_duration) noexcept {
  const bool limits_ok = limits.max_linear_speed > 0.0 && limits.max_angular_speed > 0.0 &&
                         limits.max_linear_acceleration > 0.0 && limits.max_angular_acceleration > 0.0 &&
                         std::isfinite(limits.max_linear_speed) && std::isfinite(limits.max_angular_speed) &&
                         std::isfinite(limits.max_linear_acceleration) &&
                         std::isfinite(limits.max_angular_acceleration);
  if (!limits_ok || !is_pose(start) || !is_pose(goal) || !std::isfinite(t0) || !std::isfinite(min_duration)) {
    return false;
  }
  start_position_ = start.translation();
  end_position_ = goal.translation();
  start_orientation_ = Eigen::Quaterniond(start.linear()).normalized();
  end_orientation_ = Eigen::Quaterniond(goal.linear()).normalized();
  if (start_orientation_.dot(end_orientation_) < 0.0) end_orientation_.coeffs() *= -1.0;  // the short way
  const Eigen::AngleAxisd rotation(end_orientation_ * start_orientation_.conjugate());
  rotation_angle_ = rotation.angle();
  rotation_axis_ = rotation_angle_ > 0.0 ? rotation.axis() : Eigen::Vector3d::UnitZ();
  const double distance = (end_position_ - start_position_).norm();
  duration_ = std::max({min_duration, 0.0, kPeakVelocity * distance / limits.max_linear_speed,
                        kPeakVelocity * rotation_angle_ / limits.max_angular_speed,
                        std::sqrt(kPeakAcceleration * distance / limits.max_linear_acceleration),
                        std::sqrt(kPeakAcceleration * rotation_angle_ / limits.max_angular_acceleration)});
  start_time_ = t0;
  return true;
}

void CartesianTrajectory::hold(const Eigen::Isometry3d& pose, double t) noexcept {
  CartesianLimits unit;
  plan(pose, pose, unit, t);
}

CartesianTrajectory::Sample CartesianTrajectory::sample(double t) const noexcept {
  Sample out;
  double s = 1.0, s_dot = 0.0;
  if (duration_ > 0.0) {
    const double tau = std::clamp((t - start_time_) / duration_, 0.0, 1.0);
    const double tau2 = tau * tau;
    s = tau2 * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
    s_dot = 30.0 * tau2 * (1.0 - tau) * (1.0 - tau) / duration_;
  }
  out.pose.setIdentity();
  out.pose.translation() = start_position_ + s * (end_position_ - start_position_);
  out.pose.linear() = start_orientation_.slerp(s, end_orientation_).toRotationMatrix();
  out.twist.head<3>() = s_dot * (end_position_ - start_position_);
  out.twist.tail<3>() = s_dot * rotation_angle_ * rotation_axis_;
  return out;
}

CartesianCommandResult track(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                             const CartesianTrajectory::Sample& reference, const TaskSpaceGains& gains,
                             const CartesianLimits& limits, double dt) noexcept {
  if (!step_ok(dt) || !is_pose(reference.pose) || !reference.twist.allFinite() || !model.update(q, data))
    return {};
  return resolve(model, data, reference.twist + pose_tracking_twist(data.tool, reference.pose, gains, dt),
                 limits, dt);
}

}  // namespace tendril::teleop
