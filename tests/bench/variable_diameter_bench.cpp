// Per-step cost of the variable-diameter MBCR's redundancy resolution (Abah 2022, §2.7.1: one 1 ms
// step of (2.34)–(2.36) with its three statics evaluations) and of its parts.
#include <benchmark/benchmark.h>

#include "tendril/teleop/variable_diameter_robot.hpp"
#include "tendril/teleop/variable_diameter_simulation.hpp"

namespace {

using namespace tendril::teleop;

struct Setup {
  VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  CircleTrajectoryParameters circle{};
  VariableDiameterData data = robot.make_data();
  VariableDiameterState state{};
  Setup() {
    state.configuration = circle_start_configuration(robot, circle);
    state.diameter_joint = robot.linkage().inner_radius_min() + 5.0;
  }
};

// One gradient-projection step: task inverse, ‖τ̃_s‖ and its central difference in a, limits, update.
void BM_VariableDiameterRedundancyStep(benchmark::State& state) {
  Setup s;
  const VariableDiameterState start = s.state;
  int i = 0;
  for (auto _ : state) {
    const double t = (++i % 1000) * s.circle.dt;
    if (i % 1000 == 0) s.state = start;
    const auto report = s.robot.step(s.state, circle_pose(s.circle, t), circle_twist(s.circle, t),
                                     s.circle.payload, s.circle.dt, true, s.data);
    benchmark::DoNotOptimize(report.force_norm);
  }
}
BENCHMARK(BM_VariableDiameterRedundancyStep);

// The fixed-diameter baseline step (no statics gradient).
void BM_VariableDiameterFixedStep(benchmark::State& state) {
  Setup s;
  const VariableDiameterState start = s.state;
  int i = 0;
  for (auto _ : state) {
    const double t = (++i % 1000) * s.circle.dt;
    if (i % 1000 == 0) s.state = start;
    const auto report = s.robot.step(s.state, circle_pose(s.circle, t), circle_twist(s.circle, t),
                                     s.circle.payload, s.circle.dt, false, s.data);
    benchmark::DoNotOptimize(report.force_norm);
  }
}
BENCHMARK(BM_VariableDiameterFixedStep);

// One evaluation of the 13 actuation forces (2.30) of the stack.
void BM_VariableDiameterActuation(benchmark::State& state) {
  Setup s;
  StackActuation tau;
  for (auto _ : state) {
    s.robot.actuation(s.state.configuration, s.state.diameter_joint, s.circle.payload, s.data, tau);
    benchmark::DoNotOptimize(tau);
  }
}
BENCHMARK(BM_VariableDiameterActuation);

// The diameter limits: ASL range and the disk-interference limit of all three segments.
void BM_VariableDiameterLimits(benchmark::State& state) {
  Setup s;
  for (auto _ : state) {
    const DiameterLimits limits = s.robot.diameter_limits(s.state.configuration);
    benchmark::DoNotOptimize(limits.upper);
  }
}
BENCHMARK(BM_VariableDiameterLimits);

}  // namespace
