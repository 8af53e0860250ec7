#include "tendril/teleop/task_space_velocity.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

namespace {

// Below this a cross product's length is treated as zero (the axes are parallel).
constexpr double kParallel = 1e-12;

void require_positive(double value, const char* name) {
  if (!(std::isfinite(value) && value > 0.0)) {
    throw std::invalid_argument(std::string("task-space gains: ") + name +
                                " must be finite and positive (got " + std::to_string(value) + ")");
  }
}

// The speed profile of A6, A7 and A9: max·(1 − e^{−e/threshold}).
double saturating(double error, double threshold, double max) noexcept {
  return max * -std::expm1(-error / threshold);
}

}  // namespace

void validate(const TaskSpaceGains& gains) {
  require_positive(gains.velocity_threshold, "velocity_threshold (mu)");
  if (!(std::isfinite(gains.integral_gain) && gains.integral_gain >= 0.0)) {
    throw std::invalid_argument("task-space gains: integral_gain (tau) must be finite and >= 0 (got " +
                                std::to_string(gains.integral_gain) + ")");
  }
  require_positive(gains.max_linear_speed, "max_linear_speed (V_d)");
  require_positive(gains.orientation_threshold, "orientation_threshold (gamma)");
  require_positive(gains.max_angular_speed, "max_angular_speed (omega_d)");
}

OrientationError orientation_error(const Eigen::Matrix3d& current, const Eigen::Matrix3d& target) noexcept {
  OrientationError e;
  const Eigen::Vector3d zu = current.col(2), zi = target.col(2);
  // A2–A3: the z axes.
  const Eigen::Vector3d cz = zu.cross(zi);
  const double sz = cz.norm();
  e.about_z = std::atan2(sz, zu.dot(zi));
  if (sz > kParallel) {
    e.axis_z = cz / sz;
  } else if (zu.dot(zi) < 0.0) {
    e.axis_z = current.col(0);  // opposite axes: any perpendicular axis turns one onto the other
  }
  // A4–A5: align z first, then the y residual about the probe axis.
  const Eigen::Matrix3d align = e.about_z > 0.0 ? Eigen::AngleAxisd(e.about_z, e.axis_z).toRotationMatrix()
                                                : Eigen::Matrix3d::Identity();
  const Eigen::Vector3d yu = align * current.col(1), yi = target.col(1);
  const Eigen::Vector3d cy = yu.cross(yi);
  const double sy = cy.norm();
  e.about_y = std::atan2(sy, yu.dot(yi));
  if (sy > kParallel) {
    e.axis_y = align.transpose() * (cy / sy);
  } else if (yu.dot(yi) < 0.0) {
    e.axis_y = zu;  // a half turn about the probe axis, either way
  }
  return e;
}

Eigen::Vector3d angular_velocity(const OrientationError& error, const TaskSpaceGains& gains) noexcept {
  const double wy = saturating(error.about_y, gains.orientation_threshold, gains.max_angular_speed);
  const double wz = saturating(error.about_z, gains.orientation_threshold, gains.max_angular_speed);
  Eigen::Vector3d w = wy * error.axis_y + wz * error.axis_z;  // A8
  const double n = w.norm();
  if (n > gains.max_angular_speed) w *= gains.max_angular_speed / n;
  return w;
}

Eigen::Vector3d linear_velocity(const Eigen::Vector3d& error, const TaskSpaceGains& gains,
                                double dt) noexcept {
  const double n = error.norm();
  Eigen::Vector3d v = Eigen::Vector3d::Zero();
  if (n > kParallel) v = saturating(n, gains.velocity_threshold, gains.max_linear_speed) / n * error;
  const double r = n / gains.velocity_threshold;
  const double gate = std::exp(-(r * r) * (r * r) * r);  // e^{−(|E|/μ)⁵}: the integral acts near the target
  v += gains.integral_gain * dt * gate * error;          // the per-iteration integral of E
  const double speed = v.norm();
  if (speed > gains.max_linear_speed) v *= gains.max_linear_speed / speed;
  return v;
}

Twist pose_tracking_twist(const Eigen::Isometry3d& current, const Eigen::Isometry3d& target,
                          const TaskSpaceGains& gains, double dt) noexcept {
  Twist twist;
  twist.head<3>() = linear_velocity(target.translation() - current.translation(), gains, dt);
  twist.tail<3>() = angular_velocity(orientation_error(current.linear(), target.linear()), gains);
  return twist;
}

bool limit_twist(Twist& twist, double max_linear, double max_angular) noexcept {
  bool limited = false;
  const double v = twist.head<3>().norm(), w = twist.tail<3>().norm();
  if (v > max_linear) {
    twist.head<3>() *= max_linear / v;
    limited = true;
  }
  if (w > max_angular) {
    twist.tail<3>() *= max_angular / w;
    limited = true;
  }
  return limited;
}

JointVelocityResult resolve_twist(const SerialArmKinematics& model, SerialArmData& data, const Twist& twist,
                                  double max_linear_speed, double max_angular_speed, double dt) noexcept {
  JointVelocityResult r;
  r.valid = model.damped_least_squares(data, twist, r.joint_velocity);
  r.damping = data.damping;
  r.manipulability = data.manipulability;
  if (!r.valid) return r;
  r.velocity_limited = model.clamp_to_velocity_limits(r.joint_velocity);
  r.position_limited = model.clamp_to_position_limits(data.q, r.joint_velocity, dt);
  const Twist achieved = data.jacobian * r.joint_velocity;
  const double excess =
      std::max(achieved.head<3>().norm() / max_linear_speed, achieved.tail<3>().norm() / max_angular_speed);
  if (excess > 1.0) {  // also false for NaN caps: those are refused by validate()
    r.joint_velocity /= excess;
    r.speed_limited = true;
  }
  return r;
}

}  // namespace tendril::teleop
