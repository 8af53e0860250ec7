// The per-tick teleop functions must not touch the heap.
#include <gtest/gtest.h>

#include <array>
#include <memory>

#include "allocation_counter.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/image_guided_replanner.hpp"
#include "tendril/teleop/pid.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"

namespace tendril::teleop {
namespace {

TEST(TeleopRealtime, TickPathDoesNotAllocate) {
  QuinticInterpolator interp(4);
  Pid pid({.kp = 2.0, .ki = 1.0, .kd = 0.01, .output_limit = 5.0, .derivative_filter_time = 0.002});
  const ConstantCurvatureCatheter cat(CatheterParameters{});
  std::array<double, 4> q{}, qd{}, qdd{}, goal{10.0, 0.5, 0.3, -0.4};
  std::array<Eigen::Vector3d, 64> backbone;
  double sink = 0.0;

  const long before = tendril::testing::allocation_count.load();
  interp.reset(q);
  EXPECT_EQ(interp.retarget(0.0, goal, 2.0, 5.0), RetargetStatus::kOk);
  for (int i = 0; i < 1000; ++i) {
    const double t = i * 1e-3;
    if (i == 500) interp.retarget(t, std::array<double, 4>{1.0, -0.5, 0.0, 0.2}, 2.0, 5.0);
    interp.sample(t, q, qd, qdd);
    sink += pid.update(q[0], 0.9 * q[0], 1e-3);
    const ConstantCurvatureCatheter::JointVector jq(q[0], q[1], q[2], q[3]);
    sink += cat.tip_pose(jq).position.x();
    sink += cat.tip_position_jacobian(jq)(0, 2);
    sink += static_cast<double>(cat.backbone(jq, 20, backbone));
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  // The counter really sees allocations, so the check above can fail.
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

// Issue 15: a planner step (load + Levenberg–Marquardt) and a live replan work in their preallocated
// workspace only.
TEST(TeleopRealtime, PlannerStepAndReplanDoNotAllocate) {
  const auto vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  const ConstantCurvatureCatheter model(nominal_planning_design());
  ShapeErrorPlannerOptions options;
  options.free_flexure = true;
  ShapeErrorPlanner planner(model, options);
  planner.prepare(vessel);
  auto ws = planner.make_workspace();
  const ImageGuidedReplanner replanner(model, options, vessel);
  ReplannerState state = replanner.make_state();
  PlanStep step;
  ReplanInput in;
  double sink = 0.0;

  const long before = tendril::testing::allocation_count.load();
  Eigen::Vector4d start(0.0, 0.0, 0.0, 0.0);
  for (int k = 1; k <= 20; ++k) {
    planner.load_step(3.0 * k, Eigen::Vector3d(0.1, 0.0, 0.0), ws);
    planner.solve_loaded(ws, start, step);
    start = {step.q[1], step.q[2], step.q[3], step.flexure};
    sink += step.cost;
    const ReplanResult next = replanner.replan(state, in);
    EXPECT_EQ(next.status, ReplanStatus::kOk);
    in.commanded_configuration = next.configuration;
    in.measured_insertion = next.target_insertion;
    in.measured_tip =
        replanner.predicted_tip(next.configuration, next.target_insertion) + Eigen::Vector3d(0.2, -0.1, 0.0);
    sink += next.configuration.sum();
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_GT(step.iterations + state.replans, 0);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
