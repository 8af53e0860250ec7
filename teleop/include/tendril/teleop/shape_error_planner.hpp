// Pre-operative path planner by shape-error minimisation (Abah 2022, §4.6.1, eqs. 4.16–4.20). The
// design optimiser of §4.6.2 and the weight sweep of §4.6.1, which run it in a loop, are in
// design_optimiser.hpp.
//
// Placement convention (the dissertation leaves it open): q1 is the inserted length of the tip
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
// Passive flexure (§4.4.1, §4.6.3): its stiffness is not given, so a design "with flexure" solves
// γ per step as a fourth free variable next to [q2, q3, q4], bounded by flexure_min/max; without it γ
// stays at the model's CatheterParameters::flexure.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>
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
  bool warm_start = true;         // start each step from the previous solution
  int max_iterations = 200;       // LM trial steps per insertion step
  double initial_damping = 1e-3;  // λ₀ (relative to diag(JᵀJ))
  // Stop when an accepted step improves the cost by less than this fraction. 1e-9 (was 1e-12): the
  // last iterations before it changed no step's cost by more than 1e-8 of itself on the benchmark
  // vessels, and took a fifth of the iterations.
  double relative_cost_tolerance = 1e-9;
  double step_tolerance = 1e-10;  // stop when |Δx|∞ is below this
  // Design with a passive flexure between the segments: γ is solved per step within these limits.
  // ±60° is chosen here (the dissertation gives no range): beyond it the joint would kink the lumen.
  bool free_flexure = false;
  double flexure_min = -1.0471975511965976;  // rad
  double flexure_max = 1.0471975511965976;
};

// Nominal model of the planning study: tip-only placeholder gain k = 1.4 rad/mm, ad hoc design
// χ = [22 mm, 18.8 mm, −0.76 rad] (§4.6.3, case ①).
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
  // x = [q2 (rad), q3 (mm), q4 (mm), γ (rad)]: the unknowns of one insertion step.
  using StepVector = Eigen::Vector4d;

  // Scratch for one insertion step: the vessel samples on the steerable section, expressed in the
  // section's base frame (so the fit needs no rotation per point), their √weights and arc lengths σ
  // along the section. Sized once by make_workspace(); the per-step functions write only into it.
  struct StepWorkspace {
    std::vector<double> sigma, sqrt_weight;
    std::vector<Eigen::Vector3d> target, target_tangent;
    std::size_t count = 0;
    double insertion = 0.0;                                       // q1 of the loaded step (mm)
    Eigen::Matrix3d base_rotation = Eigen::Matrix3d::Identity();  // insertion frame
    Eigen::Vector3d base_position = Eigen::Vector3d::Zero();
  };

  // Throws PlannerOptionsError when an option is not finite, not positive where it must be, or a
  // limit interval is empty or excludes 0 (the straight catheter must be reachable).
  ShapeErrorPlanner(const ConstantCurvatureCatheter& model, const ShapeErrorPlannerOptions& options);

  const ShapeErrorPlannerOptions& options() const noexcept { return options_; }
  const ConstantCurvatureCatheter& model() const noexcept { return model_; }

  // Plans q1 = dq1, 2·dq1, … ≤ vessel length. The vessel is aligned to the insertion frame first.
  // The result depends only on (model, vessel, options); scratch buffers are sized once per call.
  // Throws VesselInputError if the vessel is shorter than one insertion step.
  PathPlan plan(const VesselCenterline& vessel);
  // Same, reporting progress (fraction of insertion steps done) and checking for cancellation before
  // every step (throws OperationCancelled).
  PathPlan plan(const VesselCenterline& vessel, const JobControl& job);

  // Step-wise use (live replanning, benchmarks, tests). prepare() aligns the vessel to the insertion
  // frame and builds its transport frames (allocates; plan() calls it too); afterwards every function
  // below is const, noexcept and allocation-free given a workspace from make_workspace().
  // Throws VesselInputError if the vessel is shorter than one insertion step.
  void prepare(const VesselCenterline& vessel);
  bool prepared() const noexcept { return !transport_.empty(); }
  // The prepared vessel in the insertion frame (start at the origin, initial tangent +z).
  const VesselCenterline& prepared_vessel() const noexcept { return *aligned_; }
  StepWorkspace make_workspace() const;
  // Pose of the steerable section's base (rotation columns x, y, z = tangent) for the tip at inserted
  // arc length q1, in the insertion frame: on the centerline at q1 − (L1 + L2), or on the straight
  // extension before the vessel start.
  void section_base(double q1, Eigen::Matrix3d& rotation, Eigen::Vector3d& position) const noexcept;
  // Loads the samples of insertion step q1 into ws. `shape_offset` (section base frame, mm) is added
  // to the model's shape in proportion to σ/(L1 + L2) — zero at the base, all of it at the tip — so a
  // measured tip offset can be corrected (ImageGuidedReplanner); zero for the pre-operative plan.
  void load_step(double q1, const Eigen::Vector3d& shape_offset, StepWorkspace& ws) const noexcept;
  // Levenberg–Marquardt on the loaded step from `start` (and four bent starts, see the .cpp). The
  // step's errors are measured against the loaded targets, i.e. for the offset shape when an offset
  // was given. With no points loaded (before prepare()) the step is `start` unchanged.
  void solve_loaded(const StepWorkspace& ws, const StepVector& start, PlanStep& out) const noexcept;

  // Eq. 4.17 at x for the loaded step: Σ of squared residuals, 6 per point (√w·δp, √(w·r_tp/δt)·(t̂ − t̂_c)).
  double cost(const StepWorkspace& ws, const StepVector& x) const noexcept;
  // The same plus the Gauss–Newton normal equations JᵀJ and Jᵀr from the analytic Jacobian.
  double normal_equations(const StepWorkspace& ws, const StepVector& x, Eigen::Matrix4d& jtj,
                          Eigen::Vector4d& jtr) const noexcept;
  // Residuals (6·ws.count rows) and analytic Jacobian ∂r/∂x (6·ws.count × 4) for inspection and tests.
  // Returns false (writing nothing) when r or J has the wrong size.
  bool residuals(const StepWorkspace& ws, const StepVector& x, Eigen::Ref<Eigen::VectorXd> r,
                 Eigen::Ref<Eigen::Matrix<double, Eigen::Dynamic, 4>> jacobian) const noexcept;

  // Point (and unit tangent) at arc length sigma ∈ [0, L1 + L2] along the steerable section, in the
  // model's frame {0} with the base at (0, 0, q1): the same closed form as
  // ConstantCurvatureCatheter::backbone, but at any arc length.
  Eigen::Vector3d steerable_point(const JointVector& q, double sigma,
                                  Eigen::Vector3d* tangent) const noexcept;

 private:
  void build_transport_frames();

  ConstantCurvatureCatheter model_;
  ShapeErrorPlannerOptions options_;
  Eigen::Vector4d lower_, upper_;
  double tangent_factor_sqrt_ = 0.0;  // √(r_tp/δt,range)

  // Set by prepare().
  std::optional<VesselCenterline> aligned_;
  std::vector<Eigen::Matrix3d> transport_;
  Eigen::Matrix3d from_aligned_ = Eigen::Matrix3d::Identity();  // vessel frame → insertion frame
  Eigen::Vector3d aligned_offset_ = Eigen::Vector3d::Zero();
};

// Backbone of a planned step's steerable section (base to tip) in the vessel's frame, a point every
// `spacing` mm of arc length plus the tip. Throws PlannerOptionsError unless 0.01 mm ≤ spacing.
std::vector<Eigen::Vector3d> planned_backbone(const PlanStep& step, double spacing);

}  // namespace tendril::teleop
