// Catheter design optimisation (seed 000 §4.9, diss. §4.6.2) and the r_tp/r_seg weight sweep
// (§4.6.1): outer loops that run the shape-error planner (shape_error_planner.hpp) once per design or
// weight pair and score each plan with the design penalty g(χ).
#pragma once

#include <vector>

#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/job_control.hpp"
#include "tendril/teleop/shape_error_planner.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop {

struct DesignOptimiserOptions {
  int max_evaluations = 60;          // planner runs (each a full plan)
  double initial_step_length = 4.0;  // mm, simplex size for L1 and L2
  double initial_step_angle = 0.4;   // rad, simplex size for δ2
  // mm, lower bound for L1 and L2. With the passive shaft conforming to the vessel (the placement
  // convention above), g(χ) keeps falling as the segments shorten (a short section fits any curve), so
  // the optimum sits on this bound. 5 mm is below every design in the source (smallest 6.6 mm) and
  // long enough for a notched NiTi segment to reach its ~80° bend.
  double min_length = 5.0;
  double max_length = 60.0;
};

struct DesignResult {
  CatheterParameters design;     // χ* in proximal_length, distal_length, plane_offset
  bool flexure = false;          // planned with γ free (planner_options.free_flexure)
  double penalty = 0.0;          // g(χ) of §4.9
  double initial_penalty = 0.0;  // g at the starting design
  int evaluations = 0;
  PathPlan plan;
};

// One planner run of the §4.6.1 weight grid.
struct WeightSweepPoint {
  double tangent_to_position_ratio = 0.0;  // r_tp
  double proximal_to_distal_ratio = 0.0;   // r_seg
  double penalty = 0.0;                    // g of the resulting plan (weight-independent, comparable)
  double position_error_mean = 0.0, position_error_max = 0.0;  // mm
  double tangent_error_mean = 0.0, tangent_error_max = 0.0;    // deg
};

struct WeightSweepResult {
  std::vector<WeightSweepPoint> grid;  // r_tp-major: grid[i·|r_seg| + j]
  WeightSweepPoint best;               // lowest penalty (first on ties)
};

// Weight selection of §4.6.1: plans the vessel with every (r_tp, r_seg) pair (the source uses a 0–10
// grid for both) and picks the pair with the lowest g. Other options come from planner_options.
// Throws PlannerOptionsError on an empty or negative/non-finite value list; progress per plan.
WeightSweepResult sweep_weights(const CatheterParameters& design, const VesselCenterline& vessel,
                                const ShapeErrorPlannerOptions& planner_options,
                                const std::vector<double>& tangent_to_position_ratios,
                                const std::vector<double>& proximal_to_distal_ratios,
                                const JobControl& job = {});

// g(χ) = (max δp + mean δp)/δ_p,range + (max δt + mean δt)/δ_t,range over the whole plan (§4.9).
double design_penalty(const PathPlan& plan, const ShapeErrorPlannerOptions& options);

// Nelder–Mead over χ = [L1, L2, δ2] starting from `start`, each evaluation a full plan (§4.9).
DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options = {});
// Same, reporting progress (evaluations done / max_evaluations) and checking for cancellation before
// every evaluation and every insertion step (throws OperationCancelled).
DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options, const JobControl& job);

}  // namespace tendril::teleop
