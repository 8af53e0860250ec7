#include "tendril/teleop/design_optimiser.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

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

DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options) {
  return optimise_design(start, vessel, planner_options, options, JobControl{});
}

DesignResult optimise_design(const CatheterParameters& start, const VesselCenterline& vessel,
                             const ShapeErrorPlannerOptions& planner_options,
                             const DesignOptimiserOptions& options, const JobControl& job) {
  if (options.max_evaluations < 4 || !(options.min_length > 0.0 && options.max_length > options.min_length) ||
      !(options.initial_step_length > 0.0 && options.initial_step_angle > 0.0)) {
    throw PlannerOptionsError(
        "optimise_design: need max_evaluations >= 4, 0 < min_length < max_length and positive initial steps");
  }
  DesignResult result;
  result.flexure = planner_options.free_flexure;
  // Nested plans only check for cancellation; progress counts whole evaluations.
  const JobControl cancel_only{{}, job.cancel};
  auto design_of = [&](const Eigen::Vector3d& chi) {
    CatheterParameters p = start;
    p.proximal_length = std::clamp(chi[0], options.min_length, options.max_length);
    p.distal_length = std::clamp(chi[1], options.min_length, options.max_length);
    p.plane_offset = wrap_angle(chi[2]);
    return p;
  };
  double best = std::numeric_limits<double>::infinity();
  auto penalty = [&](const Eigen::Vector3d& chi) {
    job.check_cancelled();
    const CatheterParameters p = design_of(chi);
    ShapeErrorPlanner planner(ConstantCurvatureCatheter(p), planner_options);
    PathPlan plan = planner.plan(vessel, cancel_only);
    // Out-of-range lengths are clamped for the model and penalised so the simplex moves back.
    const double outside = std::abs(chi[0] - p.proximal_length) + std::abs(chi[1] - p.distal_length);
    const double g = design_penalty(plan, planner_options) + outside;
    ++result.evaluations;
    job.report(std::min(1.0, static_cast<double>(result.evaluations) / options.max_evaluations));
    if (g < best) {
      best = g;
      result.design = p;
      result.penalty = g;
      result.plan = std::move(plan);
    }
    return g;
  };

  // Standard Nelder–Mead (reflection 1, expansion 2, contraction ½, shrink ½).
  std::array<Eigen::Vector3d, 4> simplex;
  std::array<double, 4> values{};
  simplex[0] = {start.proximal_length, start.distal_length, start.plane_offset};
  for (int j = 0; j < 3; ++j) {
    simplex[j + 1] = simplex[0];
    simplex[j + 1][j] += j < 2 ? options.initial_step_length : options.initial_step_angle;
  }
  for (int j = 0; j < 4; ++j) values[j] = penalty(simplex[j]);
  result.initial_penalty = values[0];
  while (result.evaluations < options.max_evaluations) {
    std::array<int, 4> order{0, 1, 2, 3};
    std::sort(order.begin(), order.end(), [&](int a, int b) { return values[a] < values[b]; });
    const int worst = order[3], second = order[2], best_index = order[0];
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (int j = 0; j < 3; ++j) centroid += simplex[order[j]] / 3.0;
    const Eigen::Vector3d reflected = centroid + (centroid - simplex[worst]);
    const double fr = penalty(reflected);
    if (fr < values[best_index]) {
      const Eigen::Vector3d expanded = centroid + 2.0 * (centroid - simplex[worst]);
      const double fe = penalty(expanded);
      if (fe < fr) {
        simplex[worst] = expanded;
        values[worst] = fe;
      } else {
        simplex[worst] = reflected;
        values[worst] = fr;
      }
    } else if (fr < values[second]) {
      simplex[worst] = reflected;
      values[worst] = fr;
    } else {
      const Eigen::Vector3d contracted = centroid + 0.5 * (simplex[worst] - centroid);
      const double fc = penalty(contracted);
      if (fc < values[worst]) {
        simplex[worst] = contracted;
        values[worst] = fc;
      } else {
        for (int j = 1; j < 4; ++j) {
          simplex[order[j]] = simplex[best_index] + 0.5 * (simplex[order[j]] - simplex[best_index]);
          values[order[j]] = penalty(simplex[order[j]]);
        }
      }
    }
  }
  return result;
}

}  // namespace tendril::teleop
