// Catheter design optimisation (Abah 2022, §4.6.2) and the r_tp/r_seg weight sweep
// (§4.6.1): outer loops that run the shape-error planner (shape_error_planner.hpp) once per design or
// weight pair and score each plan with the design penalty g(χ).
#pragma once

#include <vector>

#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/job_control.hpp"
#include "tendril/teleop/shape_error_planner.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop {

// The design optimiser (§4.6.2). The dissertation minimises g(χ), χ = [L1, L2, δ2], with Nelder–Mead; on
// tortuous vessels g is rugged (every evaluation is a full nested plan whose per-step LM solutions jump
// between local minima), and an unbounded simplex from one start stalled on plateaus of long designs
// (issue 15). tendril searches in three stages, every evaluation a full plan:
//   1. exploration: the start and `exploration_samples` space-filling designs (a Halton sequence over
//      the bounds, lengths log-uniform) so a start on a plateau does not decide the result;
//   2. local search: NLopt's BOBYQA (bounded quadratic-model trust region, derivative-free) from the
//      best explored design, restarted from the best explored design outside the basins searched so
//      far, up to `local_runs` runs; each stops when a step changes χ by less than the tolerances, when
//      g improves by less than relative_penalty_tolerance, or on its evaluation budget;
//   3. the best design is planned once more at the vessel's own spacing (stages 1–2 run on the vessel
//      resampled at search_spacing when that is coarser: g differs by a few per cent, a plan costs half).
// With free_flexure, stages 1–3 first optimise the design without flexure (γ held at the start's
// value); its optimum then seeds a BOBYQA run with γ free. The flexure design space contains the
// design without it (γ may stay at its value at every step), so a flexure design must never be worse:
// the best flexure designs of that run (up to three, lowest g first) are planned at the vessel's
// spacing and the first that is no worse than the subset optimum in g and in the mean and maximum
// position and tip errors is the result; if none is, the subset plan is returned with γ held (the
// planner's per-step LM with γ free can end in a worse local minimum than with γ held at the same χ,
// so this is needed, not only cautious). The best design seen is always kept.
struct DesignOptimiserOptions {
  int max_evaluations = 90;          // hard cap on planner runs over all stages (≥ 4)
  int exploration_samples = 10;      // stage 1, besides the start (≥ 0)
  int local_runs = 2;                // stage 2: BOBYQA runs, the first and its restarts (≥ 1)
  int local_evaluations = 24;        // planner runs per BOBYQA run (≥ 8: BOBYQA's 2n+1 model points + 1)
  int flexure_evaluations = 20;      // the BOBYQA run with γ free (free_flexure only; ≥ 8)
  double search_spacing = 1.0;       // mm, ds of stages 1–2 (0: the vessel's own)
  double initial_step_length = 4.0;  // mm, first trust-region radius for L1 and L2
  double initial_step_angle = 0.4;   // rad, first trust-region radius for δ2
  double length_tolerance = 0.1;     // mm: a local run stops when no step changes L by more
  double angle_tolerance = 0.01;     // rad: … nor δ2 by more
  double relative_penalty_tolerance = 1e-3;  // … or when a step improves g by less than this fraction
  // mm, bounds for L1 and L2. With the passive shaft conforming to the vessel (the placement
  // convention of shape_error_planner.hpp), g(χ) keeps falling as the segments shorten (a short
  // section fits any curve), so the optimum sits on the lower bound. 5 mm is below every design in the
  // source (smallest 6.6 mm) and long enough for a notched NiTi segment to reach its ~80° bend. δ2 is
  // searched over one turn centred on the start's (it is periodic).
  double min_length = 5.0;
  double max_length = 60.0;
};

// Why the last local search of the optimisation stopped.
enum class DesignStopReason {
  step_tolerance,     // converged: a step changed χ by less than the tolerances
  penalty_tolerance,  // converged: a step improved g by less than relative_penalty_tolerance
  evaluation_budget,  // local_evaluations / flexure_evaluations or max_evaluations used up
  roundoff,           // BOBYQA could not progress further at machine precision (converged)
  no_local_search,    // the budget ran out in exploration
};
const char* to_string(DesignStopReason reason) noexcept;

// How the search went, for the API and console (penalties are g at the vessel's own spacing unless
// said otherwise).
struct DesignConvergence {
  DesignStopReason stop_reason = DesignStopReason::no_local_search;
  bool converged = false;         // the last local search stopped on a tolerance, not on a budget
  int local_runs = 0;             // BOBYQA runs made (the flexure run included)
  int search_evaluations = 0;     // planner runs at search_spacing (stages 1–2)
  double search_spacing = 0.0;    // mm, ds used in stages 1–2
  double explored_penalty = 0.0;  // best g after exploration (at search_spacing)
  // free_flexure: g of the best design without flexure (the seed of the flexure search) and whether
  // a plan with γ free improved on it without worsening any error (false: the subset plan with γ held
  // is the result). NaN/false otherwise.
  double subset_penalty = 0.0;
  bool flexure_improved = false;
  std::vector<double> best_penalty_history;  // best g seen after each planner run (search spacing)
};

struct DesignResult {
  CatheterParameters design;     // χ* in proximal_length, distal_length, plane_offset (wrapped to ±π)
  bool flexure = false;          // optimised with γ free allowed (planner_options.free_flexure)
  double penalty = 0.0;          // g(χ*) of §4.6.2, at the vessel's spacing
  double initial_penalty = 0.0;  // g at the starting design, at the vessel's spacing
  int evaluations = 0;           // planner runs in total (all stages)
  // Tip error of the plan: distance from each step's planned tip to the vessel centerline at the
  // inserted length q1, mean and max over the steps (mm).
  double tip_error_mean = 0.0;
  double tip_error_max = 0.0;
  DesignConvergence convergence;
  PathPlan plan;  // the plan of χ* at the vessel's spacing (plan.free_flexure: γ solved)
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

// g(χ) = (max δp + mean δp)/δ_p,range + (max δt + mean δt)/δ_t,range over the whole plan (§4.6.2).
double design_penalty(const PathPlan& plan, const ShapeErrorPlannerOptions& options);

// Optimises χ = [L1, L2, δ2] from `start` (its other parameters, gains and γ, are kept) as described
// above. Throws PlannerOptionsError on bad options (counts below their minimum, non-finite or
// non-positive steps, tolerances or spacing, an empty length interval, a start outside it), the
// planner's errors for bad planner options or a too-short vessel. Deterministic.
DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options = {});
// Same, reporting progress (planner runs done / max_evaluations, 1 at the end) after every planner run
// and checking for cancellation before every run and every insertion step (throws OperationCancelled).
DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options, const JobControl& job);

}  // namespace tendril::teleop
