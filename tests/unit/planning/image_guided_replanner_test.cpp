// ImageGuidedReplanner (issue 15): error values for bad input, agreement with the plan when the image
// agrees with the model, and a measured tip error that is corrected.
#include "tendril/teleop/image_guided_replanner.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace tendril::teleop {
namespace {

struct Fixture {
  VesselCenterline vessel = VesselCenterline::from_polyline(make_synthetic_ica(1), 0.5);
  ConstantCurvatureCatheter model{nominal_planning_design()};
  ShapeErrorPlannerOptions options;
  ImageGuidedReplanner replanner{model, options, vessel};
  PathPlan plan = ShapeErrorPlanner(model, options).plan(vessel);

  Eigen::Vector4d configuration(const PlanStep& s) const {
    return {s.q[0], s.q[1], model.proximal_bend(s.q), model.distal_bend(s.q)};
  }
};

TEST(ImageGuidedReplanner, BadInputGivesAnErrorValueAndLeavesTheStateAlone) {
  Fixture f;
  ReplannerState state = f.replanner.make_state();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ReplanInput in;
  in.measured_tip = Eigen::Vector3d(nan, 0.0, 0.0);
  EXPECT_EQ(f.replanner.replan(state, in).status, ReplanStatus::kNotFinite);
  in.measured_tip.setZero();
  in.commanded_configuration[2] = std::numeric_limits<double>::infinity();
  EXPECT_EQ(f.replanner.replan(state, in).status, ReplanStatus::kNotFinite);
  in.commanded_configuration.setZero();
  in.measured_insertion = -0.5;
  EXPECT_EQ(f.replanner.replan(state, in).status, ReplanStatus::kInsertionOutOfRange);
  in.measured_insertion = f.vessel.length() + 1.0;
  EXPECT_EQ(f.replanner.replan(state, in).status, ReplanStatus::kInsertionOutOfRange);
  in.measured_insertion = 0.0;
  in.measured_tip = Eigen::Vector3d(20.0, 0.0, 0.0);  // 20 mm off a straight catheter at the entry
  EXPECT_EQ(f.replanner.replan(state, in).status, ReplanStatus::kTipOutlier);
  EXPECT_EQ(state.replans, 0);
  EXPECT_EQ(state.warm_start, Eigen::Vector4d::Zero());
  EXPECT_EQ(state.tip_error, Eigen::Vector3d::Zero());
  EXPECT_THROW(ImageGuidedReplanner(f.model, f.options, f.vessel, {.tip_error_gain = 0.0}),
               PlannerOptionsError);
  EXPECT_THROW(ImageGuidedReplanner(f.model, f.options, f.vessel, {.max_tip_correction = -1.0}),
               PlannerOptionsError);
}

// A tip exactly where the model puts it: the next target is the plan's next step.
TEST(ImageGuidedReplanner, AgreesWithThePlanWhenTheImageAgreesWithTheModel) {
  Fixture f;
  ReplannerState state = f.replanner.make_state();
  for (std::size_t k = 10; k + 1 < f.plan.steps.size(); k += 13) {
    const PlanStep& now = f.plan.steps[k];
    state.warm_start = {now.q[1], now.q[2], now.q[3], now.flexure};
    state.tip_error.setZero();
    ReplanInput in;
    in.commanded_configuration = f.configuration(now);
    in.measured_insertion = now.q[0];
    in.measured_tip = f.replanner.predicted_tip(in.commanded_configuration, now.q[0]);
    const ReplanResult next = f.replanner.replan(state, in);
    ASSERT_EQ(next.status, ReplanStatus::kOk);
    EXPECT_LT(next.tip_error.norm(), 1e-9);
    EXPECT_DOUBLE_EQ(next.target_insertion, f.plan.steps[k + 1].q[0]);
    const Eigen::Vector4d expected = f.configuration(f.plan.steps[k + 1]);
    EXPECT_NEAR(next.configuration[0], expected[0], 1e-12);
    EXPECT_NEAR(std::remainder(next.configuration[1] - expected[1], 2.0 * M_PI), 0.0, 1e-6) << k;
    EXPECT_NEAR(next.configuration[2], expected[2], 1e-6) << k;
    EXPECT_NEAR(next.configuration[3], expected[3], 1e-6) << k;
    // The roll is the one nearest the commanded roll.
    EXPECT_LE(std::abs(next.configuration[1] - in.commanded_configuration[1]), M_PI + 1e-12);
  }
}

// A tip measured 1 mm off the model's prediction: the replanned shape moves its model tip the other way,
// so that model + error lands nearer the centerline than uncorrected.
TEST(ImageGuidedReplanner, AMeasuredTipErrorShiftsTheNextTarget) {
  Fixture f;
  const PlanStep& now = f.plan.steps[20];
  ImageGuidedReplanner full(f.model, f.options, f.vessel, {.tip_error_gain = 1.0});
  ReplannerState state = full.make_state();
  state.warm_start = {now.q[1], now.q[2], now.q[3], now.flexure};
  ReplanInput in;
  in.commanded_configuration = f.configuration(now);
  in.measured_insertion = now.q[0];
  Eigen::Matrix3d base;
  Eigen::Vector3d origin;
  full.planner().section_base(now.q[0], base, origin);
  const Eigen::Vector3d offset = base.col(0);  // 1 mm along the section's x axis
  in.measured_tip = full.predicted_tip(in.commanded_configuration, now.q[0]) + offset;
  const ReplanResult next = full.replan(state, in);
  ASSERT_EQ(next.status, ReplanStatus::kOk);
  EXPECT_LT((next.tip_error - Eigen::Vector3d::UnitX()).norm(), 1e-9);
  // The corrected model tip (prediction at the target + the error) against the uncorrected plan's tip.
  const Eigen::Vector3d target = full.planner().prepared_vessel().points()[static_cast<std::size_t>(
      std::lround(next.target_insertion / 0.5))];
  Eigen::Matrix3d next_base;
  Eigen::Vector3d next_origin;
  full.planner().section_base(next.target_insertion, next_base, next_origin);
  const Eigen::Vector3d corrected =
      full.predicted_tip(next.configuration, next.target_insertion) + next_base * next.tip_error;
  const Eigen::Vector3d uncorrected =
      full.predicted_tip(f.configuration(f.plan.steps[21]), next.target_insertion) +
      next_base * next.tip_error;
  EXPECT_LT((corrected - target).norm(), (uncorrected - target).norm() - 0.3);
}

// A nearly straight catheter has no roll to follow. Along the straight part of a vessel, with the tip
// imaged with 0.25 mm noise, the target keeps the commanded roll (the solver's own roll jumped by up to
// ±3 rad from frame to frame there, and the roll drive swung for nothing); where the vessel bends, the
// roll follows the solver again. With the hold off (roll_hold_bend 0) the same frames move the roll.
TEST(ImageGuidedReplanner, AlongAStraightVesselTheRollStaysWhereItIs) {
  std::vector<Eigen::Vector3d> points;
  for (double z = 0.0; z < 40.0; z += 0.5) points.emplace_back(0.0, 0.0, z);
  const double radius = 30.0;
  for (double a = 0.0; a <= 70.0 * M_PI / 180.0; a += 0.5 / radius)
    points.emplace_back(radius * (1.0 - std::cos(a)), 0.0, 40.0 + radius * std::sin(a));
  const auto vessel = VesselCenterline::from_polyline({points, {}}, 0.5);
  const ConstantCurvatureCatheter model{nominal_planning_design()};
  const ShapeErrorPlannerOptions options;

  const auto run = [&](double hold, int& rolls_moved, bool& followed_in_bend) {
    const ImageGuidedReplanner replanner(model, options, vessel, {.roll_hold_bend = hold});
    ReplannerState state = replanner.make_state();
    std::mt19937 rng(5);
    std::normal_distribution<double> noise(0.0, 0.25);
    Eigen::Vector4d commanded(5.0, 0.3, 0.0, 0.0);
    rolls_moved = 0;
    followed_in_bend = false;
    for (double s = 5.0; s <= 70.0; s += 1.0) {
      ReplanInput in;
      in.commanded_configuration = commanded;
      in.measured_insertion = s;
      in.measured_tip =
          replanner.predicted_tip(commanded, s) + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
      const ReplanResult out = replanner.replan(state, in);
      EXPECT_EQ(out.status, ReplanStatus::kOk) << s;
      if (out.status != ReplanStatus::kOk) return;
      if (s <= 25.0) {
        // The catheter's 40 mm steerable section is inside the straight part up to here.
        if (std::abs(out.configuration[1] - commanded[1]) > 1e-12) ++rolls_moved;
        EXPECT_LT(std::max(std::abs(out.configuration[2]), std::abs(out.configuration[3])), 0.1) << s;
      } else if (!state.roll_held) {
        followed_in_bend = true;
      }
      commanded = out.configuration;
    }
  };
  int moved = 0;
  bool followed = false;
  run(0.05, moved, followed);
  EXPECT_EQ(moved, 0) << "the roll stayed at the commanded 0.3 rad along the straight part";
  EXPECT_TRUE(followed) << "in the bend the roll is the solver's again";
  run(0.0, moved, followed);
  EXPECT_GT(moved, 5) << "without the hold the noise moves the roll";
  EXPECT_THROW(ImageGuidedReplanner(model, options, vessel, {.roll_hold_bend = -0.1}), PlannerOptionsError);
}

}  // namespace
}  // namespace tendril::teleop
