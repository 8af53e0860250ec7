// Per-cycle cost of the arm's control path (Heunis et al. 2021: "joint velocities take an average of 6 ms to
// be calculated and prescribed"; we target < 1 ms): kinematics, the damped inverse, the Heunis et al. 2021
// hybrid controller, and the Cartesian commands.
#include <benchmark/benchmark.h>

#include <numbers>

#include "tendril/teleop/cartesian_control.hpp"
#include "tendril/teleop/hybrid_force_controller.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace {

using namespace tendril::teleop;

ArmVector scanning_pose() {
  ArmVector q;
  q << 0.1, -1.2, 1.6, -std::numbers::pi / 2 + 1.2 - 1.6, -std::numbers::pi / 2, 0.2;
  return q;
}

void BM_ArmForwardKinematics(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ArmVector q = scanning_pose();
  for (auto _ : state) {
    q[0] += 1e-9;
    arm.forward_kinematics(q, data);
    benchmark::DoNotOptimize(data.tool);
  }
}
BENCHMARK(BM_ArmForwardKinematics);

void BM_ArmKinematicsAndJacobian(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ArmVector q = scanning_pose();
  for (auto _ : state) {
    q[0] += 1e-9;
    arm.update(q, data);
    benchmark::DoNotOptimize(data.jacobian);
  }
}
BENCHMARK(BM_ArmKinematicsAndJacobian);

void BM_ArmDampedLeastSquares(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ArmVector q = scanning_pose();
  q[4] =
      state.range(0) == 0 ? -std::numbers::pi / 2 : 0.01;  // well-conditioned or near the wrist singularity
  arm.update(q, data);
  Twist v;
  v << 20.0, -10.0, 5.0, 0.02, 0.0, -0.05;
  ArmVector qd;
  for (auto _ : state) {
    arm.damped_least_squares(data, v, qd);
    benchmark::DoNotOptimize(qd);
  }
}
BENCHMARK(BM_ArmDampedLeastSquares)->Arg(0)->Arg(1);

// One full control cycle of the ultrasound probe controller: FK, Jacobian, A1–A12, DLS, clamps, gate.
void BM_HybridPositionForceStep(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  const HybridPositionForceController controller(HybridControlParameters{});
  HybridControlState s;
  HybridControlInputs in;
  in.q = scanning_pose();
  arm.forward_kinematics(in.q, data);
  in.target = data.tool;
  in.target.translation() += Eigen::Vector3d(2.0, -1.0, -3.0);
  in.force = Eigen::Vector3d(0.0, 0.0, -0.7);
  in.force_valid = true;
  for (auto _ : state) {
    in.q[0] += 1e-9;
    benchmark::DoNotOptimize(controller.step(arm, data, s, in, 0.002));
  }
}
BENCHMARK(BM_HybridPositionForceStep);

void BM_ServoCp(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ArmVector q = scanning_pose();
  arm.forward_kinematics(q, data);
  Eigen::Isometry3d goal = data.tool;
  goal.translation() += Eigen::Vector3d(30.0, 0.0, 10.0);
  const TaskSpaceGains gains;
  const CartesianLimits limits;
  for (auto _ : state) {
    q[0] += 1e-9;
    benchmark::DoNotOptimize(servo_cp(arm, data, q, goal, gains, limits, 0.002));
  }
}
BENCHMARK(BM_ServoCp);

void BM_MoveCpTrack(benchmark::State& state) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ArmVector q = scanning_pose();
  arm.forward_kinematics(q, data);
  Eigen::Isometry3d goal = data.tool;
  goal.translation() += Eigen::Vector3d(80.0, -20.0, 10.0);
  goal.linear() = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()) * goal.linear();
  CartesianTrajectory trajectory;
  trajectory.plan(data.tool, goal, CartesianLimits{}, 0.0);
  const TaskSpaceGains gains;
  double t = 0.0;
  for (auto _ : state) {
    t += 1e-4;
    if (t > trajectory.duration()) t = 0.0;
    benchmark::DoNotOptimize(track(arm, data, q, trajectory.sample(t), gains, CartesianLimits{}, 0.002));
  }
}
BENCHMARK(BM_MoveCpTrack);

}  // namespace
