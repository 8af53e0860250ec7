// Per-cycle cost of the ultrasound sweep's joint-velocity computation on the control thread (Heunis et al.
// 2021: "joint velocities take an average of 6 ms to be calculated and prescribed"; issue 17 targets ≤ 1 ms):
// UltrasoundSweep::step — the via-point re-expressed from the limb's tracked pose (motion
// compensation), the HybridPositionForceController (kinematics, Jacobian, damped inverse, caps), the
// phase machine — on a plan made from the SIMULATED limb with the shipped defaults.
#include <benchmark/benchmark.h>

#include <numbers>

#include "serial_arm/limb_simulation.hpp"
#include "serial_arm/ultrasound_sweep.hpp"
#include "tendril/teleop/cartesian_control.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace {

using namespace tendril;

void BM_SweepCycle(benchmark::State& state) {
  server::UltrasoundSettings settings;
  settings.limb.rest_pose.translation() = Eigen::Vector3d(-610.0, -109.0, 150.0);
  settings.limb.y = {0.0, 0.0, 4.0, 1.0, 0.0};
  settings.limb.z = {0.0, 2.0, 0.0, 0.0, 1.0};
  settings.limb.rx = {0.0, 0.0, 0.03, 0.01, 0.0};
  const server::LimbSimulation limb(settings.limb);
  const server::SweepPlan plan = server::make_sweep_plan(limb, settings);
  server::SweepPlanData data;
  data.count = static_cast<int>(plan.via_points.size());
  for (int i = 0; i < data.count; ++i)
    Eigen::Map<Eigen::Matrix4d>(data.via_points[static_cast<std::size_t>(i)].data()) =
        plan.via_points[static_cast<std::size_t>(i)].matrix();
  const teleop::SerialArmKinematics model(teleop::ur5_parameters());
  teleop::SerialArmData arm = model.make_data();
  server::UltrasoundSweep sweep(settings, teleop::TaskSpaceGains{}, teleop::CartesianLimits{});
  sweep.load(data);
  sweep.command(server::SweepAction::pre_position, 0.0);
  server::UltrasoundSweep::Inputs in;
  in.q << 0.0, -1.2, 1.6, -std::numbers::pi / 2 + 1.2 - 1.6, -std::numbers::pi / 2, 0.0;
  in.force_valid = true;
  in.dt = 0.001;
  teleop::CartesianCommandResult out;
  for (auto _ : state) {
    in.t += in.dt;
    in.world_T_limb = limb.pose_at(in.t);  // a new limb pose every cycle (the feed-forward runs too)
    in.limb_t = in.t;
    benchmark::DoNotOptimize(sweep.step(model, arm, in, out));
    benchmark::DoNotOptimize(out.joints.joint_velocity);
  }
}
BENCHMARK(BM_SweepCycle);

}  // namespace
