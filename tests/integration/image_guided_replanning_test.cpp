// Live replanning (issue 15, Abah 2022, §4.11 high-level controller) closed around a simulated catheter
// in stepped time, no threads, no clocks. The "plant" is the same kinematics as the model with other
// parameters: 15 % lower actuation-loss slopes (eqs. 4.13–4.14: less bend per mm of drive), 20 % more
// coupling (eq. 4.15), a 10 % longer distal segment and 1 mm of insertion slack. Its tip is "imaged"
// with 0.25 mm Gaussian noise per axis and its inserted length with 0.1 mm.
//
// Both runs feed their targets through the configuration mode's own controller
// (ConfigurationSpaceController with the model's CatheterConfigurationMap: loss and coupling
// compensation, eq. 4.21, quintic in ψ, 1 kHz ticks) — the same conversion the srmc's configuration
// mode applies; the server's path_following mode itself plays joint targets and is not used here.
//   open loop:   the pre-operative plan's configurations ψ*(q1), one step after another;
//   closed loop: every step, ImageGuidedReplanner from the measured tip and insertion.
// The shaft is taken to conform to the vessel (the planner's convention) and the wall is not simulated,
// so the tip's distance to the centerline is the shape error that remains at the tip.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

#include "tendril/teleop/catheter_configuration.hpp"
#include "tendril/teleop/image_guided_replanner.hpp"

namespace tendril::teleop {
namespace {

using Vector4 = Eigen::Vector4d;

// The srmc's planning design (config/robots/srmc.json "kinematics": k = 1.4 rad/mm times the loss slopes).
CatheterParameters srmc_design() {
  CatheterParameters p;
  p.proximal_length = 22.0;
  p.distal_length = 18.8;
  p.plane_offset = -0.76;
  p.proximal_curvature_gain = 0.0882;
  p.distal_curvature_gain = 0.238;
  return p;
}

ShapeErrorPlannerOptions srmc_planner_options() {
  ShapeErrorPlannerOptions o;   // ds 0.5 (the vessel's), dq1 3
  o.proximal_drive_min = -5.9;  // srmc joint limits less the soft margins
  o.proximal_drive_max = 9.9;
  o.distal_drive_min = -4.9;
  o.distal_drive_max = 4.9;
  return o;
}

struct CatheterVariant {
  double loss_slope_scale = 1.0;
  double coupling_scale = 1.0;
  double distal_length_scale = 1.0;
  double insertion_slack = 0.0;  // mm of commanded insertion that does not reach the tip
};

// The configuration map (ψ ↔ drive positions) of the srmc's "catheter.model" with a variant applied.
CatheterConfigurationMap configuration_map(const CatheterVariant& v) {
  CatheterParameters nominal;
  nominal.proximal_length = 22.0;
  nominal.distal_length = 18.8 * v.distal_length_scale;
  nominal.plane_offset = -0.76;
  nominal.proximal_curvature_gain = nominal.distal_curvature_gain = 1.4;
  ConfigurationRateParameters rates;
  rates.proximal_loss = {0.063 * v.loss_slope_scale, -0.049};
  rates.distal_loss = {0.17 * v.loss_slope_scale, 0.019};
  rates.proximal_outer_radius = 0.6 * v.coupling_scale;
  rates.plane_offset = -0.76;
  return CatheterConfigurationMap(constant_curvature_modal_parameters(nominal), rates);
}

double distance_to_polyline(const Eigen::Vector3d& x, const std::vector<Eigen::Vector3d>& line) {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < line.size(); ++i) {
    const Eigen::Vector3d d = line[i + 1] - line[i];
    const double u = std::clamp((x - line[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (line[i] + u * d - x).norm());
  }
  return best;
}

struct RunResult {
  double rms = 0.0;  // tip-to-centerline distance at the end of every step (mm)
  double max = 0.0;
  int steps = 0;
};

class Simulation {
 public:
  Simulation(const VesselCenterline& vessel, const CatheterVariant& plant, std::uint32_t seed)
      : model_map_(configuration_map({})),
        plant_map_(configuration_map(plant)),
        plant_variant_(plant),
        plant_shape_(ConstantCurvatureCatheter(plant_design(plant)), srmc_planner_options()),
        controller_(model_map_, Vector4(10.0, 1.5, 0.5, 0.5), Vector4(50.0, 10.0, 5.0, 5.0)),
        rng_(seed) {
    plant_shape_.prepare(vessel);
    EXPECT_TRUE(model_map_.joints(Vector4::Zero(), q_));
    controller_.reset(t_, q_);
  }

  static CatheterParameters plant_design(const CatheterVariant& v) {
    CatheterParameters p = srmc_design();
    p.distal_length *= v.distal_length_scale;
    return p;
  }

  // Moves to ψ through the configuration controller and lets the drift correction settle.
  void move_to(const Vector4& psi) {
    ASSERT_TRUE(controller_.retarget(t_, psi)) << psi.transpose();
    commanded_ = psi;
    Vector4 qd;
    int settle = 0;
    for (int tick = 0; tick < 60000 && settle < 200; ++tick) {
      t_ += kDt;
      ASSERT_TRUE(controller_.step(t_, kDt, q_, qd));
      if (controller_.done(t_)) ++settle;
    }
    ASSERT_EQ(settle, 200) << "move did not finish";
  }

  double tip_arc_length() const {
    const double length = plant_shape_.prepared_vessel().length();
    return std::clamp(q_[0] - plant_variant_.insertion_slack, 0.0, length);
  }

  // The real tip: the plant's bends from its own map at the drive positions, its own lengths.
  Eigen::Vector3d true_tip() const {
    const Vector4 psi = plant_map_.configuration(q_);
    const auto& P = plant_shape_.model().parameters();
    const ShapeErrorPlanner::JointVector q(0.0, psi[1], psi[2] / P.proximal_curvature_gain,
                                           psi[3] / P.distal_curvature_gain);
    Eigen::Matrix3d rotation;
    Eigen::Vector3d position;
    plant_shape_.section_base(tip_arc_length(), rotation, position);
    return rotation * plant_shape_.steerable_point(q, P.proximal_length + P.distal_length, nullptr) +
           position;
  }

  ReplanInput measure() {
    std::normal_distribution<double> tip_noise(0.0, 0.25), insertion_noise(0.0, 0.1);
    ReplanInput in;
    in.measured_tip = true_tip() + Eigen::Vector3d(tip_noise(rng_), tip_noise(rng_), tip_noise(rng_));
    in.measured_insertion =
        std::clamp(tip_arc_length() + insertion_noise(rng_), 0.0, plant_shape_.prepared_vessel().length());
    in.commanded_configuration = commanded_;
    return in;
  }

  void record(RunResult& r) const {
    const double d = distance_to_polyline(true_tip(), plant_shape_.prepared_vessel().points());
    r.rms += d * d;
    r.max = std::max(r.max, d);
    ++r.steps;
  }

  const Vector4& commanded() const { return commanded_; }

 private:
  static constexpr double kDt = 1e-3;
  CatheterConfigurationMap model_map_, plant_map_;
  CatheterVariant plant_variant_;
  ShapeErrorPlanner plant_shape_;  // only its vessel frames and closed-form shape
  ConfigurationSpaceController controller_;
  std::mt19937 rng_;
  double t_ = 0.0;
  Vector4 q_ = Vector4::Zero();  // drive positions (the LLC is taken to track them exactly)
  Vector4 commanded_ = Vector4::Zero();
};

VesselCenterline test_vessel() {
  SyntheticIcaOptions o;
  o.point_spacing = 0.2;
  o.length = 120.0;  // the srmc's insertion range
  // Bends of 20–40 mm radius: the srmc's assembled bend gains (at most ~0.9 + 1.2 rad over 40.8 mm within
  // its drive limits) cannot follow the ICA's 5–15 mm bends (plan tip errors of 5–11 mm there), and the
  // comparison is about the plant's mismatch, not about a design that does not fit.
  o.min_bend_radius = 20.0;
  o.max_bend_radius = 40.0;
  return VesselCenterline::from_polyline(make_synthetic_ica(7, o), 0.5);
}

RunResult open_loop(const VesselCenterline& vessel, const CatheterVariant& plant, std::uint32_t seed) {
  const ConstantCurvatureCatheter model(srmc_design());
  const PathPlan plan = ShapeErrorPlanner(model, srmc_planner_options()).plan(vessel);
  Simulation sim(vessel, plant, seed);
  RunResult r;
  for (const PlanStep& step : plan.steps) {
    const double roll =
        sim.commanded()[1] + std::remainder(step.q[1] - sim.commanded()[1], 2.0 * std::numbers::pi);
    sim.move_to(Vector4(step.q[0], roll, model.proximal_bend(step.q), model.distal_bend(step.q)));
    sim.record(r);
  }
  r.rms = std::sqrt(r.rms / r.steps);
  return r;
}

RunResult closed_loop(const VesselCenterline& vessel, const CatheterVariant& plant, std::uint32_t seed) {
  const ImageGuidedReplanner replanner(ConstantCurvatureCatheter(srmc_design()), srmc_planner_options(),
                                       vessel);
  ReplannerState state = replanner.make_state();
  Simulation sim(vessel, plant, seed);
  const auto steps = static_cast<int>(std::floor(vessel.length() / 3.0 + 1e-9));
  RunResult r;
  for (int k = 0; k < steps; ++k) {
    const ReplanResult next = replanner.replan(state, sim.measure());
    EXPECT_EQ(next.status, ReplanStatus::kOk) << "step " << k;
    if (next.status != ReplanStatus::kOk) break;
    sim.move_to(next.configuration);
    sim.record(r);
  }
  r.rms = std::sqrt(r.rms / r.steps);
  return r;
}

TEST(ImageGuidedReplanning, ClosedLoopKeepsTheTipNearerTheCenterlineThanThePlanAlone) {
  const VesselCenterline vessel = test_vessel();
  const CatheterVariant plant{
      .loss_slope_scale = 0.85, .coupling_scale = 1.2, .distal_length_scale = 1.1, .insertion_slack = 1.0};
  // Noise seed 3. Over seeds 1–6 the closed loop measured 1.29–1.95 mm RMS (gcc), open loop 3.39 mm.
  const RunResult open = open_loop(vessel, plant, 3);
  const RunResult closed = closed_loop(vessel, plant, 3);
  std::printf(
      "[ replan ] perturbed plant: RMS tip-to-centerline open loop %.3f mm (max %.3f), closed loop "
      "%.3f mm (max %.3f), %d / %d steps\n",
      open.rms, open.max, closed.rms, closed.max, open.steps, closed.steps);
  EXPECT_EQ(open.steps, 40);
  EXPECT_EQ(closed.steps, 40);
  EXPECT_LT(closed.rms, 0.6 * open.rms);
}

TEST(ImageGuidedReplanning, WithTheModelsOwnParametersBothLoopsAgree) {
  // Noise seed 1. Over seeds 1–5 the closed loop measured 0.92–1.39 mm against 0.91 mm open loop (a
  // noisy fix can tip a step into a neighbouring local minimum); without noise 0.99 mm.
  const std::uint32_t seed = 1;
  const VesselCenterline vessel = test_vessel();
  const RunResult open = open_loop(vessel, {}, seed);
  const RunResult closed = closed_loop(vessel, {}, seed);
  std::printf(
      "[ replan ] identical plant: RMS tip-to-centerline open loop %.3f mm (max %.3f), closed loop "
      "%.3f mm (max %.3f)\n",
      open.rms, open.max, closed.rms, closed.max);
  EXPECT_NEAR(closed.rms, open.rms, 0.5);
}

}  // namespace
}  // namespace tendril::teleop
