// SerialArmKinematics: a six-joint serial arm in standard (distal) Denavit–Hartenberg convention, split
// as in Pinocchio into an immutable model (this class: DH table, tool transform, joint limits, damping
// law) and a preallocated workspace (SerialArmData) that every evaluation writes into. After the model
// and its data are constructed, forward kinematics, the Jacobian and the damped least-squares inverse
// never allocate, lock or throw.
//
// Conventions: lengths in mm, angles in rad. Link i's transform is
//   ⁱ⁻¹Tᵢ = Rot_z(qᵢ + θ_offset,i) · Trans_z(dᵢ) · Trans_x(aᵢ) · Rot_x(αᵢ),
// frame 0 is the robot base and frame 6 the tool flange; the tool point is frame 6 · tool. A twist is
// [v (mm/s); ω (rad/s)]: the linear velocity of the tool point and the angular velocity, both in the base
// frame, so the geometric Jacobian maps q̇ to that twist.
//
// Damped least squares (Heunis et al. 2021, eq. A14): q̇ = Jᵀ(JJᵀ + ρ²I)⁻¹V, evaluated in metres and radians
// (the linear rows of J and V are divided by DampingParameters::length_scale), so ρ has the SI meaning that
// the usual damping of 0.01–0.05 assumes and does not depend on the model's length unit. The article
// leaves ρ open; we choose a manipulability-dependent damping (Nakamura & Hanafusa 1986): with Yoshikawa's
// manipulability w = √det(JJᵀ) = |det J| of the SI Jacobian,
//   ρ² = ρ_max² (1 − w/w₀)²  for w < w₀,  else 0,
// so the inverse is exact away from singularities and smoothly damped near them. For any J the damped
// gain is at most 1/(2ρ) per unit of twist, so at a singularity ‖q̇‖ ≤ ‖V‖/(2ρ_max). Defaults for the
// UR5: ρ_max = 0.05 (the top of the usual range) and w₀ = 0.02 m³. The UR5 at a probe-down scanning
// pose has w ≈ 0.10; the median over uniformly random joint angles is 0.014. With w₀ = 0.02 the largest
// joint speed the article's caps (50 mm/s, 0.1 rad/s) can demand while the wrist (q5) or the elbow (q3)
// passes through its singularity is 2.6 rad/s, inside the UR5's 3.14 rad/s; with w₀ = 0.01 it would be
// 4.1 rad/s (serial_arm_kinematics_test.cpp sweeps both singularities).
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstddef>

namespace tendril::teleop {

inline constexpr std::size_t kArmJoints = 6;
using ArmVector = Eigen::Matrix<double, 6, 1>;
using ArmJacobian = Eigen::Matrix<double, 6, 6>;
using Twist = Eigen::Matrix<double, 6, 1>;  // [v (mm/s); ω (rad/s)] of the tool point, base frame

// One row of the standard DH table.
struct DhLink {
  double a = 0.0;             // mm, along x_i
  double alpha = 0.0;         // rad, about x_i
  double d = 0.0;             // mm, along z_{i−1}
  double theta_offset = 0.0;  // rad, added to the joint position
};

struct ArmJointLimit {
  double lower = 0.0;             // rad
  double upper = 0.0;             // rad
  double max_velocity = 0.0;      // rad/s
  double max_acceleration = 0.0;  // rad/s²
};

struct DampingParameters {
  double max_damping = 0.05;               // ρ_max, at w = 0 (SI); usual values 0.01–0.05
  double manipulability_threshold = 0.02;  // w₀ (m³ for a 6R arm): no damping above it
  double length_scale = 1000.0;            // model length units per metre (mm → m)
};

struct SerialArmParameters {
  std::array<DhLink, kArmJoints> links{};
  std::array<ArmJointLimit, kArmJoints> limits{};
  Eigen::Isometry3d tool = Eigen::Isometry3d::Identity();  // flange (frame 6) → tool point
  DampingParameters damping{};
};

// The UR5 (CB3 and e-series share the geometry) with Universal Robots' published DH parameters:
// d1 = 89.159, a2 = −425, a3 = −392.25, d4 = 109.15, d5 = 94.65, d6 = 82.3 mm; α = π/2, 0, 0, π/2,
// −π/2, 0. Limits from the UR5 data sheet: every joint ±360° at 180°/s. The data sheet gives no
// acceleration limit; 8 rad/s² is our choice (a probe held at the article's 50 mm/s and 0.1 rad/s needs
// far less, and it keeps a simulated stop short). `tool` is identity.
SerialArmParameters ur5_parameters();

// The mutable workspace of one arm. Create it with SerialArmKinematics::make_data().
struct SerialArmData {
  ArmVector q = ArmVector::Zero();  // the joint positions of the last forward_kinematics()
  // frames[0] is the base (identity), frames[i] the DH frame of link i, frames[6] the flange.
  std::array<Eigen::Isometry3d, kArmJoints + 1> frames{};
  Eigen::Isometry3d tool = Eigen::Isometry3d::Identity();  // the tool point in the base frame
  ArmJacobian jacobian = ArmJacobian::Zero();              // geometric, tool point, base frame
  double manipulability = 0.0;                             // w of the last damped_least_squares() (SI)
  double damping = 0.0;                                    // ρ of the last damped_least_squares() (SI)
  // Workspace of the damped inverse.
  ArmJacobian scaled_jacobian = ArmJacobian::Zero();
  ArmJacobian normal_matrix = ArmJacobian::Zero();
  Eigen::LDLT<ArmJacobian> ldlt{};
};

class SerialArmKinematics {
 public:
  // Throws std::invalid_argument naming the joint and value when a DH entry or limit is not finite,
  // lower ≥ upper, a velocity or acceleration limit is not positive, the tool transform is not a rigid
  // motion, or a damping parameter is negative, not finite, or (threshold, length scale) not positive.
  explicit SerialArmKinematics(const SerialArmParameters& parameters);

  const SerialArmParameters& parameters() const noexcept { return parameters_; }
  const ArmJointLimit& limit(std::size_t joint) const noexcept { return parameters_.limits[joint]; }
  SerialArmData make_data() const;

  // Every frame and the tool pose at q. Returns false (data untouched) when q is not finite.
  bool forward_kinematics(const ArmVector& q, SerialArmData& data) const noexcept;
  // The geometric Jacobian at data.q (call forward_kinematics first).
  void compute_jacobian(SerialArmData& data) const noexcept;
  // Both, for the common case. Returns false (data untouched) when q is not finite.
  bool update(const ArmVector& q, SerialArmData& data) const noexcept;

  // q̇ = J†V with the damping law above, at data's Jacobian; records w and ρ in data. Returns false
  // and a zero q̇ when the twist is not finite or the solution is not finite.
  bool damped_least_squares(SerialArmData& data, const Twist& twist,
                            ArmVector& joint_velocity) const noexcept;
  // ρ for a manipulability w (SI).
  double damping_for(double manipulability) const noexcept;

  bool within_limits(const ArmVector& q) const noexcept;
  // Scales q̇ uniformly (its direction, hence the tool's path, is kept) so that no joint exceeds its
  // velocity limit. Returns true when it had to.
  bool clamp_to_velocity_limits(ArmVector& joint_velocity) const noexcept;
  // Stops each joint that would cross its position limit within dt: its q̇ is cut to reach the limit
  // exactly. Returns true when any joint was cut.
  bool clamp_to_position_limits(const ArmVector& q, ArmVector& joint_velocity, double dt) const noexcept;

 private:
  SerialArmParameters parameters_;
};

}  // namespace tendril::teleop
