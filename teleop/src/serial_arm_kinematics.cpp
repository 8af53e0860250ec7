#include "tendril/teleop/serial_arm_kinematics.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

namespace {

constexpr double kPi = std::numbers::pi;

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("serial arm: " + what);
}

std::string joint_name(std::size_t i) { return "joint " + std::to_string(i + 1); }

// ⁱ⁻¹Tᵢ = Rot_z(θ) · Trans_z(d) · Trans_x(a) · Rot_x(α), written out.
Eigen::Isometry3d dh_transform(const DhLink& link, double theta) noexcept {
  const double ct = std::cos(theta), st = std::sin(theta);
  const double ca = std::cos(link.alpha), sa = std::sin(link.alpha);
  Eigen::Isometry3d t;
  t.matrix() << ct, -st * ca, st * sa, link.a * ct,  //
      st, ct * ca, -ct * sa, link.a * st,            //
      0.0, sa, ca, link.d,                           //
      0.0, 0.0, 0.0, 1.0;
  return t;
}

}  // namespace

SerialArmParameters ur5_parameters() {
  SerialArmParameters p;
  p.links = {{{.a = 0.0, .alpha = kPi / 2.0, .d = 89.159},
              {.a = -425.0, .alpha = 0.0, .d = 0.0},
              {.a = -392.25, .alpha = 0.0, .d = 0.0},
              {.a = 0.0, .alpha = kPi / 2.0, .d = 109.15},
              {.a = 0.0, .alpha = -kPi / 2.0, .d = 94.65},
              {.a = 0.0, .alpha = 0.0, .d = 82.3}}};
  for (auto& limit : p.limits) {
    limit = {.lower = -2.0 * kPi, .upper = 2.0 * kPi, .max_velocity = kPi, .max_acceleration = 8.0};
  }
  return p;
}

SerialArmKinematics::SerialArmKinematics(const SerialArmParameters& parameters) : parameters_(parameters) {
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    const DhLink& l = parameters.links[i];
    require(
        std::isfinite(l.a) && std::isfinite(l.alpha) && std::isfinite(l.d) && std::isfinite(l.theta_offset),
        joint_name(i) + ": DH parameters must be finite");
    const ArmJointLimit& lim = parameters.limits[i];
    require(std::isfinite(lim.lower) && std::isfinite(lim.upper) && lim.lower < lim.upper,
            joint_name(i) + ": position limits must be finite with lower < upper (got " +
                std::to_string(lim.lower) + ", " + std::to_string(lim.upper) + ")");
    require(std::isfinite(lim.max_velocity) && lim.max_velocity > 0.0,
            joint_name(i) + ": max_velocity must be positive (got " + std::to_string(lim.max_velocity) + ")");
    require(std::isfinite(lim.max_acceleration) && lim.max_acceleration > 0.0,
            joint_name(i) + ": max_acceleration must be positive (got " +
                std::to_string(lim.max_acceleration) + ")");
  }
  const Eigen::Matrix4d& tool = parameters.tool.matrix();
  require(tool.allFinite(), "the tool transform must be finite");
  const Eigen::Matrix3d r = parameters.tool.linear();
  require((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-9 && r.determinant() > 0.0,
          "the tool transform's rotation must be orthonormal with determinant +1");
  const DampingParameters& d = parameters.damping;
  require(std::isfinite(d.max_damping) && d.max_damping >= 0.0,
          "damping.max_damping must be finite and ≥ 0 (got " + std::to_string(d.max_damping) + ")");
  require(std::isfinite(d.manipulability_threshold) && d.manipulability_threshold > 0.0,
          "damping.manipulability_threshold must be positive (got " +
              std::to_string(d.manipulability_threshold) + ")");
  require(std::isfinite(d.length_scale) && d.length_scale > 0.0,
          "damping.length_scale must be positive (got " + std::to_string(d.length_scale) + ")");
}

SerialArmData SerialArmKinematics::make_data() const {
  SerialArmData data;
  forward_kinematics(ArmVector::Zero(), data);
  compute_jacobian(data);
  return data;
}

bool SerialArmKinematics::forward_kinematics(const ArmVector& q, SerialArmData& data) const noexcept {
  if (!q.allFinite()) return false;
  data.q = q;
  data.frames[0].setIdentity();
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    const DhLink& link = parameters_.links[i];
    data.frames[i + 1] =
        data.frames[i] * dh_transform(link, q[static_cast<Eigen::Index>(i)] + link.theta_offset);
  }
  data.tool = data.frames[kArmJoints] * parameters_.tool;
  return true;
}

void SerialArmKinematics::compute_jacobian(SerialArmData& data) const noexcept {
  const Eigen::Vector3d tool_point = data.tool.translation();
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    // Joint i+1 turns about z of frame i, through frame i's origin.
    const Eigen::Vector3d z = data.frames[i].linear().col(2);
    const Eigen::Vector3d p = data.frames[i].translation();
    const auto c = static_cast<Eigen::Index>(i);
    data.jacobian.block<3, 1>(0, c) = z.cross(tool_point - p);
    data.jacobian.block<3, 1>(3, c) = z;
  }
}

bool SerialArmKinematics::update(const ArmVector& q, SerialArmData& data) const noexcept {
  if (!forward_kinematics(q, data)) return false;
  compute_jacobian(data);
  return true;
}

double SerialArmKinematics::damping_for(double manipulability) const noexcept {
  const DampingParameters& d = parameters_.damping;
  if (!(manipulability < d.manipulability_threshold)) return 0.0;  // also for NaN: callers check J first
  const double shortfall = 1.0 - std::max(manipulability, 0.0) / d.manipulability_threshold;
  return d.max_damping * shortfall;
}

bool SerialArmKinematics::damped_least_squares(SerialArmData& data, const Twist& twist,
                                               ArmVector& joint_velocity) const noexcept {
  joint_velocity.setZero();
  if (!twist.allFinite() || !data.jacobian.allFinite()) return false;
  const double inv_scale = 1.0 / parameters_.damping.length_scale;
  data.scaled_jacobian = data.jacobian;
  data.scaled_jacobian.topRows<3>() *= inv_scale;
  Twist scaled_twist = twist;
  scaled_twist.head<3>() *= inv_scale;

  data.manipulability = std::abs(data.scaled_jacobian.determinant());
  data.damping = damping_for(data.manipulability);
  data.normal_matrix.noalias() = data.scaled_jacobian * data.scaled_jacobian.transpose();
  data.normal_matrix.diagonal().array() += data.damping * data.damping;
  data.ldlt.compute(data.normal_matrix);
  const Twist y = data.ldlt.solve(scaled_twist);
  joint_velocity.noalias() = data.scaled_jacobian.transpose() * y;
  if (data.ldlt.info() != Eigen::Success || !joint_velocity.allFinite()) {
    joint_velocity.setZero();
    return false;
  }
  return true;
}

bool SerialArmKinematics::within_limits(const ArmVector& q) const noexcept {
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    const double qi = q[static_cast<Eigen::Index>(i)];
    if (!(qi >= parameters_.limits[i].lower && qi <= parameters_.limits[i].upper)) return false;
  }
  return true;
}

bool SerialArmKinematics::clamp_to_velocity_limits(ArmVector& joint_velocity) const noexcept {
  double worst = 1.0;
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    worst = std::max(
        worst, std::abs(joint_velocity[static_cast<Eigen::Index>(i)]) / parameters_.limits[i].max_velocity);
  }
  if (!(worst > 1.0)) return false;
  joint_velocity /= worst;
  return true;
}

bool SerialArmKinematics::clamp_to_position_limits(const ArmVector& q, ArmVector& joint_velocity,
                                                   double dt) const noexcept {
  if (!(dt > 0.0)) return false;
  bool cut = false;
  for (std::size_t i = 0; i < kArmJoints; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    const ArmJointLimit& lim = parameters_.limits[i];
    const double next = q[k] + joint_velocity[k] * dt;
    if (next > lim.upper && joint_velocity[k] > 0.0) {
      joint_velocity[k] = std::max(0.0, (lim.upper - q[k]) / dt);
      cut = true;
    } else if (next < lim.lower && joint_velocity[k] < 0.0) {
      joint_velocity[k] = std::min(0.0, (lim.lower - q[k]) / dt);
      cut = true;
    }
  }
  return cut;
}

}  // namespace tendril::teleop
