// Per-tick cost of the SRMC control path: quintic sample, PID, forward kinematics, supervisor.
#include <benchmark/benchmark.h>

#include <array>
#include <memory>

#include "tendril/safety/safety_supervisor.hpp"
#include "tendril/teleop/active_compliance.hpp"
#include "tendril/teleop/catheter_configuration.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/pid.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"

namespace {

using tendril::teleop::ConstantCurvatureCatheter;
using JV = ConstantCurvatureCatheter::JointVector;

constexpr std::array<double, 4> kGoal{20.0, 0.8, 0.4, -0.5};

void BM_QuinticSample(benchmark::State& state) {
  tendril::teleop::QuinticInterpolator interp(4);
  interp.reset(std::array<double, 4>{});
  interp.retarget(0.0, kGoal, 2.0, 5.0);
  std::array<double, 4> q{}, qd{}, qdd{};
  double t = 0.0;
  for (auto _ : state) {
    interp.sample(t, q, qd, qdd);
    benchmark::DoNotOptimize(q);
    t += 1e-4;
    if (t > interp.duration()) t = 0.0;
  }
}
BENCHMARK(BM_QuinticSample);

void BM_QuinticRetargetMidMotion(benchmark::State& state) {
  tendril::teleop::QuinticInterpolator interp(4);
  interp.reset(std::array<double, 4>{});
  interp.retarget(0.0, kGoal, 2.0, 5.0);
  const double t_mid = 0.4 * interp.duration();
  const std::array<double, 4> other{-5.0, -0.5, -0.3, 0.6};
  for (auto _ : state) {
    // Re-seed from the same mid-motion state each time so every iteration does the same search.
    interp.reset(std::array<double, 4>{});
    interp.retarget(0.0, kGoal, 2.0, 5.0);
    benchmark::DoNotOptimize(interp.retarget(t_mid, other, 2.0, 5.0));
  }
}
BENCHMARK(BM_QuinticRetargetMidMotion);

void BM_Pid(benchmark::State& state) {
  tendril::teleop::Pid pid(
      {.kp = 2.0, .ki = 1.0, .kd = 0.01, .output_limit = 5.0, .derivative_filter_time = 0.002});
  double y = 0.0;
  for (auto _ : state) {
    const double u = pid.update(1.0, y, 1e-3);
    y += 1e-3 * (u - y);
    benchmark::DoNotOptimize(y);
  }
}
BENCHMARK(BM_Pid);

void BM_TipPose(benchmark::State& state) {
  const ConstantCurvatureCatheter cat(tendril::teleop::CatheterParameters{});
  JV q(10.0, 0.3, 0.4, -0.5);
  for (auto _ : state) {
    benchmark::DoNotOptimize(cat.tip_pose(q));
    q[2] += 1e-9;
  }
}
BENCHMARK(BM_TipPose);

void BM_TipJacobian(benchmark::State& state) {
  const ConstantCurvatureCatheter cat(tendril::teleop::CatheterParameters{});
  const JV q(10.0, 0.3, 0.4, -0.5);
  for (auto _ : state) benchmark::DoNotOptimize(cat.tip_position_jacobian(q));
}
BENCHMARK(BM_TipJacobian);

void BM_Backbone(benchmark::State& state) {
  const ConstantCurvatureCatheter cat(tendril::teleop::CatheterParameters{});
  const JV q(10.0, 0.3, 0.4, -0.5);
  std::array<Eigen::Vector3d, 128> points;
  const auto per_segment = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(cat.backbone(q, per_segment, points));
}
BENCHMARK(BM_Backbone)->Arg(10)->Arg(50);

// One full 1 kHz tick for a 4-joint catheter: sample, 4 PIDs, tip pose, clamp, supervisor tick.
void BM_ControlTick(benchmark::State& state) {
  tendril::teleop::QuinticInterpolator interp(4);
  interp.reset(std::array<double, 4>{10.0, 0.0, 0.0, 0.0});
  interp.retarget(0.0, kGoal, 2.0, 5.0);
  std::array<tendril::teleop::Pid, 4> pids;
  pids.fill(tendril::teleop::Pid({.kp = 2.0, .ki = 1.0, .kd = 0.01, .output_limit = 5.0}));
  const ConstantCurvatureCatheter cat(tendril::teleop::CatheterParameters{});
  auto supervisor = std::make_unique<tendril::safety::SafetySupervisor>(tendril::safety::LimitSet({
      {"insertion", "mm", 0.0, 100.0, 1.0, 5.0, 20.0, 50.0},
      {"roll", "rad", -3.0, 3.0, 0.1, 1.5, 5.0, 5.0},
      {"proximal", "mm", -1.0, 1.0, 0.05, 0.5, 2.0, 5.0},
      {"distal", "mm", -1.0, 1.0, 0.05, 0.5, 2.0, 5.0},
  }));
  supervisor->request(0.0, tendril::safety::StateCommand::kEnable);
  std::array<double, 4> q{}, qd{}, qdd{}, measured{10.0, 0.0, 0.0, 0.0}, effort{};
  double t = 0.0;
  for (auto _ : state) {
    interp.sample(t, q, qd, qdd);
    supervisor->clamp_setpoint(q, qd);
    for (std::size_t j = 0; j < 4; ++j) effort[j] = pids[j].update(q[j], measured[j], 1e-3);
    benchmark::DoNotOptimize(cat.tip_pose(JV(measured[0], measured[1], measured[2], measured[3])));
    benchmark::DoNotOptimize(supervisor->tick(t, measured, q));
    benchmark::DoNotOptimize(effort);
    t += 1e-3;
    if (t > interp.duration()) t = 0.0;
  }
}
BENCHMARK(BM_ControlTick);

// Configuration controller step: one step() of configuration-space control (Abah 2022, §4.7.2): quintic
// sample in ψ, (4.21) twice (midpoint rule) and the drift correction, on the dissertation's placeholder
// model. The goal alternates between two bend configurations whenever a motion ends, so every step is
// mid-motion except the one that retargets.
void BM_ConfigurationControllerStep(benchmark::State& state) {
  using tendril::teleop::CatheterConfigurationMap;
  using V4 = CatheterConfigurationMap::Vector4;
  const CatheterConfigurationMap map(
      tendril::teleop::constant_curvature_modal_parameters(tendril::teleop::CatheterParameters{}),
      tendril::teleop::ConfigurationRateParameters{});
  tendril::teleop::ConfigurationSpaceController controller(map, V4(2.0, 0.5, 0.1, 0.2),
                                                           V4(5.0, 2.0, 0.5, 1.0));
  const std::array<V4, 2> goals{V4(20.0, 0.8, 0.05, 0.3), V4(10.0, -0.4, -0.02, 0.0)};
  V4 q(10.0, 0.0, 0.0, 0.0), qd = V4::Zero();
  double t = 0.0;
  std::size_t next = 0;
  controller.reset(t, q);
  controller.retarget(t, goals[next]);
  for (auto _ : state) {
    t += 1e-3;
    benchmark::DoNotOptimize(controller.step(t, 1e-3, q, qd));
    benchmark::DoNotOptimize(q);
    if (controller.done(t)) controller.retarget(t, goals[next ^= 1]);
  }
}
BENCHMARK(BM_ConfigurationControllerStep)->Name("configuration controller step");

// The SRMC's mid-level plus low-level compute per 1 kHz tick, by mode (issue target: < 20 µs):
// the mode's setpoint law, the supervisor's clamp and tick, four joint PIDs (the drives' position
// loop in simulation) and the tip pose for display. 0 = configuration (eq. 4.21), 1 = active
// compliance (eqs. 4.24–4.26), 2 = telemanipulation (joystick velocity integrated).
void BM_SrmcMidAndLowLevelTick(benchmark::State& state) {
  using tendril::teleop::CatheterConfigurationMap;
  using V4 = CatheterConfigurationMap::Vector4;
  tendril::teleop::CatheterParameters nominal;
  nominal.proximal_length = 22.0;
  nominal.distal_length = 18.8;
  nominal.plane_offset = -0.76;
  const CatheterConfigurationMap map(tendril::teleop::constant_curvature_modal_parameters(nominal),
                                     tendril::teleop::ConfigurationRateParameters{});
  tendril::teleop::ConfigurationSpaceController controller(map, V4(10.0, 1.5, 0.18, 0.48),
                                                           V4(50.0, 10.0, 1.8, 4.8));
  const tendril::teleop::ActiveComplianceParameters compliance;
  std::array<tendril::teleop::Pid, 4> pids;
  pids.fill(tendril::teleop::Pid({.kp = 2.0, .ki = 1.0, .kd = 0.01, .output_limit = 5.0}));
  const ConstantCurvatureCatheter cat(tendril::teleop::CatheterParameters{});
  auto supervisor = std::make_unique<tendril::safety::SafetySupervisor>(tendril::safety::LimitSet({
      {"insertion", "mm", 0.0, 120.0, 0.5, 10.0, 50.0, 50.0},
      {"roll", "rad", -3.14, 3.14, 0.02, 1.5, 10.0, 5.0},
      {"proximal_bend", "mm", -6.0, 10.0, 0.1, 2.0, 20.0, 5.0},
      {"distal_bend", "mm", -5.0, 5.0, 0.1, 2.0, 20.0, 5.0},
  }));
  supervisor->request(0.0, tendril::safety::StateCommand::kEnable);
  const std::array<V4, 2> goals{V4(20.0, 0.8, 0.3, -0.4), V4(10.0, -0.4, -0.1, 0.2)};
  std::size_t next = 0;
  V4 q(10.0, 0.0, 0.0, 0.0), qd = V4::Zero();
  std::array<double, 4> measured{10.0, 0.0, 0.0, 0.0}, effort{}, q_des{}, qd_des{};
  const std::array<double, 2> deflection{-0.4, 0.2};
  const std::array<double, 4> stick{0.5, 0.0, 0.3, -0.2}, max_speed{3.0, 0.5, 1.0, 1.0};
  double t = 0.0;
  controller.reset(t, q);
  controller.retarget(t, goals[next]);
  const auto mode = state.range(0);
  for (auto _ : state) {
    t += 1e-3;
    if (mode == 0) {
      controller.step(t, 1e-3, q, qd);
      if (controller.done(t)) controller.retarget(t, goals[next ^= 1]);
      for (int j = 0; j < 4; ++j) {
        q_des[static_cast<std::size_t>(j)] = q[j];
        qd_des[static_cast<std::size_t>(j)] = qd[j];
      }
    } else if (mode == 1) {
      tendril::teleop::apply_active_compliance(compliance, measured, deflection, 1e-3, q_des);
    } else {
      for (std::size_t j = 0; j < 4; ++j) {
        qd_des[j] = stick[j] * max_speed[j];
        q_des[j] += qd_des[j] * 1e-3;
      }
      if (q_des[0] > 100.0) q_des = measured;
    }
    supervisor->clamp_setpoint(q_des, qd_des);
    for (std::size_t j = 0; j < 4; ++j) effort[j] = pids[j].update(q_des[j], measured[j], 1e-3);
    benchmark::DoNotOptimize(cat.tip_pose(JV(measured[0], measured[1], measured[2], measured[3])));
    benchmark::DoNotOptimize(supervisor->tick(t, measured, q_des));
    benchmark::DoNotOptimize(effort);
  }
}
BENCHMARK(BM_SrmcMidAndLowLevelTick)->Arg(0)->Arg(1)->Arg(2)->ArgName("mode");

}  // namespace
