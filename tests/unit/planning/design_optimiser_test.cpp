#include "tendril/teleop/design_optimiser.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <vector>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;

TEST(DesignOptimiser, ImprovesOnTheAdHocDesign) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ShapeErrorPlannerOptions planner_options;
  DesignOptimiserOptions options;
  options.max_evaluations = 20;
  const DesignResult result = optimise_design(nominal_planning_design(), vessel, planner_options, options);
  EXPECT_LE(result.evaluations, options.max_evaluations + 5);
  EXPECT_LT(result.penalty, result.initial_penalty);
  EXPECT_NEAR(design_penalty(result.plan, planner_options), result.penalty, 1e-9);
  EXPECT_THROW(optimise_design(nominal_planning_design(), vessel, planner_options, {.max_evaluations = 2}),
               PlannerOptionsError);
}

TEST(DesignOptimiser, ForwardsCancellationIntoNestedPlans) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  std::atomic<bool> cancel{false};
  std::size_t evaluations = 0;
  JobControl design_job{[&](double) {
                          if (++evaluations == 3) cancel = true;
                        },
                        &cancel};
  EXPECT_THROW(optimise_design(nominal_planning_design(), vessel, {}, {}, design_job), OperationCancelled);
  EXPECT_EQ(evaluations, 3u);
}

// Table 4.1 (seed 000 §4.6.3) on the synthetic ICA (seed 1; the source's CT path is not published).
// Source: ad hoc 1.70/4.18 mm, 0.27/0.62 rad; optimised 1.13/2.34 mm, 0.21/0.38 rad; optimised with
// flexure 0.49/0.96 mm, 0.09/0.23 rad (mean/max). Measured here (60 evaluations each; the flexure
// design starts from the optimised one):
//   ad hoc [22, 18.8, −0.76]              2.25/8.51 mm, 0.348/1.797 rad
//   optimised [5.8, 5.6, −0.64]           0.11/0.48 mm, 0.059/0.394 rad
//   optimised + flexure [5.4, 5.6, 0.37]  0.04/0.28 mm, 0.036/0.206 rad
// The ordering ③ < ② < ① holds in every metric (also for synthetic seeds 2–5, checked by hand). The
// optimised lengths differ from the source's: with the shaft conforming to the vessel, g keeps falling
// as the segments shorten, so they end near the 5 mm lower bound.
TEST(DesignOptimiser, ReproducesTable41Ordering) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ShapeErrorPlannerOptions options;  // r_tp 0.75, r_seg 1, ds 0.5, dq1 3
  const PathPlan ad_hoc =
      ShapeErrorPlanner(ConstantCurvatureCatheter(nominal_planning_design()), options).plan(vessel);
  DesignOptimiserOptions optimiser;
  optimiser.max_evaluations = 60;
  const DesignResult optimised = optimise_design(nominal_planning_design(), vessel, options, optimiser);
  ShapeErrorPlannerOptions with_flexure = options;
  with_flexure.free_flexure = true;
  const DesignResult flexure = optimise_design(optimised.design, vessel, with_flexure, optimiser);
  EXPECT_FALSE(optimised.flexure);
  EXPECT_TRUE(flexure.flexure);
  auto print = [](const char* name, const CatheterParameters& d, const PathPlan& p) {
    std::printf("%-22s [%.1f, %.1f, %.2f]  %.2f/%.2f mm  %.3f/%.3f rad\n", name, d.proximal_length,
                d.distal_length, d.plane_offset, p.position_error_mean, p.position_error_max,
                p.tangent_error_mean * kPi / 180.0, p.tangent_error_max * kPi / 180.0);
  };
  print("ad hoc", nominal_planning_design(), ad_hoc);
  print("optimised", optimised.design, optimised.plan);
  print("optimised + flexure", flexure.design, flexure.plan);
  const PathPlan* ordered[] = {&ad_hoc, &optimised.plan, &flexure.plan};
  for (int i = 0; i < 2; ++i) {
    const PathPlan& worse = *ordered[i];
    const PathPlan& better = *ordered[i + 1];
    EXPECT_LT(better.position_error_mean, worse.position_error_mean) << i;
    EXPECT_LT(better.position_error_max, worse.position_error_max) << i;
    EXPECT_LT(better.tangent_error_mean, worse.tangent_error_mean) << i;
    EXPECT_LT(better.tangent_error_max, worse.tangent_error_max) << i;
  }
  EXPECT_GE(optimised.design.proximal_length, optimiser.min_length);
  EXPECT_GE(optimised.design.distal_length, optimiser.min_length);
}

// §4.6.1: the grid picks the pair with the lowest g, and weighting tangents (r_tp > 0) lowers the
// tangent error against position-only matching (r_tp = 0).
TEST(WeightSweep, PicksTheLowestPenaltyAndTangentWeightHelpsTangents) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  const std::vector<double> r_tp{0.0, 0.75, 2.0}, r_seg{0.5, 1.0, 1.25};
  const WeightSweepResult sweep = sweep_weights(nominal_planning_design(), vessel, {}, r_tp, r_seg);
  ASSERT_EQ(sweep.grid.size(), 9u);
  for (const auto& point : sweep.grid) EXPECT_LE(sweep.best.penalty, point.penalty);
  EXPECT_DOUBLE_EQ(sweep.grid[4].tangent_to_position_ratio, 0.75);
  EXPECT_DOUBLE_EQ(sweep.grid[4].proximal_to_distal_ratio, 1.0);
  for (std::size_t j = 0; j < r_seg.size(); ++j) {
    EXPECT_LT(sweep.grid[r_seg.size() + j].tangent_error_mean, sweep.grid[j].tangent_error_mean) << j;
  }
  EXPECT_THROW(sweep_weights(nominal_planning_design(), vessel, {}, {}, r_seg), PlannerOptionsError);
  EXPECT_THROW(sweep_weights(nominal_planning_design(), vessel, {}, {-1.0}, r_seg), PlannerOptionsError);
}

}  // namespace
}  // namespace tendril::teleop
