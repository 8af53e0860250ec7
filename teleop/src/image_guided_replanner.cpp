#include "tendril/teleop/image_guided_replanner.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace tendril::teleop {

ImageGuidedReplanner::ImageGuidedReplanner(const ConstantCurvatureCatheter& model,
                                           const ShapeErrorPlannerOptions& planner_options,
                                           const VesselCenterline& vessel,
                                           const ImageGuidedReplannerOptions& options)
    : planner_(model, planner_options), options_(options) {
  const auto& o = options;
  if (!(std::isfinite(o.tip_error_gain) && o.tip_error_gain > 0.0 && o.tip_error_gain <= 1.0)) {
    throw PlannerOptionsError("ImageGuidedReplanner: tip_error_gain must be in (0, 1]");
  }
  if (!(std::isfinite(o.max_tip_correction) && o.max_tip_correction > 0.0) ||
      !(std::isfinite(o.max_tip_innovation) && o.max_tip_innovation > 0.0)) {
    throw PlannerOptionsError(
        "ImageGuidedReplanner: max_tip_correction and max_tip_innovation must be > 0 mm");
  }
  if (!(std::isfinite(o.roll_hold_bend) && o.roll_hold_bend >= 0.0)) {
    throw PlannerOptionsError("ImageGuidedReplanner: roll_hold_bend must be a finite angle ≥ 0 rad");
  }
  const auto& P = model.parameters();
  if (P.proximal_curvature_gain == 0.0 || P.distal_curvature_gain == 0.0) {
    throw PlannerOptionsError(
        "ImageGuidedReplanner: the bend gains k1, k2 must be non-zero (configuration targets are k·q)");
  }
  planner_.prepare(vessel);
}

ReplannerState ImageGuidedReplanner::make_state() const {
  ReplannerState state;
  state.workspace = planner_.make_workspace();
  state.warm_start = {0.0, 0.0, 0.0, planner_.model().parameters().flexure};
  return state;
}

Eigen::Vector3d ImageGuidedReplanner::predicted_tip(const Eigen::Vector4d& configuration,
                                                    double insertion) const noexcept {
  const auto& P = planner_.model().parameters();
  const ShapeErrorPlanner::JointVector q(0.0, configuration[1], configuration[2] / P.proximal_curvature_gain,
                                         configuration[3] / P.distal_curvature_gain);
  Eigen::Matrix3d rotation;
  Eigen::Vector3d position;
  planner_.section_base(insertion, rotation, position);
  return rotation * planner_.steerable_point(q, P.proximal_length + P.distal_length, nullptr) + position;
}

ReplanResult ImageGuidedReplanner::replan(ReplannerState& state, const ReplanInput& input) const noexcept {
  ReplanResult out;
  if (!input.measured_tip.allFinite() || !std::isfinite(input.measured_insertion) ||
      !input.commanded_configuration.allFinite()) {
    out.status = ReplanStatus::kNotFinite;
    return out;
  }
  const double length = vessel_length();
  if (input.measured_insertion < 0.0 || input.measured_insertion > length + 1e-9) {
    out.status = ReplanStatus::kInsertionOutOfRange;
    return out;
  }
  const Eigen::Vector4d& commanded = input.commanded_configuration;
  out.predicted_tip = predicted_tip(commanded, input.measured_insertion);
  const Eigen::Vector3d innovation = input.measured_tip - out.predicted_tip;
  if (innovation.norm() > options_.max_tip_innovation) {
    out.status = ReplanStatus::kTipOutlier;
    return out;
  }
  Eigen::Matrix3d base_rotation;
  Eigen::Vector3d base_position;
  planner_.section_base(input.measured_insertion, base_rotation, base_position);
  // The error is kept in the section's base frame, which follows the vessel, so it carries over to the
  // next step's base (3 mm further on) with the shape it belongs to.
  Eigen::Vector3d tip_error =
      state.tip_error + options_.tip_error_gain * (base_rotation.transpose() * innovation - state.tip_error);
  const double norm = tip_error.norm();
  if (norm > options_.max_tip_correction) tip_error *= options_.max_tip_correction / norm;

  const double advance = std::min(planner_.options().insertion_step, length - input.measured_insertion);
  out.target_insertion = input.measured_insertion + advance;
  planner_.load_step(out.target_insertion, tip_error, state.workspace);
  planner_.solve_loaded(state.workspace, state.warm_start, out.step);

  const auto& P = planner_.model().parameters();
  // The roll nearest the commanded one, so a wrap at ±π does not send the catheter round a full turn.
  double roll = commanded[1] + std::remainder(out.step.q[1] - commanded[1], 2.0 * std::numbers::pi);
  double q2 = out.step.q[2], q3 = out.step.q[3];
  const double bend1 = P.proximal_curvature_gain * q2, bend2 = P.distal_curvature_gain * q3;
  const double largest = std::max(std::abs(bend1), std::abs(bend2));
  const bool hold =
      state.roll_held ? largest < 2.0 * options_.roll_hold_bend : largest < options_.roll_hold_bend;
  if (hold) {
    // Nearly straight: keep the commanded roll; both bend planes turn with the roll, so each bend's
    // component in the commanded planes is its cosine share.
    const double share = std::cos(roll - commanded[1]);
    q2 *= share;
    q3 *= share;
    roll = commanded[1];
  }
  out.configuration = {commanded[0] + advance, roll, P.proximal_curvature_gain * q2,
                       P.distal_curvature_gain * q3};
  out.tip_error = tip_error;
  state.warm_start = {roll, q2, q3, out.step.flexure};
  state.roll_held = hold;
  state.tip_error = tip_error;
  ++state.replans;
  return out;
}

}  // namespace tendril::teleop
