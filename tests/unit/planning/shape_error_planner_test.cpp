#include "tendril/teleop/shape_error_planner.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <vector>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;
using JointVector = ConstantCurvatureCatheter::JointVector;

CenterlinePolyline straight_line(double length) {
  CenterlinePolyline line;
  for (int i = 0; i <= 100; ++i) line.points.emplace_back(0.0, 0.0, length * i / 100.0);
  return line;
}

TEST(ShapeErrorPlanner, SteerablePointMatchesKinematicModel) {
  const ConstantCurvatureCatheter model(nominal_planning_design());
  const ShapeErrorPlanner planner(model, {});
  const JointVector q(12.0, 0.7, 2.5, -1.8);
  constexpr std::size_t kPerSegment = 10;
  std::vector<Eigen::Vector3d> backbone(model.backbone_point_count(kPerSegment));
  ASSERT_EQ(model.backbone(q, kPerSegment, backbone), backbone.size());
  const double L1 = model.parameters().proximal_length, L2 = model.parameters().distal_length;
  for (std::size_t i = 0; i <= kPerSegment; ++i) {
    const double sigma = L1 * static_cast<double>(i) / kPerSegment;
    EXPECT_LT((planner.steerable_point(q, sigma, nullptr) - backbone[i]).norm(), 1e-12) << i;
  }
  for (std::size_t i = 1; i <= kPerSegment; ++i) {
    const double sigma = L1 + L2 * static_cast<double>(i) / kPerSegment;
    EXPECT_LT((planner.steerable_point(q, sigma, nullptr) - backbone[kPerSegment + i]).norm(), 1e-12) << i;
  }
  Eigen::Vector3d tangent;
  const TipPose tip = model.tip_pose(q);
  EXPECT_LT((planner.steerable_point(q, L1 + L2, &tangent) - tip.position).norm(), 1e-12);
  EXPECT_LT((tangent - tip.rotation.col(2)).norm(), 1e-12);
}

TEST(ShapeErrorPlanner, StraightVesselKeepsCatheterStraight) {
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  const auto vessel = VesselCenterline::from_polyline(straight_line(90.0), 0.5);
  const PathPlan plan = planner.plan(vessel);
  ASSERT_EQ(plan.steps.size(), 30u);
  for (const auto& step : plan.steps) {
    EXPECT_NEAR(step.q[2], 0.0, 1e-9);
    EXPECT_NEAR(step.q[3], 0.0, 1e-9);
    EXPECT_LT(step.position_error_max, 1e-9);
    EXPECT_LT(step.tangent_error_max, 1e-6);
  }
  EXPECT_DOUBLE_EQ(plan.steps.back().q[0], 90.0);
  // Only points on the inserted steerable section count: 40.8 mm at ds 0.5 once fully inside.
  EXPECT_EQ(plan.steps[0].points, 7u);       // s = 0 … 3
  EXPECT_EQ(plan.steps.back().points, 82u);  // s = 49.5 … 90
}

TEST(ShapeErrorPlanner, FindsAShapeTheModelCanReproduce) {
  const ConstantCurvatureCatheter model(nominal_planning_design());
  const JointVector truth(0.0, 0.9, 1.2, -0.9);
  // The vessel is the catheter's own steerable shape, base at the insertion point.
  std::vector<Eigen::Vector3d> backbone(model.backbone_point_count(4000));
  model.backbone(truth, 4000, backbone);
  CenterlinePolyline line;
  line.points = backbone;
  const auto vessel = VesselCenterline::from_polyline(line, 0.4);  // 40.8 mm = 102 samples
  ASSERT_NEAR(vessel.length(), 40.8, 1e-9);
  ShapeErrorPlannerOptions options;
  options.insertion_step = 40.8 / 17.0;  // last step inserts exactly the whole steerable section
  ShapeErrorPlanner planner(model, options);
  const PathPlan plan = planner.plan(vessel);
  ASSERT_EQ(plan.steps.size(), 17u);
  const PlanStep& last = plan.steps.back();
  EXPECT_EQ(last.points, 103u);
  EXPECT_LT(last.position_error_max, 0.05);
  // The vessel's finite-difference tangent is off by ~κ·ds/2 at the segment junction, where the
  // curvature jumps; elsewhere it is exact to O(ds²).
  EXPECT_LT(last.tangent_error_max, 1.0);
  EXPECT_LT(last.tangent_error_mean, 0.1);
  // (q2 + π, −q3, −q4) draws the same curve, so either configuration is the answer.
  const bool flipped = std::abs(std::remainder(last.q[1] - truth[1], 2.0 * kPi)) > 0.5 * kPi;
  const double sign = flipped ? -1.0 : 1.0;
  EXPECT_NEAR(std::remainder(last.q[1] - truth[1] - (flipped ? kPi : 0.0), 2.0 * kPi), 0.0, 0.01);
  EXPECT_NEAR(sign * last.q[2], truth[2], 0.01);
  EXPECT_NEAR(sign * last.q[3], truth[3], 0.01);
}

TEST(ShapeErrorPlanner, PlansSyntheticIcaWithinLimits) {
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  const PathPlan plan = planner.plan(vessel);
  ASSERT_EQ(plan.steps.size(), 50u);
  for (const auto& step : plan.steps) {
    EXPECT_GE(step.q[2], -6.0);
    EXPECT_LE(step.q[2], 10.0);
    EXPECT_GE(step.q[3], -5.0);
    EXPECT_LE(step.q[3], 5.0);
    EXPECT_LE(std::abs(step.q[1]), kPi + 1e-12);
    EXPECT_TRUE(std::isfinite(step.position_error_mean));
  }
  // Bending must do better than leaving the catheter straight on a tortuous path.
  ShapeErrorPlannerOptions frozen;
  frozen.proximal_drive_min = frozen.distal_drive_min = -1e-9;
  frozen.proximal_drive_max = frozen.distal_drive_max = 1e-9;
  ShapeErrorPlanner straight_only(ConstantCurvatureCatheter(nominal_planning_design()), frozen);
  EXPECT_LT(plan.position_error_mean, 0.5 * straight_only.plan(vessel).position_error_mean);
  // Same inputs, same plan (pure function of model, vessel and options; scratch reuse is invisible).
  const PathPlan again = planner.plan(vessel);
  EXPECT_EQ(again.steps.back().q, plan.steps.back().q);
}

TEST(ShapeErrorPlanner, WarmStartNeedsFewerIterations) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ShapeErrorPlannerOptions warm, cold;
  cold.warm_start = false;
  const ConstantCurvatureCatheter model(nominal_planning_design());
  const PathPlan warm_plan = ShapeErrorPlanner(model, warm).plan(vessel);
  const PathPlan cold_plan = ShapeErrorPlanner(model, cold).plan(vessel);
  EXPECT_LT(warm_plan.total_iterations, cold_plan.total_iterations);
}

TEST(ShapeErrorPlanner, RejectsBadOptionsAndShortVessels) {
  const ConstantCurvatureCatheter model(nominal_planning_design());
  auto with = [](auto change) {
    ShapeErrorPlannerOptions o;
    change(o);
    return o;
  };
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.insertion_step = 0.0; })), PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.insertion_step = NAN; })), PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.position_error_range = -1.0; })),
               PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.tangent_to_position_ratio = -0.1; })),
               PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.proximal_drive_min = 11.0; })),
               PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.distal_drive_max = -1.0; })),
               PlannerOptionsError);
  EXPECT_THROW(ShapeErrorPlanner(model, with([](auto& o) { o.max_iterations = 0; })), PlannerOptionsError);
  ShapeErrorPlanner planner(model, {});
  EXPECT_THROW(planner.plan(VesselCenterline::from_polyline(straight_line(2.0), 0.5)), VesselInputError);
}

TEST(ShapeErrorPlanner, FreeFlexureRecoversAFlexedShape) {
  // The vessel is the shape of a catheter whose flexure is bent by 0.5 rad; a planner with γ free
  // finds it (a planner with γ fixed at 0 cannot).
  CatheterParameters flexed = nominal_planning_design();
  flexed.flexure = 0.5;
  const ConstantCurvatureCatheter truth_model(flexed);
  std::vector<Eigen::Vector3d> backbone(truth_model.backbone_point_count(4000));
  truth_model.backbone(JointVector(0.0, 0.4, 0.8, -0.6), 4000, backbone);
  CenterlinePolyline line;
  line.points = backbone;
  const auto vessel = VesselCenterline::from_polyline(line, 0.4);
  ShapeErrorPlannerOptions options;
  options.insertion_step = 40.8 / 17.0;
  const ConstantCurvatureCatheter model(nominal_planning_design());
  const PathPlan fixed_plan = ShapeErrorPlanner(model, options).plan(vessel);
  options.free_flexure = true;
  const PathPlan free_plan = ShapeErrorPlanner(model, options).plan(vessel);
  EXPECT_TRUE(free_plan.free_flexure);
  EXPECT_LT(free_plan.steps.back().position_error_max, 0.05);
  EXPECT_GT(fixed_plan.steps.back().position_error_max, 0.5);
  EXPECT_NEAR(std::abs(free_plan.steps.back().flexure), 0.5, 0.01);
  options.flexure_min = 0.1;  // must include 0
  EXPECT_THROW(ShapeErrorPlanner(model, options), PlannerOptionsError);
}

TEST(ShapeErrorPlanner, PlannedBackboneIsInTheVesselFrame) {
  auto line = make_synthetic_ica(2);
  const auto vessel = VesselCenterline::from_polyline(line, 0.5);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(30.0, -12.0, 5.0);
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  const PathPlan plan = planner.plan(vessel);
  const PathPlan moved = planner.plan(vessel.transformed(R, t));
  ASSERT_EQ(plan.steps.size(), moved.steps.size());
  for (std::size_t k = 0; k < plan.steps.size(); k += 7) {
    const auto a = planned_backbone(plan.steps[k], 0.5), b = planned_backbone(moved.steps[k], 0.5);
    ASSERT_EQ(a.size(), 83u);  // 40.8 mm every 0.5 mm plus the tip
    for (std::size_t i = 0; i < a.size(); ++i) EXPECT_LT((R * a[i] + t - b[i]).norm(), 1e-6);
    // The tip is at inserted arc length q1 on the vessel, within the step's worst error.
    const auto tip_index = static_cast<std::size_t>(std::lround(plan.steps[k].q[0] / 0.5));
    EXPECT_LE((a.back() - vessel.points()[tip_index]).norm(), plan.steps[k].position_error_max + 1e-9);
  }
  EXPECT_THROW(planned_backbone(plan.steps[0], 0.0), PlannerOptionsError);
}

TEST(ShapeErrorPlanner, ReportsProgressAndStopsWhenCancelled) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  std::vector<double> fractions;
  std::atomic<bool> cancel{false};
  JobControl job{[&](double f) { fractions.push_back(f); }, &cancel};
  const PathPlan plan = planner.plan(vessel, job);
  ASSERT_EQ(fractions.size(), plan.steps.size());
  EXPECT_TRUE(std::is_sorted(fractions.begin(), fractions.end()));
  EXPECT_DOUBLE_EQ(fractions.back(), 1.0);
  // Cancel after the 10th step: the next step does not run.
  fractions.clear();
  JobControl cancelling{[&](double f) {
                          fractions.push_back(f);
                          if (fractions.size() == 10) cancel = true;
                        },
                        &cancel};
  EXPECT_THROW(planner.plan(vessel, cancelling), OperationCancelled);
  EXPECT_EQ(fractions.size(), 10u);
}

// Issue 15: the analytic Jacobian of the residuals against central differences of the residuals, on a
// step with both segments inside a curved vessel, at a bent configuration with a flexure, and near the
// straight pose (where the series branches of the closed forms apply); also the normal equations.
TEST(ShapeErrorPlanner, AnalyticJacobianMatchesFiniteDifferences) {
  ShapeErrorPlannerOptions options;
  options.free_flexure = true;
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), options);
  planner.prepare(VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5));
  auto ws = planner.make_workspace();
  planner.load_step(60.0, Eigen::Vector3d(0.3, -0.2, 0.1), ws);
  ASSERT_EQ(ws.count, 82u);
  const auto rows = static_cast<Eigen::Index>(6 * ws.count);
  Eigen::VectorXd r(rows), plus(rows), minus(rows);
  Eigen::Matrix<double, Eigen::Dynamic, 4> J(rows, 4), unused(rows, 4);
  for (const Eigen::Vector4d& x :
       {Eigen::Vector4d(0.7, 1.3, -0.9, 0.25), Eigen::Vector4d(-2.0, 2e-3, -5e-4, 0.0),
        Eigen::Vector4d(0.1, 4e-5, 3e-3, -0.4)}) {
    ASSERT_TRUE(planner.residuals(ws, x, r, J));
    for (int j = 0; j < 4; ++j) {
      const double h = 1e-6;
      Eigen::Vector4d xp = x, xm = x;
      xp[j] += h;
      xm[j] -= h;
      planner.residuals(ws, xp, plus, unused);
      planner.residuals(ws, xm, minus, unused);
      const Eigen::VectorXd numeric = (plus - minus) / (2.0 * h);
      EXPECT_LT((J.col(j) - numeric).cwiseAbs().maxCoeff(),
                1e-6 * std::max(1.0, numeric.cwiseAbs().maxCoeff()))
          << "column " << j << " at " << x.transpose();
    }
    Eigen::Matrix4d A;
    Eigen::Vector4d g;
    const double cost = planner.normal_equations(ws, x, A, g);
    EXPECT_NEAR(cost, r.squaredNorm(), 1e-9 * std::max(1.0, cost));
    EXPECT_NEAR(planner.cost(ws, x), cost, 1e-9 * std::max(1.0, cost));
    EXPECT_LT((A - J.transpose() * J).cwiseAbs().maxCoeff(), 1e-9 * std::max(1.0, A.cwiseAbs().maxCoeff()));
    EXPECT_LT((g - J.transpose() * r).cwiseAbs().maxCoeff(), 1e-9 * std::max(1.0, g.cwiseAbs().maxCoeff()));
  }
  Eigen::VectorXd short_r(rows - 1);
  EXPECT_FALSE(planner.residuals(ws, Eigen::Vector4d::Zero(), short_r, unused));
}

// The step-wise API reproduces plan(): loading step k and solving from step k−1's solution gives step k.
TEST(ShapeErrorPlanner, StepwiseSolveReproducesThePlan) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ShapeErrorPlanner planner(ConstantCurvatureCatheter(nominal_planning_design()), {});
  const PathPlan plan = planner.plan(vessel);
  auto ws = planner.make_workspace();
  PlanStep step;
  for (std::size_t k = 1; k < plan.steps.size(); k += 6) {
    const PlanStep& previous = plan.steps[k - 1];
    planner.load_step(plan.steps[k].q[0], Eigen::Vector3d::Zero(), ws);
    planner.solve_loaded(ws, {previous.q[1], previous.q[2], previous.q[3], previous.flexure}, step);
    EXPECT_EQ(step.q, plan.steps[k].q) << k;
    EXPECT_EQ(step.cost, plan.steps[k].cost) << k;
    EXPECT_LT((step.base_position - plan.steps[k].base_position).norm(), 1e-12);
  }
}

}  // namespace
}  // namespace tendril::teleop
