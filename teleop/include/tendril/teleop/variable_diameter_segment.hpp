// One continuum segment of the variable-diameter multi-backbone continuum robot (MBCR, Abah 2022,
// ch. 2): its instantaneous kinematics with the diameter as an extra joint (§2.5, eqs. 2.19–2.23) and
// its statics by virtual work (§2.6.1, eqs. 2.24–2.30). Pure functions of their arguments: const data
// in, fixed-size Eigen values out, noexcept and allocation-free, so the control thread may call them.
//
// Conventions (Simaan's, as the dissertation's equations use them):
//   ψ = [θ_L, δ]: θ_L is the end disk's tangent angle, π/2 when straight; δ the bending-plane angle.
//   Θ = θ_L − π/2 is the bend (≤ 0 when bent by a positive amount; the formulas accept either sign).
//   Secondary backbone i (i = 1..4) sits at angle (i − 1)·π/2 about the segment's z axis on the
//   configuration radius r; δ_i = δ + (i − 1)·π/2 and its length is L_i = L + r·Θ·cos δ_i (2.19), so
//   its joint value (push–pull displacement) is q_i = L_i − L. The segment bends towards the base-frame
//   direction (cos δ, −sin δ, 0), where the shortened backbones are.
//   The end disk's frame is R = Rz(−δ)·Ry(−Θ)·Rz(δ) at p = (L/Θ)·[cos δ(cos Θ − 1), −sin δ(cos Θ − 1),
//   sin Θ] (Abah 2022, §2.5, extended); its backbone holes line up with the next segment's backbones.
//   A twist is [v (mm/s); ω (rad/s)] of the end disk's centre, in the segment's base frame.
// Lengths in mm, forces in N, moments in N·mm, Young's modulus in N/mm² (MPa).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace tendril::teleop {

using SegmentConfiguration = Eigen::Vector2d;                  // ψ = [θ_L, δ] (rad)
using SegmentJointJacobian = Eigen::Matrix<double, 4, 2>;      // J_qψ: ψ̇ → q̇ of the four backbones
using SegmentAugmentation = Eigen::Matrix<double, 4, 5>;       // A of (2.22)
using SegmentAugmentedJacobian = Eigen::Matrix<double, 5, 2>;  // J_q̃ψ = A⁺·J_qψ (2.23)
using SegmentTwistJacobian = Eigen::Matrix<double, 6, 2>;      // J_xψ: ψ̇ → [v; ω]
using SegmentActuation = Eigen::Matrix<double, 5, 1>;          // τ̃ = [4 backbone forces (N); diameter (N)]
using Wrench = Eigen::Matrix<double, 6, 1>;                    // [f (N); m (N·mm)]

inline constexpr double kStraightTangentAngle = 1.57079632679489661923;  // θ_L of a straight segment

// Θ = θ_L − π/2.
inline double segment_bend(const SegmentConfiguration& psi) noexcept {
  return psi[0] - kStraightTangentAngle;
}

// (2.19) q_i = r·Θ·cos δ_i for the four backbones.
Eigen::Vector4d backbone_displacements(const SegmentConfiguration& psi, double r) noexcept;
// J_qψ, row i = [r·cos δ_i, −r·Θ·sin δ_i] (the derivative of (2.19)).
SegmentJointJacobian backbone_jacobian(const SegmentConfiguration& psi, double r) noexcept;
// The column ∂q_i/∂a = Θ·cos δ_i·dr/da of the diameter joint, so A = [I₄ | −column] (2.22).
Eigen::Vector4d diameter_column(const SegmentConfiguration& psi, double dr_da) noexcept;
SegmentAugmentation augmentation_matrix(const SegmentConfiguration& psi, double dr_da) noexcept;
// (2.23) J_q̃ψ = A⁺·J_qψ with A⁺ = Aᵀ(AAᵀ)⁻¹ in closed form (AAᵀ = I + ccᵀ, Sherman–Morrison).
SegmentAugmentedJacobian augmented_jacobian(const SegmentConfiguration& psi, double r, double dr_da) noexcept;

// End-disk pose in the segment's base frame, and J_xψ (with second-order Taylor forms near Θ = 0).
Eigen::Isometry3d segment_end_pose(const SegmentConfiguration& psi, double length) noexcept;
SegmentTwistJacobian segment_twist_jacobian(const SegmentConfiguration& psi, double length) noexcept;

// Bending stiffness E·I of one round backbone of outer diameter `diameter` (mm): I = π·d⁴/64.
double backbone_bending_stiffness(double youngs_modulus, double diameter) noexcept;

// (2.24) U = Σ E·I·Θ²/(2·L_i), the backbones' bending energy (N·mm).
double elastic_energy(const SegmentConfiguration& psi, double r, double length,
                      double bending_stiffness) noexcept;
// (2.26) ∂U/∂r = −(E·I·Θ³/2)·Σ cos δ_i/L_i², with the square the dissertation's print drops.
double elastic_energy_radius_gradient(const SegmentConfiguration& psi, double r, double length,
                                      double bending_stiffness) noexcept;
// (2.27) ∂U/∂ψ.
Eigen::Vector2d elastic_energy_configuration_gradient(const SegmentConfiguration& psi, double r,
                                                      double length, double bending_stiffness) noexcept;

struct SegmentStatics {
  SegmentActuation actuation = SegmentActuation::Zero();                           // τ̃ (2.30)
  SegmentAugmentedJacobian augmented_jacobian = SegmentAugmentedJacobian::Zero();  // J_q̃ψ
  Eigen::RowVector2d radius_jacobian = Eigen::RowVector2d::Zero();                 // J_rψ
  Eigen::Vector2d generalized_load = Eigen::Vector2d::Zero();  // J_rψᵀ∇U_r + ∇U_ψ − J_xψᵀW_e (2.29)
};

// (2.28)–(2.30) for one segment carrying `wrench` at its end disk (base frame): the minimum-norm
// actuation τ̃ = (J_q̃ψᵀ)⁺·[J_rψᵀ∇U_r + ∇U_ψ − J_xψᵀW_e], with J_rψ = (dr/da)·(row 5 of J_q̃ψ), the
// radius change that the diameter joint's share of the motion makes (the dissertation leaves J_rψ implicit).
// The pseudo-inverse drops directions that a straight segment cannot express (δ has no effect at
// Θ = 0). Returns false, with a zero τ̃, when an input is not finite.
bool segment_statics(const SegmentConfiguration& psi, double r, double dr_da, double length,
                     double bending_stiffness, const Wrench& wrench, SegmentStatics& out) noexcept;

}  // namespace tendril::teleop
