// The ultrasound probe's controller (HybridPositionForceController on the UR5's SerialArmKinematics) closed
// around the SIMULATED arm and force sensor through the hardware seam only, as a robot plug-in runs it
// against a real UR5 over RTDE: the control cycle knows a hardware::JointInterface in velocity mode and a
// hardware::ForceSensor, and the runtime steps every hardware::HardwareComponent before and after it.
// The simulation around it: the arm's 500 Hz controller (one-period latency, 20 ms first-order drive
// within 8 rad/s²), the force sensor (1 kHz, 2 ms latency, 0.02 N noise) and tissue as a 0.5 N/mm spring.
// Stepped simulated time only: nothing here reads a clock.
//
// The reference numbers (the controller of Heunis et al. 2021, Appendix A, with Table 1's gains in an
// ideal-arm reference simulation: 1-D spring tissue, start 5 mm above, dt 6–8 ms): monotone convergence on
// 0.8 N with no overshoot, contact after ≈ 3.8 s, within 2 % of 0.8 N after 8.4 s at 0.5 N/mm.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <string>
#include <vector>

#include "tendril/drivers/hardware/joint_interface.hpp"
#include "tendril/drivers/hardware/sensor_interfaces.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/drivers/sim/simulated_force_sensor.hpp"
#include "tendril/drivers/sim/simulated_velocity_arm.hpp"
#include "tendril/teleop/hybrid_force_controller.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace tendril {
namespace {

using Clock = hardware::HardwareComponent::Clock;
constexpr double kContactForce = 0.8;                      // d_f (N), Table 1
constexpr double kSettleBand = 0.02 * kContactForce;       // ±2 %
constexpr std::int64_t kForceStaleNs = 20'000'000;         // Hard limits: force data stale > 20 ms → hold
constexpr double kReferenceSettleAtHalfNewtonPerMm = 8.4;  // s, ideal-arm reference simulation
constexpr double kReferenceContactTime = 3.8;              // s, ideal-arm reference simulation

std::int64_t nanoseconds(Clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

// A scanning pose with the probe pointing straight down (q2 + q3 + q4 = −π/2, q5 = −π/2).
std::array<double, 6> probe_down_pose() {
  constexpr double q2 = -1.2, q3 = 1.6;
  return {0.0, q2, q3, -std::numbers::pi / 2 - q2 - q3, -std::numbers::pi / 2, 0.0};
}

// The control cycle of a velocity-commanded probe arm, written only against the hardware interfaces.
class ProbeControlCycle {
 public:
  ProbeControlCycle(hardware::JointInterface& joints, const hardware::ForceSensor& force_sensor,
                    const teleop::SerialArmKinematics& model)
      : joints_(joints),
        force_sensor_(force_sensor),
        model_(model),
        data_(model.make_data()),
        controller_(teleop::HybridControlParameters{}) {}

  struct Result {
    bool powered = false;  // every joint's power stage is on: the controller ran
    teleop::HybridControlOutput output{};
  };

  Result run(Clock::time_point now, double dt, const Eigen::Isometry3d& target) {
    Result result;
    result.powered = true;
    teleop::HybridControlInputs in;
    in.target = target;
    for (std::size_t j = 0; j < joints_.size(); ++j) {
      hardware::JointFeedback fb;
      joints_.read(j, fb);
      in.q[static_cast<Eigen::Index>(j)] = fb.position;
      result.powered = result.powered && fb.power == hardware::PowerState::on;
    }
    const hardware::ForceReading f = force_sensor_.read();
    in.force = Eigen::Vector3d(f.force_n[0], f.force_n[1], f.force_n[2]);
    in.force_valid = f.valid && nanoseconds(now) - f.stamp_ns <= kForceStaleNs;
    if (!result.powered) {
      state_.reset();  // the controller starts when the arm is on
    } else {
      result.output = controller_.step(model_, data_, state_, in, dt);
    }
    for (std::size_t j = 0; j < joints_.size(); ++j) {
      const double v = result.powered ? result.output.joint_velocity[static_cast<Eigen::Index>(j)] : 0.0;
      joints_.write(j, hardware::JointCommand{.request = hardware::PowerRequest::on, .velocity = v});
    }
    return result;
  }

  const teleop::SerialArmData& data() const { return data_; }

 private:
  hardware::JointInterface& joints_;
  const hardware::ForceSensor& force_sensor_;
  const teleop::SerialArmKinematics& model_;
  teleop::SerialArmData data_;
  teleop::HybridPositionForceController controller_;
  teleop::HybridControlState state_;
};

// The simulated UR5 with its force sensor over a flat tissue `height` mm below the probe, stepped as the
// runtime steps hardware components in stepped simulation.
struct ProbeRig {
  ProbeRig(double height, double stiffness, double dt_)
      : dt(dt_),
        kinematics(teleop::ur5_parameters()),
        arm(sim::ur5_simulated_arm(probe_down_pose())),
        tissue(tissue_parameters(kinematics, height, stiffness)),
        sensor(arm, kinematics, tissue, sim::SimulatedForceSensorParameters{}),
        control(arm, sensor, kinematics) {
    for (hardware::HardwareComponent* c : components) c->configure({});
  }

  static sim::ContactSurfaceParameters tissue_parameters(const teleop::SerialArmKinematics& model,
                                                         double height, double stiffness) {
    sim::ContactSurfaceParameters p;
    p.pose = Eigen::Isometry3d::Identity();
    p.pose.translation().z() = start_tool(model).translation().z() - height;
    p.stiffness = stiffness;  // damping: the default 0.005 N·s/mm
    return p;
  }
  static Eigen::Isometry3d start_tool(const teleop::SerialArmKinematics& model) {
    teleop::SerialArmData d = model.make_data();
    const std::array<double, 6> q = probe_down_pose();
    model.forward_kinematics(Eigen::Map<const teleop::ArmVector>(q.data()), d);
    return d.tool;
  }
  // The probe pose at a point of the tissue surface `lateral` mm beside the start, probe axis straight
  // down (into the tissue).
  Eigen::Isometry3d surface_target(const Eigen::Vector3d& lateral = Eigen::Vector3d::Zero()) const {
    Eigen::Isometry3d target = start_tool(kinematics);
    target.translation() += lateral;
    target.translation().z() = tissue.pose().translation().z();
    return target;
  }

  ProbeControlCycle::Result cycle(const Eigen::Isometry3d& target) {
    now += std::chrono::microseconds(std::lround(dt * 1e6));
    for (hardware::HardwareComponent* c : components) c->step(now, dt, false);
    ProbeControlCycle::Result r = control.run(now, dt, target);
    for (hardware::HardwareComponent* c : components) c->step(now, dt, true);
    return r;
  }
  // The normal force the tissue really exerts on the probe face (noiseless).
  double true_force() const { return -sensor.truth().force_sensor[2]; }

  double dt;
  teleop::SerialArmKinematics kinematics;
  sim::SimulatedVelocityArm arm;
  sim::ContactSurface tissue;
  sim::SimulatedForceSensor sensor;
  std::vector<hardware::HardwareComponent*> components{&arm, &sensor};  // the arm first: the sensor reads it
  ProbeControlCycle control;
  Clock::time_point now = Clock::time_point{} + std::chrono::hours(1);
};

struct SettleRun {
  double contact_time = -1.0;  // s from the controller's start to the first touch
  double settle_time = -1.0;   // s from the controller's start to the last entry into 0.8 N ± 2 %
  double max_true_force = 0.0;
  double final_true_force = 0.0;
  double final_measured_mean = 0.0;  // the sensor's reading over the last 2 s
  double first_gate_time = -1.0;
  double gate_true_force = 0.0;  // when the gate first opened
  bool always_ok = true;
};

SettleRun settle(ProbeRig& rig, const Eigen::Isometry3d& target, double seconds) {
  SettleRun run;
  double t = -1.0;  // controller time; negative while the arm releases its brakes
  double measured_sum = 0.0;
  int measured_count = 0;
  const int cycles_total = static_cast<int>(std::lround(seconds / rig.dt));
  for (int k = 0; k < cycles_total; ++k) {
    const ProbeControlCycle::Result r = rig.cycle(target);
    if (!r.powered) continue;
    t = t < 0.0 ? 0.0 : t + rig.dt;
    run.always_ok = run.always_ok && r.output.status == teleop::HybridControlStatus::ok;
    const double f = rig.true_force();
    run.max_true_force = std::max(run.max_true_force, f);
    if (run.contact_time < 0.0 && rig.sensor.truth().in_contact) run.contact_time = t;
    if (std::abs(f - kContactForce) > kSettleBand) {
      run.settle_time = -1.0;
    } else if (run.settle_time < 0.0) {
      run.settle_time = t;
    }
    if (r.output.acquire && run.first_gate_time < 0.0) {
      run.first_gate_time = t;
      run.gate_true_force = f;
    }
    if (k >= cycles_total - static_cast<int>(std::lround(2.0 / rig.dt))) {
      measured_sum += r.output.normal_force;
      ++measured_count;
    }
    run.final_true_force = f;
  }
  run.final_measured_mean = measured_count > 0 ? measured_sum / measured_count : 0.0;
  return run;
}

TEST(ArmForceLoop, TheSimulatedDevicesSitBehindTheHardwareSeam) {
  ProbeRig rig(5.0, 0.5, 0.002);
  const hardware::JointInterface& joints = rig.arm;
  ASSERT_EQ(joints.size(), teleop::kArmJoints);
  for (std::size_t j = 0; j < joints.size(); ++j) {
    EXPECT_EQ(joints.command_mode(j), hardware::CommandMode::velocity) << "joint " << j;
  }
  const hardware::ForceSensor& force = rig.sensor;
  for (int k = 0; k < 5; ++k) rig.cycle(rig.surface_target());
  EXPECT_TRUE(force.read().valid);
}

// Force regulation on the simulated hardware: 5 mm above 0.5 N/mm tissue, at the 1 kHz-class loop (2 ms) and
// at the article's 8 ms (the reference simulation used 6–8 ms).
TEST(ArmForceLoop, SettlesOnTheArticlesContactForceWithoutOvershoot) {
  for (const double dt : {0.002, 0.008}) {
    ProbeRig rig(5.0, 0.5, dt);
    const SettleRun run = settle(rig, rig.surface_target(), 20.0);
    const std::string at = "dt " + std::to_string(dt) + " s";
    EXPECT_TRUE(run.always_ok) << at;
    EXPECT_EQ(rig.arm.truth().state, sim::ArmControllerState::running) << at;
    // No overshoot: the true force never leaves the 2 % band above 0.8 N (stricter than a ~0.85 N bound).
    EXPECT_LE(run.max_true_force, kContactForce + kSettleBand) << at;
    EXPECT_NEAR(run.final_true_force, kContactForce, kSettleBand) << at;
    EXPECT_NEAR(run.final_measured_mean, kContactForce, kSettleBand) << at;
    ASSERT_GT(run.settle_time, 0.0) << at;
    // The ideal-arm reference simulation: contact after ≈ 3.8 s, within 2 % after 8.4 s. The
    // simulated arm's lag and latency and the sensor's latency may cost a little, not much.
    EXPECT_NEAR(run.settle_time, kReferenceSettleAtHalfNewtonPerMm, 0.1 * kReferenceSettleAtHalfNewtonPerMm)
        << at;
    EXPECT_NEAR(run.contact_time, kReferenceContactTime, 0.5) << at;
    EXPECT_GT(run.first_gate_time, 0.0) << at << ": the acquisition gate opened";
    RecordProperty("settle_s_dt_" + std::to_string(dt), std::to_string(run.settle_time));
    RecordProperty("contact_s_dt_" + std::to_string(dt), std::to_string(run.contact_time));
    RecordProperty("max_true_force_N_dt_" + std::to_string(dt), std::to_string(run.max_true_force));
    RecordProperty("gate_s_dt_" + std::to_string(dt), std::to_string(run.first_gate_time));
  }
}

// From 30 mm above and 3 mm to the side the position law brings the probe down, hands over to force
// control before it can push, and the acquisition gate opens once position and force have held.
TEST(ArmForceLoop, ApproachesUnderPositionControlThenSettlesAndOpensTheGate) {
  ProbeRig rig(30.0, 0.5, 0.002);
  const Eigen::Isometry3d target = rig.surface_target(Eigen::Vector3d(3.0, 0.0, 0.0));
  const SettleRun run = settle(rig, target, 25.0);
  EXPECT_TRUE(run.always_ok);
  EXPECT_LE(run.max_true_force, kContactForce + kSettleBand);
  EXPECT_NEAR(run.final_true_force, kContactForce, kSettleBand);
  ASSERT_GT(run.first_gate_time, run.contact_time);
  // The gate's force tolerance (0.1 N) is wider than the 2 % settling band: it may open before the force
  // has settled, never before it is within 0.1 N of 0.8 N.
  EXPECT_NEAR(run.gate_true_force, kContactForce, 0.1);
  // Where the gate opened the probe sits over the surface point within d_p = 0.5 mm.
  const Eigen::Vector3d error = target.translation() - rig.control.data().tool.translation();
  EXPECT_LT(std::hypot(error.x(), error.y()), 0.5);
  RecordProperty("settle_s", std::to_string(run.settle_time));
  RecordProperty("gate_s", std::to_string(run.first_gate_time));
  RecordProperty("contact_s", std::to_string(run.contact_time));
  RecordProperty("max_true_force_N", std::to_string(run.max_true_force));
}

// Hard limits: a force sensor that falls silent in contact is stale after 20 ms; from that cycle the
// controller holds (zero joint velocities), the arm stops and the contact force stays where it was.
// When readings come back, control resumes.
TEST(ArmForceLoop, SilentForceSensorHoldsTheProbeInContact) {
  ProbeRig rig(5.0, 0.5, 0.002);
  const Eigen::Isometry3d target = rig.surface_target();
  const SettleRun run = settle(rig, target, 15.0);
  ASSERT_NEAR(run.final_true_force, kContactForce, kSettleBand);
  rig.sensor.set_silent(true);
  const std::int64_t last_stamp = rig.sensor.read().stamp_ns;
  int holding_cycles = 0;
  for (int k = 0; k < 250; ++k) {  // 0.5 s
    const ProbeControlCycle::Result r = rig.cycle(target);
    const bool stale = nanoseconds(rig.now) - last_stamp > kForceStaleNs;
    if (stale) {
      EXPECT_EQ(r.output.status, teleop::HybridControlStatus::force_lost) << "cycle " << k;
      EXPECT_TRUE(r.output.joint_velocity.isZero()) << "cycle " << k;
      ++holding_cycles;
    } else {
      EXPECT_EQ(r.output.status, teleop::HybridControlStatus::ok) << "cycle " << k;
    }
    EXPECT_NEAR(rig.true_force(), kContactForce, kSettleBand) << "cycle " << k;
  }
  EXPECT_GT(holding_cycles, 200);
  const sim::ArmTruth held = rig.arm.truth();
  for (const double v : held.velocity) EXPECT_NEAR(v, 0.0, 1e-9);  // first-order decay to rest
  EXPECT_EQ(held.state, sim::ArmControllerState::running) << "a hold, not a stop";
  rig.sensor.set_silent(false);
  const SettleRun resumed = settle(rig, target, 2.0);
  EXPECT_TRUE(resumed.always_ok);
  EXPECT_NEAR(resumed.final_true_force, kContactForce, kSettleBand);
}

}  // namespace
}  // namespace tendril
