// Live replanning from image feedback: the high-level controller of Abah 2022, §4.11 (HLC:
// "position feedback from real-time bi-plane segmentation, plus path-plan predictions based on the
// measured insertion depth"). The dissertation gives no algorithm; this one is chosen here:
//
//  1. From the measured insertion s (arc length of the tip inside the vessel) and the configuration
//     ψ the robot was last sent, the planner's model predicts where the tip should be. The measured
//     tip minus that prediction, expressed in the steerable section's base frame, is the model error
//     at the tip (unmodelled losses, stiffness, lengths). It is low-pass filtered (gain
//     `tip_error_gain` per measurement) and capped at `max_tip_correction`.
//  2. The next target is one insertion step ahead of where the tip is: s + dq1 (the vessel end at
//     most). The shape-error step of §4.6.1 (eqs. 4.16–4.20) is solved there, warm-started from the
//     previous solution, with the filtered error added to the model's shape in proportion to σ/(L1+L2)
//     (none at the base, all of it at the tip): the solver then places the corrected shape, i.e. the
//     real catheter, on the vessel.
//  3. The result is a configuration-space target ψ = [q1, q2, θ_L1, θ_L2] for the configuration mode
//     (θ_Li = k_i·q_i, the planning model's bend angles), its insertion advanced by the same step from
//     the commanded one (so insertion slack does not accumulate into the shape), the roll unwrapped to
//     the one nearest the commanded roll; when every bend of the solution is under roll_hold_bend, the
//     commanded roll itself, with the bends projected onto its planes (a straight catheter has no roll
//     to follow).
//
// Model/data split: ImageGuidedReplanner is immutable after construction (the catheter model, the
// planner's options and the prepared vessel); ReplannerState holds the preallocated workspace, the
// warm start and the filtered tip error. replan() is const, noexcept and does not allocate.
#pragma once

#include <Eigen/Core>

#include "tendril/teleop/shape_error_planner.hpp"

namespace tendril::teleop {

struct ImageGuidedReplannerOptions {
  double tip_error_gain = 0.5;       // fraction of a new tip-error measurement taken into the estimate
  double max_tip_correction = 5.0;   // mm: cap on the estimated tip error (an implausible fix is bounded)
  double max_tip_innovation = 15.0;  // mm: a measured tip this far from the prediction is refused
  // rad: a solution whose bends are all smaller than this keeps the commanded roll (its bends projected
  // onto that roll's planes). A nearly straight catheter's roll is undetermined: the solver's roll then
  // follows the image noise from frame to frame (measured: jumps of up to ±3 rad every frame along a
  // straight vessel), and the roll drive swings for nothing. 0.05 rad (≈ 3°) is above the bends that
  // noise produced there (≤ 0.02 rad) and below those of a vessel's bends. Hysteresis: once held, the
  // roll follows the solver again only when a bend reaches twice this (else the target roll alternated
  // between the held one and the solver's from frame to frame as the bends grew through 0.05 rad).
  double roll_hold_bend = 0.05;
};

enum class ReplanStatus {
  kOk,
  kNotFinite,            // a measured or commanded value is NaN or infinite
  kInsertionOutOfRange,  // measured insertion < 0 or beyond the vessel
  kTipOutlier,           // measured tip further than max_tip_innovation from the prediction
};

// What the image and the robot say, in the planner's insertion frame (vessel start at the origin,
// initial tangent +z; mm, rad).
struct ReplanInput {
  Eigen::Vector3d measured_tip = Eigen::Vector3d::Zero();
  double measured_insertion = 0.0;  // arc length of the tip inside the vessel (mm)
  // ψ last sent to the configuration mode: [insertion command (mm), roll (rad), θ_L1, θ_L2 (rad)].
  Eigen::Vector4d commanded_configuration = Eigen::Vector4d::Zero();
};

struct ReplanResult {
  ReplanStatus status = ReplanStatus::kOk;
  Eigen::Vector4d configuration = Eigen::Vector4d::Zero();  // next ψ target for the configuration mode
  PlanStep step;                  // the solved step (q in the planning model's joints, at s + dq1)
  double target_insertion = 0.0;  // arc length the tip is planned to reach (mm)
  Eigen::Vector3d predicted_tip = Eigen::Vector3d::Zero();  // model tip at the measurement (insertion frame)
  Eigen::Vector3d tip_error = Eigen::Vector3d::Zero();      // filtered error used (section base frame)
};

struct ReplannerState {
  ShapeErrorPlanner::StepWorkspace workspace;
  ShapeErrorPlanner::StepVector warm_start = ShapeErrorPlanner::StepVector::Zero();
  Eigen::Vector3d tip_error = Eigen::Vector3d::Zero();  // filtered, section base frame (mm)
  bool roll_held = true;  // the last target kept the commanded roll (nearly straight; a run starts so)
  int replans = 0;
};

class ImageGuidedReplanner {
 public:
  // Prepares the vessel (any frame; it is aligned to the insertion frame like ShapeErrorPlanner::plan).
  // Throws PlannerOptionsError / VesselInputError as ShapeErrorPlanner does, and PlannerOptionsError
  // for a gain outside (0, 1] or a non-positive cap.
  ImageGuidedReplanner(const ConstantCurvatureCatheter& model,
                       const ShapeErrorPlannerOptions& planner_options, const VesselCenterline& vessel,
                       const ImageGuidedReplannerOptions& options = {});

  // A state for one catheter run: workspace sized for the vessel (allocates), warm start straight
  // (or the design's flexure), no tip error yet.
  ReplannerState make_state() const;

  // One replan (see the top of the file). On an error status nothing in `state` changes and `out`
  // keeps only the status. Allocation-free.
  ReplanResult replan(ReplannerState& state, const ReplanInput& input) const noexcept;

  // Model tip for configuration ψ with the tip at arc length `insertion` (insertion frame; the design's
  // flexure γ).
  Eigen::Vector3d predicted_tip(const Eigen::Vector4d& configuration, double insertion) const noexcept;

  const ShapeErrorPlanner& planner() const noexcept { return planner_; }
  double vessel_length() const noexcept { return planner_.prepared_vessel().length(); }

 private:
  ShapeErrorPlanner planner_;  // prepared; only its const step functions are used
  ImageGuidedReplannerOptions options_;
};

}  // namespace tendril::teleop
