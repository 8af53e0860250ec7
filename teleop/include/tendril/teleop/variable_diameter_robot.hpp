// VariableDiameterRobot: the three-segment variable-diameter multi-backbone continuum robot (MBCR,
// `mbcr_vd`, Abah 2022, §2.7) with gradient-projection redundancy resolution (eq. 2.31–2.36) that
// uses the shared diameter joint a to lower the actuation forces while it keeps every joint inside its
// limits and the disks apart. Split as in Pinocchio into an immutable model (this class) and a
// preallocated workspace (VariableDiameterData); after both exist, every per-step function is const,
// noexcept, allocation-free and reports problems as values, so it may run on the control thread.
//
// Robot (Abah 2022, §2.7.1): three identical segments stacked with aligned backbones, each a 2-DoF segment of
// variable_diameter_segment.hpp on its predecessor's end disk; one diameter input a shared by all; the
// backbones of different segments are actuated independently (Abah 2022, ref. [98]).
//   ψ_s = [θ_L1, δ1, θ_L2, δ2, θ_L3, δ3]   configuration (6)
//   q̃   = [q_1,1, q_1,2, q_2,1, q_2,2, q_3,1, q_3,2, a]   joints (7): backbones 1 and 2 of each segment
//         (3 and 4 are their mirror images, q_3 = −q_1 and q_4 = −q_2) and the diameter joint a
//   τ̃_s = [τ_1,1..τ_1,4, τ_2,1..τ_2,4, τ_3,1..τ_3,4, τ_a]   actuation (13): all twelve backbones and a
// The base frame has z along the straight robot; the tip is segment 3's end disk. A task twist is
// [v (mm/s); ω (rad/s)] of the tip in the base frame; a wrench [f (N); m (N·mm)] acts at the tip.
//
// Choices where the dissertation is silent (each one also in
// teleop/mbcr_vd/README.md):
// - Statics of the stack (2.30 "with twist transformations"): the twelve backbones and a form one
//   augmented joint vector with A₁₂ = [I₁₂ | −c], c the ∂q/∂a column of (2.22) for every backbone;
//   J_q̃ψ = A₁₂⁺·blkdiag(J_qψ,k) (13×6); J_rψ = (dr/da)·(row 13); ∇U_r and ∇U_ψ are the segments'
//   gradients (∇U_r summed, since all share r); J_xψs is the stacked twist Jacobian below.
// - ∇‖τ̃_s‖ (2.36) enters (2.34) only through its null-space projection. The null space of A_s is the
//   single direction n = [c_s; 1]/‖·‖ (a changes, the backbones follow, ψ stays), so the projected
//   finite-difference gradient is n·n_a·∂‖τ̃_s‖/∂a at fixed ψ: two statics evaluations (central
//   difference, step `force_difference_step`) instead of fourteen, and well defined when a segment is
//   straight, where ψ(q̃) is not differentiable. ∇H is analytic (derived here from H).
// - Units of the objective. The model works in mm, N, s, but the dissertation's λ = 0.05 carries no unit, and
//   g mixes newtons (‖τ̃_s‖) with an inverse length (H), so the units of g decide both how fast a moves
//   and where the force and limit terms balance. Read in mm (λ in mm²/(N·s)) the gradient moves a by
//   ~0.02 mm/s and H holds it within ~0.2 mm of a_min, so a follows only the minimum-norm part of
//   (2.34): it stays at a_min while the segments curl and grows as they unwind, with no first growth.
//   Read in SI (m, N, s; the units a MATLAB model is usually written in) the force and limit terms
//   balance ~10 mm inside the limit of a, which is the behaviour the dissertation describes (a grows, is
//   pushed back by the interference limit, grows again). We therefore evaluate g and λ∇g in SI
//   (objective_length_scale = 1000 model units per metre) and convert η back to mm/s. In SI the
//   explicit 1 ms step of λ∇g is stiff near a limit, so the null-space motion of a is capped at
//   max_diameter_rate (10 mm/s, our choice for the diameter drive), which keeps the step stable.
// - The diameter limits are [a_min, min(a_max, a_interference(ψ_s))] with a_interference the inner radius
//   at which the first segment's outer radius b reaches its interference limit (2.16); recomputed every
//   step before (2.34) as the dissertation says. H is evaluated with a floor of `limit_floor` on the distance
//   to a limit so that a limit that moves past a in one step gives a large, finite push back; after the step
//   a is clamped into its limits and the step reports that it clamped.
// - ψ̇_s = J_xψs^#·(ẋ_d + K·e) (closed-loop resolved rates, e the pose error) with a singularity-robust
//   inverse: damped least squares on J made dimensionless (linear rows divided by L), with
//   damping ρ² = ρ_max²·(1 − (σ_min/σ₀)²) below σ₀ and none above (Maciejewski & Klein 1988).
#pragma once

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <array>
#include <cstddef>

#include "tendril/teleop/variable_diameter_linkage.hpp"
#include "tendril/teleop/variable_diameter_segment.hpp"

namespace tendril::teleop {

inline constexpr int kVariableDiameterSegments = 3;
using StackConfiguration = Eigen::Matrix<double, 6, 1>;  // ψ_s
using StackJoints = Eigen::Matrix<double, 7, 1>;         // q̃ = [q (6); a]
using StackActuation = Eigen::Matrix<double, 13, 1>;     // τ̃_s
using StackTwistJacobian = Eigen::Matrix<double, 6, 6>;  // J_xψs
using StackTwist = Eigen::Matrix<double, 6, 1>;          // [v (mm/s); ω (rad/s)]

struct RedundancyParameters {
  double force_weight = 1.0;            // w₁ (Abah 2022, §2.7.2)
  double limit_weight = 1.0;            // w₂
  double step_gain = 0.05;              // λ
  double force_difference_step = 1e-3;  // mm of a for ∂‖τ̃_s‖/∂a (central difference)
  double limit_floor = 1e-3;            // mm: smallest distance to a limit that H is evaluated with
  // Model length units per length unit of the objective: g is evaluated in metres and newtons
  // (1000 mm per m), the units in which λ = 0.05 gives the dissertation's behaviour (see the header comment).
  double objective_length_scale = 1000.0;
  double max_diameter_rate = 10.0;  // mm/s: cap on the null-space motion of a (the diameter drive's speed)
};

struct TaskInverseParameters {
  double pose_gain = 20.0;           // K (1/s) on the pose error of the closed-loop resolved rates
  double max_damping = 0.02;         // ρ_max of the damped least squares (dimensionless J)
  double singular_threshold = 0.05;  // σ₀: no damping while the smallest singular value is above it
};

struct VariableDiameterRobotParameters {
  ScissorLinkageParameters linkage{};  // l₁ = 20 mm, n = 8, d = 2 mm (Table 2.3 + our d)
  DiskInterferenceParameters disks{};  // L = 200 mm, n_d = 8, h_d = 10 mm (PF 0.4), per segment
  double backbone_diameter = 1.0;      // mm (Table 2.3)
  // N/mm². The dissertation prints 74 MPa; as a backbone modulus that is a units slip for 74 GPa (nitinol is
  // 40–75 GPa), so 74 GPa is the default and tests run both.
  double youngs_modulus = 74000.0;
  double backbone_lower = -200.0;  // q_min (mm), §2.7.2
  double backbone_upper = 200.0;   // q_max (mm)
  RedundancyParameters redundancy{};
  TaskInverseParameters task{};
};

// Preallocated workspace of one robot. Create it with VariableDiameterRobot::make_data().
struct VariableDiameterData {
  // frames[k] is segment k's base (frames[0] = identity), frames[3] the tip (end disk of segment 3).
  std::array<Eigen::Isometry3d, kVariableDiameterSegments + 1> frames{};
  StackTwistJacobian task_jacobian = StackTwistJacobian::Zero();  // J_xψs at the last tip_pose()
  // Statics workspace.
  Eigen::Matrix<double, 12, 6> backbone_jacobian = Eigen::Matrix<double, 12, 6>::Zero();
  Eigen::Matrix<double, 13, 6> augmented_jacobian = Eigen::Matrix<double, 13, 6>::Zero();
  Eigen::Matrix<double, 12, 1> diameter_column = Eigen::Matrix<double, 12, 1>::Zero();
  Eigen::Matrix<double, 6, 6> gram = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> gram_solver{};
  Eigen::Matrix<double, 6, 1> generalized_load = Eigen::Matrix<double, 6, 1>::Zero();
  // Task inverse workspace.
  Eigen::JacobiSVD<StackTwistJacobian> task_svd{};
  double damping = 0.0;            // ρ of the last task inverse
  double smallest_singular = 0.0;  // σ_min of the last task inverse (scaled J)
};

// Where a configuration's diameter joint may go.
struct DiameterLimits {
  double lower = 0.0;                     // a_min of the linkage
  double upper = 0.0;                     // min(a_max, interference limit)
  double interference = 0.0;              // the interference limit alone (a); +inf when no segment can touch
  bool interference_unavoidable = false;  // even a_min makes disks touch (then upper = lower)
};

enum class VariableDiameterStatus {
  kOk,
  kNonFinite,                // an input or the result was not finite; the state was left unchanged
  kDiameterClamped,          // a was clamped into its limits after the step (a safe state, reported)
  kInterferenceUnavoidable,  // no diameter keeps the disks apart at this ψ_s (a held at a_min)
};

// The robot's state between steps.
struct VariableDiameterState {
  StackConfiguration configuration = StackConfiguration::Zero();  // ψ_s
  double diameter_joint = 0.0;                                    // a (mm)
};

struct VariableDiameterStepReport {
  VariableDiameterStatus status = VariableDiameterStatus::kOk;
  StackJoints joint_velocity = StackJoints::Zero();  // q̃̇ of (2.34), after any clamp
  double force_norm = 0.0;                           // ‖τ̃_s‖ at the state before the step (N)
  double force_gradient = 0.0;  // ∂‖τ̃_s‖/∂a at fixed ψ_s (N/mm), 0 when the diameter is held
  double tracking_error = 0.0;  // ‖p_d − p‖ (mm) before the step
  DiameterLimits limits{};      // at the state before the step
};

class VariableDiameterRobot {
 public:
  // Throws std::invalid_argument naming the parameter when the linkage or the disks are invalid
  // (ScissorLinkage, validate(DiskInterferenceParameters)), a backbone or material value is not
  // positive and finite, the backbone limits are not ordered, or a redundancy or task parameter is
  // negative or not finite.
  explicit VariableDiameterRobot(const VariableDiameterRobotParameters& parameters);

  const VariableDiameterRobotParameters& parameters() const noexcept { return parameters_; }
  const ScissorLinkage& linkage() const noexcept { return linkage_; }
  double bending_stiffness() const noexcept { return bending_stiffness_; }
  VariableDiameterData make_data() const;

  // Tip pose in the base frame; fills data.frames and data.task_jacobian (J_xψs).
  Eigen::Isometry3d tip_pose(const StackConfiguration& psi, VariableDiameterData& data) const noexcept;

  // q̃ at (ψ_s, a): q_k,i = r(a)·Θ_k·cos δ_k,i (2.19) for backbones 1 and 2 of each segment.
  StackJoints joints(const StackConfiguration& psi, double a) const noexcept;
  // A_s (2.33), 6×7.
  Eigen::Matrix<double, 6, 7> augmentation_matrix(const StackConfiguration& psi, double a) const noexcept;
  // J_qψs (2.32), 6×6 block diagonal.
  Eigen::Matrix<double, 6, 6> backbone_jacobian(const StackConfiguration& psi, double a) const noexcept;
  // The unit vector spanning the null space of A_s: n = [c_s; 1]/‖[c_s; 1]‖.
  StackJoints null_space_direction(const StackConfiguration& psi, double a) const noexcept;

  DiameterLimits diameter_limits(const StackConfiguration& psi) const noexcept;

  // τ̃_s (13) at (ψ_s, a) under a tip wrench (base frame). Returns false and zeros when an input is
  // not finite or a is outside the linkage's range.
  bool actuation(const StackConfiguration& psi, double a, const Wrench& wrench, VariableDiameterData& data,
                 StackActuation& out) const noexcept;

  // H of (2.36) and its gradient, with distances to a limit floored at limit_floor.
  double limit_cost(const StackJoints& q, const DiameterLimits& limits, StackJoints* gradient) const noexcept;

  // ψ̇_s = J_xψs^#·twist with the damping law in the header comment (call tip_pose first).
  bool task_inverse(VariableDiameterData& data, const StackTwist& twist,
                    StackConfiguration& rate) const noexcept;

  // One step of length dt of the closed-loop resolved-rate tracker towards `target` (pose) moving with
  // `target_twist`, carrying `wrench`. vary_diameter = true: gradient projection (2.34)–(2.36);
  // false: the fixed-diameter baseline (a held, q̇ = J_qψs·ψ̇_s). State is advanced in place.
  VariableDiameterStepReport step(VariableDiameterState& state, const Eigen::Isometry3d& target,
                                  const StackTwist& target_twist, const Wrench& wrench, double dt,
                                  bool vary_diameter, VariableDiameterData& data) const noexcept;

 private:
  VariableDiameterRobotParameters parameters_;
  ScissorLinkage linkage_;
  double bending_stiffness_ = 0.0;
};

// Pose error [p_d − p; rotation vector of R_d·Rᵀ] (mm, rad), base frame.
StackTwist pose_error(const Eigen::Isometry3d& target, const Eigen::Isometry3d& actual) noexcept;

}  // namespace tendril::teleop
