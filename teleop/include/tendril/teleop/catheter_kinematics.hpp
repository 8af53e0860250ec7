// ConstantCurvatureCatheter: forward kinematics of the two-segment steerable robotic microcatheter
// (SRMC, Abah 2022, §4.5.1, eqs. 4.4–4.6) with the constant-curvature placeholder shape of §4.5.2:
//   θ_i(s, q) = π/2 − k_i·q_{i+2}·s/L_i   (tangent angle from x̂ in the bending plane).
// Chain: ⁰H₁ (insert q1 along ẑ) · roll e^{q2[ẑ×]} · proximal CS [e^{θ̃_L1[ŷ×]}, d1] · e^{δ2[ẑ×]} ·
// flexure e^{γ[x̂×]} · distal CS [e^{θ̃_L2[ŷ×]}, d2], with θ̃ = π/2 − θ_L = k·q (the bend angle).
//
// Frame convention (chosen here, the dissertation leaves it open): frame {0} is the insertion frame; its z
// axis is the insertion axis. The base of the proximal segment sits at (0, 0, q1), so a straight
// catheter (q3 = q4 = 0) points along +z with its tip at z = q1 + L1 + L2. A positive push-pull q3
// bends the proximal segment towards +x (before roll). Lengths in mm, angles in rad, q1/q3/q4 in mm.
// The model is immutable; all evaluation functions are const, noexcept and allocation-free.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <span>

namespace tendril::teleop {

struct CatheterParameters {
  double proximal_length = 10.5;         // L1 (mm)
  double distal_length = 23.5;           // L2 (mm)
  double plane_offset = -0.44;           // δ2 (rad) between the bending planes
  double proximal_curvature_gain = 1.4;  // k1 (rad/mm): tip bend angle per mm of q3
  double distal_curvature_gain = 1.4;    // k2 (rad/mm): tip bend angle per mm of q4
  double flexure = 0.0;                  // γ (rad), passive flexure about x at the distal base
  double shaft_length = 0.0;             // straight non-steerable shaft drawn before the segments (mm)
};

struct TipPose {
  Eigen::Vector3d position;
  Eigen::Matrix3d rotation;  // columns: tip x (bending plane), y, z (tangent) in frame {0}
  Eigen::Quaterniond orientation() const { return Eigen::Quaterniond(rotation); }
};

class ConstantCurvatureCatheter {
 public:
  static constexpr std::size_t kJoints = 4;  // insertion, roll, proximal drive, distal drive
  using JointVector = Eigen::Matrix<double, 4, 1>;
  using PositionJacobian = Eigen::Matrix<double, 3, 4>;

  // Throws std::invalid_argument when a length is not positive or a parameter is not finite.
  explicit ConstantCurvatureCatheter(const CatheterParameters& parameters);

  const CatheterParameters& parameters() const noexcept { return parameters_; }

  // Tip bend angles θ̃_Li = π/2 − θ_i(L_i, q) (rad) of the proximal and distal segments.
  double proximal_bend(const JointVector& q) const noexcept;
  double distal_bend(const JointVector& q) const noexcept;

  // Pose of the distal tip (frame {6}) in frame {0}.
  TipPose tip_pose(const JointVector& q) const noexcept;

  // ∂(tip position)/∂q, 3×4, in frame {0} (central differences on the closed-form model).
  PositionJacobian tip_position_jacobian(const JointVector& q) const noexcept;

  // Number of points backbone() writes for a given resolution.
  std::size_t backbone_point_count(std::size_t points_per_segment) const noexcept;

  // Backbone polyline in frame {0}: the shaft start (if shaft_length > 0), the proximal base, then
  // points_per_segment points along each segment ending at the tip. Returns the number of points
  // written, or 0 when out is too small or points_per_segment is 0.
  std::size_t backbone(const JointVector& q, std::size_t points_per_segment,
                       std::span<Eigen::Vector3d> out) const noexcept;

 private:
  CatheterParameters parameters_;
};

}  // namespace tendril::teleop
