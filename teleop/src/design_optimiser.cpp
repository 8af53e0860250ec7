#include "tendril/teleop/design_optimiser.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>
#include <utility>

#include <nlopt.h>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;

double wrap_angle(double a) noexcept { return std::remainder(a, 2.0 * kPi); }

}  // namespace

double design_penalty(const PathPlan& plan, const ShapeErrorPlannerOptions& options) {
  constexpr double kDegToRad = kPi / 180.0;
  return (plan.position_error_max + plan.position_error_mean) / options.position_error_range +
         kDegToRad * (plan.tangent_error_max + plan.tangent_error_mean) / options.tangent_error_range;
}

WeightSweepResult sweep_weights(const CatheterParameters& design, const VesselCenterline& vessel,
                                const ShapeErrorPlannerOptions& planner_options,
                                const std::vector<double>& tangent_to_position_ratios,
                                const std::vector<double>& proximal_to_distal_ratios, const JobControl& job) {
  auto valid = [](const std::vector<double>& values) {
    return !values.empty() &&
           std::all_of(values.begin(), values.end(), [](double v) { return std::isfinite(v) && v >= 0.0; });
  };
  if (!valid(tangent_to_position_ratios) || !valid(proximal_to_distal_ratios)) {
    throw PlannerOptionsError("sweep_weights: r_tp and r_seg lists must be non-empty, finite and >= 0");
  }
  const ConstantCurvatureCatheter model(design);
  const JobControl cancel_only{{}, job.cancel};
  WeightSweepResult result;
  const double total =
      static_cast<double>(tangent_to_position_ratios.size() * proximal_to_distal_ratios.size());
  for (const double r_tp : tangent_to_position_ratios) {
    for (const double r_seg : proximal_to_distal_ratios) {
      job.check_cancelled();
      ShapeErrorPlannerOptions options = planner_options;
      options.tangent_to_position_ratio = r_tp;
      options.proximal_to_distal_ratio = r_seg;
      const PathPlan plan = ShapeErrorPlanner(model, options).plan(vessel, cancel_only);
      WeightSweepPoint point{r_tp,
                             r_seg,
                             design_penalty(plan, options),
                             plan.position_error_mean,
                             plan.position_error_max,
                             plan.tangent_error_mean,
                             plan.tangent_error_max};
      if (result.grid.empty() || point.penalty < result.best.penalty) result.best = point;
      result.grid.push_back(point);
      job.report(static_cast<double>(result.grid.size()) / total);
    }
  }
  return result;
}

const char* to_string(DesignStopReason reason) noexcept {
  switch (reason) {
    case DesignStopReason::step_tolerance:
      return "converged: the last step changed the design by less than the tolerances";
    case DesignStopReason::penalty_tolerance:
      return "converged: the last step improved the penalty by less than the relative tolerance";
    case DesignStopReason::evaluation_budget:
      return "stopped on the evaluation budget before converging";
    case DesignStopReason::roundoff:
      return "converged: no further progress at machine precision";
    case DesignStopReason::no_local_search:
      return "stopped on the evaluation budget during exploration (no local search ran)";
  }
  return "unknown";
}

namespace {

using Design = Eigen::Vector3d;  // χ = [L1 (mm), L2 (mm), δ2 (rad)]

// Halton radical inverse: a deterministic low-discrepancy sequence, so the exploration covers the box
// evenly without a random seed.
double radical_inverse(int index, int base) {
  double result = 0.0, scale = 1.0 / base;
  for (int i = index; i > 0; i /= base, scale /= base) result += scale * (i % base);
  return result;
}

VesselCenterline resampled(const VesselCenterline& vessel, double spacing) {
  CenterlinePolyline line;
  line.points = vessel.points();
  line.radii = vessel.radii();
  return VesselCenterline::from_polyline(line, spacing);
}

void validate(const CatheterParameters& start, const DesignOptimiserOptions& o) {
  auto require = [](bool ok, const std::string& message) {
    if (!ok) throw PlannerOptionsError("optimise_design: " + message);
  };
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  require(o.max_evaluations >= 4, "max_evaluations must be at least 4 planner runs");
  require(o.exploration_samples >= 0, "exploration_samples must be >= 0");
  require(o.local_runs >= 1, "local_runs must be >= 1");
  require(o.local_evaluations >= 8 && o.flexure_evaluations >= 8,
          "local_evaluations and flexure_evaluations must be >= 8 (BOBYQA needs 7 model points)");
  require(std::isfinite(o.search_spacing) && o.search_spacing >= 0.0,
          "search_spacing must be >= 0 mm (0: the vessel's own)");
  require(positive(o.initial_step_length) && positive(o.initial_step_angle),
          "initial_step_length and initial_step_angle must be > 0");
  require(positive(o.length_tolerance) && positive(o.angle_tolerance) &&
              std::isfinite(o.relative_penalty_tolerance) && o.relative_penalty_tolerance >= 0.0,
          "length_tolerance and angle_tolerance must be > 0, relative_penalty_tolerance >= 0");
  require(positive(o.min_length) && std::isfinite(o.max_length) && o.max_length > o.min_length,
          "need 0 < min_length < max_length (mm)");
  require(std::isfinite(start.plane_offset), "the start design's plane offset δ2 must be finite");
  require(start.proximal_length >= o.min_length && start.proximal_length <= o.max_length &&
              start.distal_length >= o.min_length && start.distal_length <= o.max_length,
          "the start design's segment lengths (" + std::to_string(start.proximal_length) + ", " +
              std::to_string(start.distal_length) + " mm) must lie within [" + std::to_string(o.min_length) +
              ", " + std::to_string(o.max_length) + "] mm");
}

// One optimisation: the planner runs, the budget, the best design seen per (spacing, flexure).
class DesignSearch {
 public:
  DesignSearch(const CatheterParameters& start, const VesselCenterline& vessel,
               const ShapeErrorPlannerOptions& planner_options, const DesignOptimiserOptions& options,
               const JobControl& job)
      : start_(start),
        vessel_(vessel),
        planner_options_(planner_options),
        options_(options),
        job_(job),
        cancel_only_{{}, job.cancel},
        search_spacing_(std::max(options.search_spacing, vessel.spacing())),
        resampled_(search_spacing_ > vessel.spacing()),
        search_vessel_(resampled_ ? resampled(vessel, search_spacing_) : vessel) {}

  double search_spacing() const noexcept { return search_spacing_; }
  int evaluations() const noexcept { return evaluations_; }
  int remaining() const noexcept { return options_.max_evaluations - evaluations_; }
  const std::vector<double>& history() const noexcept { return history_; }

  CatheterParameters design_of(const Design& chi) const {
    CatheterParameters p = start_;
    p.proximal_length = std::clamp(chi[0], options_.min_length, options_.max_length);
    p.distal_length = std::clamp(chi[1], options_.min_length, options_.max_length);
    p.plane_offset = wrap_angle(chi[2]);
    return p;
  }

  // A full plan of χ on the vessel at its own spacing (the reported result). When the search runs at
  // that spacing too, its penalty is remembered for the search.
  PathPlan final_plan(const Design& chi, bool flexure) {
    const CatheterParameters p = design_of(chi);
    const Design key(p.proximal_length, p.distal_length, p.plane_offset);
    PathPlan plan = run(vessel_, key, flexure);
    if (!resampled_ && lookup(key, flexure) == nullptr)
      remember(key, flexure, design_penalty(plan, planner_options_));
    return plan;
  }

  // The designs planned at the search spacing with this flexure setting whose g is below `below`,
  // lowest g first.
  std::vector<Design> designs_below(bool flexure, double below) const {
    std::vector<Cached> found;
    for (const auto& c : cache_)
      if (c.flexure == flexure && c.penalty < below) found.push_back(c);
    std::stable_sort(found.begin(), found.end(),
                     [](const Cached& a, const Cached& b) { return a.penalty < b.penalty; });
    std::vector<Design> out;
    out.reserve(found.size());
    for (const auto& c : found) out.push_back(c.chi);
    return out;
  }

  // g(χ) on the search vessel; repeated designs are answered from a cache (BOBYQA re-evaluates its
  // start, which exploration has already planned).
  double search_penalty(const Design& chi, bool flexure) {
    const CatheterParameters p = design_of(chi);
    const Design key(p.proximal_length, p.distal_length, p.plane_offset);
    if (const double* g = lookup(key, flexure)) return *g;
    const double g = design_penalty(run(search_vessel_, key, flexure), planner_options_);
    remember(key, flexure, g);
    return g;
  }

 private:
  const double* lookup(const Design& key, bool flexure) const {
    for (const auto& c : cache_)
      if (c.flexure == flexure && c.chi == key) return &c.penalty;
    return nullptr;
  }
  void remember(const Design& key, bool flexure, double g) {
    cache_.push_back({key, flexure, g});
    best_ = std::min(best_, g);
    history_.push_back(best_);
  }

  PathPlan run(const VesselCenterline& vessel, const Design& chi, bool flexure) {
    job_.check_cancelled();
    ShapeErrorPlannerOptions o = planner_options_;
    o.free_flexure = flexure;
    PathPlan plan =
        ShapeErrorPlanner(ConstantCurvatureCatheter(design_of(chi)), o).plan(vessel, cancel_only_);
    ++evaluations_;
    job_.report(std::min(1.0, static_cast<double>(evaluations_) / options_.max_evaluations));
    return plan;
  }

  struct Cached {
    Design chi;
    bool flexure;
    double penalty;
  };
  const CatheterParameters& start_;
  const VesselCenterline& vessel_;
  const ShapeErrorPlannerOptions& planner_options_;
  const DesignOptimiserOptions& options_;
  const JobControl& job_;
  JobControl cancel_only_;  // nested plans only check for cancellation; progress counts whole plans
  double search_spacing_;
  bool resampled_;
  VesselCenterline search_vessel_;
  int evaluations_ = 0;
  double best_ = std::numeric_limits<double>::infinity();
  std::vector<double> history_;
  std::vector<Cached> cache_;
};

struct LocalResult {
  Design chi;
  double penalty = std::numeric_limits<double>::infinity();
  DesignStopReason reason = DesignStopReason::evaluation_budget;
};

// NLopt calls back through C: exceptions (cancellation, planner errors) must not cross it, so they are
// caught, the run is force-stopped and the exception rethrown after nlopt_optimize returns.
struct Objective {
  DesignSearch* search;
  bool flexure;
  LocalResult* best;
  std::exception_ptr error;
};

double objective(unsigned n, const double* x, double* gradient, void* data) {
  (void)n;
  (void)gradient;  // derivative-free: never requested
  auto* o = static_cast<Objective*>(data);
  try {
    const Design chi(x[0], x[1], x[2]);
    const double g = o->search->search_penalty(chi, o->flexure);
    if (g < o->best->penalty) {
      o->best->penalty = g;
      o->best->chi = chi;
    }
    return g;
  } catch (...) {
    o->error = std::current_exception();
    return std::numeric_limits<double>::infinity();
  }
}

// BOBYQA from `from` with `budget` planner runs; lengths within the options' bounds, δ2 within one turn
// centred on the start. Returns the best design seen (at least `from` itself).
LocalResult local_search(DesignSearch& search, const DesignOptimiserOptions& options, const Design& from,
                         bool flexure, int budget) {
  LocalResult best;
  best.chi = from;
  Objective data{&search, flexure, &best, nullptr};
  nlopt_opt opt = nlopt_create(NLOPT_LN_BOBYQA, 3);
  if (opt == nullptr) throw std::bad_alloc();
  const std::array<double, 3> lower{options.min_length, options.min_length, from[2] - kPi};
  const std::array<double, 3> upper{options.max_length, options.max_length, from[2] + kPi};
  // BOBYQA needs its first trust region inside the box: at most half the box width per coordinate.
  const double width = options.max_length - options.min_length;
  const std::array<double, 3> step{std::min(options.initial_step_length, 0.5 * width),
                                   std::min(options.initial_step_length, 0.5 * width),
                                   std::min(options.initial_step_angle, kPi)};
  const std::array<double, 3> tolerance{options.length_tolerance, options.length_tolerance,
                                        options.angle_tolerance};
  nlopt_set_lower_bounds(opt, lower.data());
  nlopt_set_upper_bounds(opt, upper.data());
  nlopt_set_initial_step(opt, step.data());
  nlopt_set_xtol_abs(opt, tolerance.data());
  nlopt_set_ftol_rel(opt, options.relative_penalty_tolerance);
  nlopt_set_maxeval(opt, budget);
  nlopt_set_min_objective(opt, objective, &data);
  std::array<double, 3> x{from[0], from[1], from[2]};
  double value = 0.0;
  const nlopt_result code = nlopt_optimize(opt, x.data(), &value);
  nlopt_destroy(opt);
  if (data.error) std::rethrow_exception(data.error);
  switch (code) {
    case NLOPT_XTOL_REACHED:
    case NLOPT_SUCCESS:
      best.reason = DesignStopReason::step_tolerance;
      break;
    case NLOPT_FTOL_REACHED:
      best.reason = DesignStopReason::penalty_tolerance;
      break;
    case NLOPT_ROUNDOFF_LIMITED:
      best.reason = DesignStopReason::roundoff;
      break;
    case NLOPT_MAXEVAL_REACHED:
      best.reason = DesignStopReason::evaluation_budget;
      break;
    default:
      throw std::runtime_error(std::string("optimise_design: NLopt BOBYQA failed (") +
                               nlopt_result_to_string(code) + ")");
  }
  return best;
}

// The errors a superset design must not worsen.
struct PlanErrors {
  double penalty, position_mean, position_max, tip_mean, tip_max;

  bool no_worse_than(const PlanErrors& o) const {
    return penalty <= o.penalty && position_mean <= o.position_mean && position_max <= o.position_max &&
           tip_mean <= o.tip_mean && tip_max <= o.tip_max;
  }
};

PlanErrors errors_of(const PathPlan& plan, const VesselCenterline& vessel,
                     const ShapeErrorPlannerOptions& planner_options) {
  PlanErrors e{design_penalty(plan, planner_options), plan.position_error_mean, plan.position_error_max, 0.0,
               0.0};
  const auto& points = vessel.points();
  const double ds = vessel.spacing();
  for (const auto& step : plan.steps) {
    const double length = step.design.proximal_length + step.design.distal_length;
    const Eigen::Vector3d tip = planned_backbone(step, length).back();
    // The centerline point at arc length q1 (linear between samples).
    const double at = std::clamp(step.q[0] / ds, 0.0, static_cast<double>(points.size() - 1));
    const auto i = std::min(static_cast<std::size_t>(at), points.size() - 2);
    const double u = at - static_cast<double>(i);
    const double d = (tip - ((1.0 - u) * points[i] + u * points[i + 1])).norm();
    e.tip_mean += d;
    e.tip_max = std::max(e.tip_max, d);
  }
  if (!plan.steps.empty()) e.tip_mean /= static_cast<double>(plan.steps.size());
  return e;
}

bool converged(DesignStopReason reason) {
  return reason == DesignStopReason::step_tolerance || reason == DesignStopReason::penalty_tolerance ||
         reason == DesignStopReason::roundoff;
}

struct StageResult {
  Design chi;
  double penalty;  // at the search spacing
};

// Stages 1 and 2 without flexure: exploration, then BOBYQA runs with restarts. `reserve` planner runs
// are kept for what follows.
StageResult explore_and_search(DesignSearch& search, const DesignOptimiserOptions& options,
                               const Design& start, int reserve, DesignConvergence& report) {
  struct Sample {
    Design chi;
    double penalty;
  };
  std::vector<Sample> samples;
  const int affordable = std::max(0, search.remaining() - reserve);
  const int count = std::max(1, std::min(options.exploration_samples + 1, affordable));
  const double log_ratio = std::log(options.max_length / options.min_length);
  for (int i = 0; i < count; ++i) {
    // Lengths log-uniform: a segment's reach scales with its curvature 1/L, and the short designs
    // where g is small would be rare under a uniform spread over [5, 60] mm.
    const Design chi = i == 0 ? start
                              : Design(options.min_length * std::exp(log_ratio * radical_inverse(i, 2)),
                                       options.min_length * std::exp(log_ratio * radical_inverse(i, 3)),
                                       start[2] + kPi * (2.0 * radical_inverse(i, 5) - 1.0));
    samples.push_back({chi, search.search_penalty(chi, false)});
  }
  std::stable_sort(samples.begin(), samples.end(),
                   [](const Sample& a, const Sample& b) { return a.penalty < b.penalty; });
  StageResult best{samples.front().chi, samples.front().penalty};
  report.explored_penalty = best.penalty;

  // A restart begins at the best explored design that lies more than two initial steps from every
  // start and optimum of the runs so far (another basin).
  std::vector<Design> visited;
  auto far_from_visited = [&](const Design& chi) {
    return std::all_of(visited.begin(), visited.end(), [&](const Design& v) {
      const double dl = (chi.head<2>() - v.head<2>()).norm() / options.initial_step_length;
      const double da = std::abs(wrap_angle(chi[2] - v[2])) / options.initial_step_angle;
      return std::hypot(dl, da) > 2.0;
    });
  };
  for (int run = 0; run < options.local_runs; ++run) {
    const auto next = std::find_if(samples.begin(), samples.end(),
                                   [&](const Sample& s) { return far_from_visited(s.chi); });
    const int budget = std::min(options.local_evaluations, search.remaining() - reserve);
    if (next == samples.end() || budget < 8) break;
    const LocalResult local = local_search(search, options, next->chi, false, budget);
    ++report.local_runs;
    report.stop_reason = local.reason;
    visited.push_back(next->chi);
    visited.push_back(local.chi);
    if (local.penalty < best.penalty) best = {local.chi, local.penalty};
  }
  return best;
}

}  // namespace

DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options) {
  return optimise_design(start, vessel, planner_options, options, JobControl{});
}

DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options, const JobControl& job) {
  validate(start, options);
  // Bad planner options are reported before any work (the planner checks them).
  const ShapeErrorPlanner options_check(ConstantCurvatureCatheter(start), planner_options);
  const bool flexure = planner_options.free_flexure;
  DesignSearch search(start, vessel, planner_options, options, job);
  DesignResult result;
  result.flexure = flexure;
  auto& report = result.convergence;
  report.search_spacing = search.search_spacing();
  report.subset_penalty = std::numeric_limits<double>::quiet_NaN();
  const Design from(start.proximal_length, start.distal_length, wrap_angle(start.plane_offset));

  result.initial_penalty = design_penalty(search.final_plan(from, flexure), planner_options);
  // Runs kept for the end: the subset optimum's plan at the vessel's spacing, and with flexure the
  // flexure search and up to three checks of its best designs at the vessel's spacing.
  constexpr int kFlexureChecks = 3;
  const int reserve = flexure ? 1 + options.flexure_evaluations + kFlexureChecks : 1;
  const StageResult subset = explore_and_search(search, options, from, reserve, report);
  result.design = search.design_of(subset.chi);
  result.plan = search.final_plan(subset.chi, false);
  PlanErrors errors = errors_of(result.plan, vessel, planner_options);

  if (flexure) {
    // Seeded with the subset optimum: the search starts where the design without flexure ended.
    report.subset_penalty = errors.penalty;
    const int budget = std::min(options.flexure_evaluations, search.remaining() - 1);
    if (budget >= 8) {
      const LocalResult local = local_search(search, options, subset.chi, true, budget);
      ++report.local_runs;
      report.stop_reason = local.reason;
    }
    const std::vector<Design> better = search.designs_below(true, subset.penalty);
    for (std::size_t k = 0; k < better.size() && k < kFlexureChecks && search.remaining() > 0; ++k) {
      PathPlan plan = search.final_plan(better[k], true);
      const PlanErrors candidate = errors_of(plan, vessel, planner_options);
      if (candidate.no_worse_than(errors)) {
        result.design = search.design_of(better[k]);
        result.plan = std::move(plan);
        errors = candidate;
        report.flexure_improved = true;
        break;
      }
    }
  }
  result.penalty = errors.penalty;
  result.tip_error_mean = errors.tip_mean;
  result.tip_error_max = errors.tip_max;
  report.converged = converged(report.stop_reason);
  report.best_penalty_history = search.history();
  report.search_evaluations = static_cast<int>(report.best_penalty_history.size());
  result.evaluations = search.evaluations();
  job.report(1.0);
  return result;
}

}  // namespace tendril::teleop
