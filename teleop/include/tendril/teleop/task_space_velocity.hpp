// The task-space velocity laws of Heunis et al. 2021, Appendix A, shared by the ultrasound
// probe's hybrid position/force controller (hybrid_force_controller.hpp) and the plain Cartesian
// commands (cartesian_control.hpp), and the step from a twist to joint velocities (A13–A14) with the
// joint limits applied. Pure functions; noexcept and allocation-free.
//
// Orientation error (A2–A5), with two misprints of the article corrected: the error is two angles about two
// axes, not a single rotation vector. E_θz is the angle between the probe's z axis (the beam axis) and
// the target's, about θ̂_z = ẑ_u × ẑ_i; E_θy is what remains about the probe axis once the rotation
// R(E_θz, θ̂_z) has aligned the z axes: the angle from R·ŷ_u to ŷ_i, about Rᵀ(R·ŷ_u × ŷ_i) = ±ẑ_u. Angles
// use atan2(|a×b|, a·b) rather than the paper's arcsin(|a×b|), which cannot tell 30° from 150°. The gate
// of the ultrasound sweep tests E_θy and E_θz separately (d_θ = 0.01 rad each), which is why we keep the
// paper's representation and do not use an angle–axis or quaternion error.
//
// A6–A8: ω_e = ω_d(1 − e^{−E_θy/γ})·θ̂_y + ω_d(1 − e^{−E_θz/γ})·θ̂_z; the two terms are orthogonal, so
// their sum can reach √2·ω_d and is scaled back to ω_d.
// A9: V_e = V_d(1 − e^{−|E|/μ})·Ê + τ·E·Δt·e^{−(|E|/μ)⁵}, with the integral read per iteration (the
// integral of E over the last control step; where the article is ambiguous, the 1-s window and the cumulative
// integral are unstable or overshoot by 15–29 mm with τ = 20), capped at V_d.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace tendril::teleop {

// Position and orientation parameters of Heunis et al. 2021, Table 1 (units mm, rad, s).
struct TaskSpaceGains {
  double velocity_threshold = 25.0;    // μ (mm): the scale of the exponential speed profile
  double integral_gain = 20.0;         // τ, Table 1's "integral time constant" (1/s² as A9 uses it)
  double max_linear_speed = 50.0;      // V_d (mm/s)
  double orientation_threshold = 0.1;  // γ (rad)
  double max_angular_speed = 0.1;      // ω_d (rad/s)
};
// Throws std::invalid_argument naming the field when a value is not finite and positive (τ may be 0).
void validate(const TaskSpaceGains& gains);

struct OrientationError {
  double about_z = 0.0;                              // E_θz (rad), in [0, π]
  double about_y = 0.0;                              // E_θy (rad), in [0, π]
  Eigen::Vector3d axis_z = Eigen::Vector3d::Zero();  // θ̂_z, unit (base frame); zero when aligned
  Eigen::Vector3d axis_y = Eigen::Vector3d::Zero();  // θ̂_y, unit, ±ẑ_u; zero when aligned
};

// A2–A5 for the current and target orientations (columns: the probe's x, y, z axes in the base frame).
OrientationError orientation_error(const Eigen::Matrix3d& current, const Eigen::Matrix3d& target) noexcept;

// A6–A8, capped at ω_d (rad/s, base frame).
Eigen::Vector3d angular_velocity(const OrientationError& error, const TaskSpaceGains& gains) noexcept;

// A9 for a position error E (mm, base frame) over a control step dt (s), capped at V_d (mm/s).
Eigen::Vector3d linear_velocity(const Eigen::Vector3d& error, const TaskSpaceGains& gains,
                                double dt) noexcept;

// A1 + A2–A9 with the full 3-D position error: the twist that drives `current` towards `target`.
Twist pose_tracking_twist(const Eigen::Isometry3d& current, const Eigen::Isometry3d& target,
                          const TaskSpaceGains& gains, double dt) noexcept;

// Scales the linear part to at most max_linear and the angular part to at most max_angular, each
// keeping its direction. Returns true when it had to.
bool limit_twist(Twist& twist, double max_linear, double max_angular) noexcept;

struct JointVelocityResult {
  ArmVector joint_velocity = ArmVector::Zero();  // rad/s; zero unless `valid`
  bool valid = false;             // false: a non-finite twist, Jacobian or solution (q̇ is zero)
  bool velocity_limited = false;  // scaled down to the joint velocity limits
  bool position_limited = false;  // a joint was stopped at its position limit
  bool speed_limited = false;     // scaled down so that J·q̇ stays within the Cartesian caps
  double damping = 0.0;           // ρ used (SI)
  double manipulability = 0.0;    // w (SI)
};

// A13–A14 at data's Jacobian (call model.update(q, data) first), then the joint velocity limits
// (uniform scaling, so the tool keeps its path) and the position limits over dt. Last, the tool twist
// the result will produce, J·q̇, is checked against the Cartesian caps and q̇ scaled down if needed:
// damping mixes the linear and angular parts (their sum of squares in SI cannot grow, but either part
// can), and a joint stopped at its limit changes the motion, so the caps are enforced on what the arm
// will do, not only on what was asked.
JointVelocityResult resolve_twist(const SerialArmKinematics& model, SerialArmData& data, const Twist& twist,
                                  double max_linear_speed, double max_angular_speed, double dt) noexcept;

}  // namespace tendril::teleop
