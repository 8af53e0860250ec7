// Pre-operative path planner by shape-error minimisation (seed 000 §4.8, eqs. 4.16–4.20, §11.2). The
// design optimiser of §4.9 and the weight sweep of §4.6.1, which run it in a loop, are in
// design_optimiser.hpp.
//
// Placement convention (the seed leaves it open, §4.8 [GAP]): q1 is the inserted length of the tip
// along the vessel. The vessel is moved so its start is the insertion point with initial tangent +z.
// The steerable section's base sits on the centerline at arc length s_b = q1 − (L1 + L2), oriented by
// a rotation-minimising (parallel-transport) frame started at the identity, with the passive shaft
// assumed to conform to the vessel. While s_b < 0 the base is still outside, on the straight
// extension (0, 0, s_b). The roll q2 is measured from that transported frame, which (unlike the
// α/β frame of eq. 4.3) stays continuous when the tangent passes through ±z.
//
// Points: vessel samples s_i ≤ q1 (n = floor(q1/ds) + 1 including s = 0) on the steerable section,
// s_i ≥ s_b, are compared with the catheter at the same arc length; samples behind the base lie on
// the non-steerable lumen and have zero weight (eq. 4.18). Weights follow eq. 4.20 with v_k/n_k taken
// as σ/L_k (the position along segment k), which equals v_k/n_k when the segment is fully inside.
// Tangent residuals use the chord t̂ − t̂_c (|t̂ − t̂_c| = 2 sin(δt/2) = δt + O(δt³)) because arccos is
// not differentiable at zero; reported tangent errors use the exact angle.
//
// Passive flexure (§4.3, §4.10 [GAP]): its stiffness is not given, so a design "with flexure" solves
// γ per step as a fourth free variable next to [q2, q3, q4], bounded by flexure_min/max; without it γ
// stays at the model's CatheterParameters::flexure.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <stdexcept>
#include <vector>

#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/job_control.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop {

class PlannerOptionsError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

struct ShapeErrorPlannerOptions {
  double insertion_step = 3.0;              // dq1 (mm)
  double position_error_range = 10.0;       // δ_p,range (mm), eq. 4.18
  double tangent_error_range = 1.0;         // δ_t,range (rad)
  double tangent_to_position_ratio = 0.75;  // r_tp
  double proximal_to_distal_ratio = 1.0;    // r_seg, eq. 4.19
  double proximal_drive_min = -6.0;         // q3 limits (mm)
  double proximal_drive_max = 10.0;
  double distal_drive_min = -5.0;  // q4 limits (mm)
  double distal_drive_max = 5.0;
  bool warm_start = true;                  // start each step from the previous solution
  int max_iterations = 200;                // LM trial steps per insertion step
  double initial_damping = 1e-3;           // λ₀ (relative to diag(JᵀJ))
  double relative_cost_tolerance = 1e-12;  // stop when an accepted step improves less than this
  double step_tolerance = 1e-10;           // stop when |Δx|∞ is below this
  // Design with a passive flexure between the segments: γ is solved per step within these limits.
  // ±60° is chosen here (the seed gives no range): beyond it the joint would kink the lumen.
  bool free_flexure = false;
  double flexure_min = -1.0471975511965976;  // rad
  double flexure_max = 1.0471975511965976;
};

// Nominal model of the planning study: tip-only placeholder gain k = 1.4 rad/mm, ad hoc design
// χ = [22 mm, 18.8 mm, −0.76 rad] (§4.10, case ①).
CatheterParameters nominal_planning_design();

struct PlanStep {
  ConstantCurvatureCatheter::JointVector q;  // [q1 (mm), q2 (rad), q3 (mm), q4 (mm)]
  double flexure = 0.0;                      // γ (rad): solved when free_flexure, else the design's
  std::size_t points = 0;                    // vessel samples on the inserted steerable section
  double position_error_mean = 0.0;          // mm
  double position_error_max = 0.0;           // mm
  double tangent_error_mean = 0.0;           // deg
  double tangent_error_max = 0.0;            // deg
  double cost = 0.0;                         // eq. 4.17 at the solution
  int iterations = 0;                        // LM trial steps taken
  // Where the planned steerable section sits, in the frame of the vessel as given to plan() (not
  // the insertion-aligned frame): base position and rotation (columns x, y, z; z = base tangent), and
  // the design with γ = flexure. Enough for planned_backbone() without the planner.
  Eigen::Matrix3d base_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d base_position = Eigen::Vector3d::Zero();
  CatheterParameters design;
};

struct PathPlan {
  CatheterParameters design;  // the model planned with (flexure = its fixed γ when not free)
  bool free_flexure = false;  // γ solved per step (design with passive flexure)
  std::vector<PlanStep> steps;
  double position_error_mean = 0.0;  // over all compared points of all steps (mm)
  double position_error_max = 0.0;
  double tangent_error_mean = 0.0;  // deg
  double tangent_error_max = 0.0;
  int total_iterations = 0;
};

class ShapeErrorPlanner {
 public:
  using JointVector = ConstantCurvatureCatheter::JointVector;

  // Throws PlannerOptionsError when an option is not finite, not positive where it must be, or a
  // limit interval is empty or excludes 0 (the straight catheter must be reachable).
  ShapeErrorPlanner(const ConstantCurvatureCatheter& model, const ShapeErrorPlannerOptions& options);

  const ShapeErrorPlannerOptions& options() const noexcept { return options_; }

  // Plans q1 = dq1, 2·dq1, … ≤ vessel length. The vessel is aligned to the insertion frame first.
  // The result depends only on (model, vessel, options); scratch buffers are sized once per call.
  // Throws VesselInputError if the vessel is shorter than one insertion step.
  PathPlan plan(const VesselCenterline& vessel);
  // Same, reporting progress (fraction of insertion steps done) and checking for cancellation before
  // every step (throws OperationCancelled).
  PathPlan plan(const VesselCenterline& vessel, const JobControl& job);

  // Point (and unit tangent) at arc length sigma ∈ [0, L1 + L2] along the steerable section, in the
  // model's frame {0} with the base at (0, 0, q1): the same closed form as
  // ConstantCurvatureCatheter::backbone, but at any arc length.
  Eigen::Vector3d steerable_point(const JointVector& q, double sigma,
                                  Eigen::Vector3d* tangent) const noexcept;

 private:
  struct Base {
    Eigen::Matrix3d rotation;
    Eigen::Vector3d position;
  };
  void build_transport_frames(const VesselCenterline& aligned);
  Base base_frame(const VesselCenterline& aligned, double arc_length) const noexcept;
  // x = [q2, q3, q4, γ]; γ is held fixed unless options_.free_flexure.
  double evaluate(const Eigen::Vector4d& x, Eigen::VectorXd& residual) const noexcept;
  PlanStep solve_step(const VesselCenterline& aligned, double q1, const Eigen::Vector4d& start);

  ConstantCurvatureCatheter model_;
  ShapeErrorPlannerOptions options_;
  Eigen::Vector4d lower_, upper_;

  // Per-plan scratch, sized in plan().
  std::vector<Eigen::Matrix3d> transport_;
  std::vector<Eigen::Vector3d> targets_, target_tangents_;
  std::vector<double> sigmas_, weights_;
  std::size_t active_ = 0;
  Base base_{};
  Eigen::Matrix3d from_aligned_ = Eigen::Matrix3d::Identity();  // vessel frame → insertion frame
  Eigen::Vector3d aligned_offset_ = Eigen::Vector3d::Zero();
  Eigen::VectorXd residual_, trial_residual_, plus_, minus_;
  Eigen::MatrixXd jacobian_;
};

// Backbone of a planned step's steerable section (base to tip) in the vessel's frame, a point every
// `spacing` mm of arc length plus the tip. Throws PlannerOptionsError unless 0.01 mm ≤ spacing.
std::vector<Eigen::Vector3d> planned_backbone(const PlanStep& step, double spacing);

}  // namespace tendril::teleop
