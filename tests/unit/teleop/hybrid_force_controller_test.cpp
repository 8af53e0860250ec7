// Heunis et al. 2021, Appendix A with Table 1's numbers.
#include "tendril/teleop/hybrid_force_controller.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <random>
#include <stdexcept>

#include "allocation_counter.hpp"
#include "arm_test_support.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::teleop {
namespace {

using test::SpringFloor;
using test::VelocityArm;
constexpr double kPi = std::numbers::pi;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- the laws on their own ----

// V_d(1 − e^{−|E|/μ}) at 50, 25, 5, 0.5 mm is 43.2, 31.6, 9.1, 0.99 mm/s.
TEST(TaskSpaceVelocity, PositionSpeedProfileHasTheArticlesNumbers) {
  const TaskSpaceGains g;
  const auto speed = [&](double e) { return linear_velocity(Eigen::Vector3d(e, 0, 0), g, 0.0).norm(); };
  EXPECT_NEAR(speed(50.0), 43.23, 0.01);
  EXPECT_NEAR(speed(25.0), 31.61, 0.01);
  EXPECT_NEAR(speed(5.0), 9.06, 0.01);
  EXPECT_NEAR(speed(0.5), 0.990, 0.001);
  EXPECT_NEAR(speed(1e4), 50.0, 1e-9);
  // The direction is the error's.
  const Eigen::Vector3d e(3.0, -4.0, 12.0);
  EXPECT_NEAR(linear_velocity(e, g, 0.002).normalized().dot(e.normalized()), 1.0, 1e-12);
}

// The per-iteration integral gate e^{−(|E|/μ)⁵}: ≈ 1 near the target, ≈ 0 beyond 40 mm.
TEST(TaskSpaceVelocity, IntegralTermActsOnlyNearTheTarget) {
  const TaskSpaceGains g;
  const auto extra = [&](double e) {
    return linear_velocity(Eigen::Vector3d(e, 0, 0), g, 0.008).x() -
           linear_velocity(Eigen::Vector3d(e, 0, 0), g, 0.0).x();
  };
  EXPECT_NEAR(extra(5.0), 20.0 * 0.008 * 5.0, 1e-3);                     // gate ≈ 1
  EXPECT_NEAR(extra(25.0), 20.0 * 0.008 * 25.0 * std::exp(-1.0), 1e-9);  // gate = e^{−1}
  EXPECT_LT(extra(45.0), 1e-6);                                          // gate ≈ 0
}

// Step response: a 50 mm step reaches |E| < 0.5 mm in under 3 s with no overshoot (our check
// simulation: 2.7 s at dt = 8 ms), at the article's loop period and at ours.
TEST(TaskSpaceVelocity, FiftyMillimetreStepSettlesWithoutOvershoot) {
  const TaskSpaceGains g;
  for (const double dt : {0.008, 0.002}) {
    double x = 0.0, reached = -1.0, overshoot = 0.0;
    for (int k = 0; k < static_cast<int>(10.0 / dt); ++k) {
      x += linear_velocity(Eigen::Vector3d(50.0 - x, 0, 0), g, dt).x() * dt;
      overshoot = std::max(overshoot, x - 50.0);
      if (reached < 0 && std::abs(50.0 - x) < 0.5) reached = (k + 1) * dt;
    }
    EXPECT_GT(reached, 2.0) << "dt " << dt;
    EXPECT_LT(reached, 3.0) << "dt " << dt;
    EXPECT_LT(overshoot, 1e-9) << "dt " << dt;
    RecordProperty(dt > 0.005 ? "step_50mm_time_dt8ms" : "step_50mm_time_dt2ms", std::to_string(reached));
  }
}

Eigen::Matrix3d rot(double angle, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

TEST(TaskSpaceVelocity, OrientationErrorSplitsTiltAndSpin) {
  const Eigen::Matrix3d base = rot(0.4, {1, 2, 3});
  // A spin about the probe's own z axis is all E_θy, about ±z.
  OrientationError e = orientation_error(base, base * rot(0.3, Eigen::Vector3d::UnitZ()));
  EXPECT_NEAR(e.about_z, 0.0, 1e-12);
  EXPECT_NEAR(e.about_y, 0.3, 1e-12);
  EXPECT_NEAR(std::abs(e.axis_y.dot(base.col(2))), 1.0, 1e-12);
  // A tilt about the probe's x axis is all E_θz.
  e = orientation_error(base, base * rot(0.2, Eigen::Vector3d::UnitX()));
  EXPECT_NEAR(e.about_z, 0.2, 1e-12);
  EXPECT_NEAR(e.about_y, 0.0, 1e-12);
  EXPECT_NEAR(e.axis_z.dot(base.col(0)), 1.0, 1e-12);
  // 150° of tilt: atan2 sees 150°, where the paper's arcsin(|a×b|) would say 30°.
  e = orientation_error(base, base * rot(150.0 * kPi / 180.0, Eigen::Vector3d::UnitY()));
  EXPECT_NEAR(e.about_z, 150.0 * kPi / 180.0, 1e-12);
  // Rotating along the commanded axes by the errors reaches the target: first tilt, then spin.
  const Eigen::Matrix3d target = base * rot(0.5, {1, -1, 0.5}) * rot(0.7, Eigen::Vector3d::UnitZ());
  e = orientation_error(base, target);
  const Eigen::Matrix3d tilted = rot(e.about_z, e.axis_z) * base;
  const Eigen::Matrix3d reached = rot(e.about_y, tilted.col(2)) * tilted;
  EXPECT_NEAR(e.axis_y.dot(base.col(2)), 1.0, 1e-12) << "θ̂_y is the current probe axis";
  EXPECT_NEAR((reached - target).norm(), 0.0, 1e-9);
}

// At E = d_θ = 0.01 rad the commanded rate is 0.1·(1 − e^{−0.1}) = 0.0095 rad/s; large errors on both
// axes sum to √2·ω_d and are capped at ω_d.
TEST(TaskSpaceVelocity, AngularSpeedProfileAndCap) {
  const TaskSpaceGains g;
  OrientationError e;
  e.about_z = 0.01;
  e.axis_z = Eigen::Vector3d::UnitX();
  EXPECT_NEAR(angular_velocity(e, g).norm(), 0.1 * (1.0 - std::exp(-0.1)), 1e-12);
  EXPECT_NEAR(angular_velocity(e, g).norm(), 0.0095, 1e-4);
  e.about_z = 2.0;
  e.about_y = 2.0;
  e.axis_y = Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(angular_velocity(e, g).norm(), 0.1, 1e-12);
}

// ---- the controller closed around a simulated arm ----

struct Rig {
  SerialArmKinematics model{ur5_parameters()};
  SerialArmData data = model.make_data();
  HybridPositionForceController controller{HybridControlParameters{}};
  HybridControlState state;
  VelocityArm arm;
  SpringFloor floor;
  bool floor_present = true;
  double dt = 0.002;

  Eigen::Isometry3d tool() {
    SerialArmData d = model.make_data();
    model.forward_kinematics(arm.q, d);
    return d.tool;
  }
  HybridControlInputs inputs(const Eigen::Isometry3d& target) {
    HybridControlInputs in;
    in.q = arm.q;
    in.target = target;
    in.force = floor_present ? floor.force_in_tool(tool()) : Eigen::Vector3d::Zero();
    in.force_valid = true;
    return in;
  }
  HybridControlOutput step(const HybridControlInputs& in) {
    HybridControlOutput out = controller.step(model, data, state, in, dt);
    arm.step(out.joint_velocity, dt);
    return out;
  }
};

// The probe's target: straight down (tool z = −z0) at `p`, spun by `spin` about the probe axis.
Eigen::Isometry3d probe_target(const Eigen::Vector3d& p, double spin = 0.0) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = test::probe_down_rotation() * rot(spin, Eigen::Vector3d::UnitZ());
  t.translation() = p;
  return t;
}

void expect_within_caps(const HybridControlOutput& out, const SerialArmData& data) {
  EXPECT_LE(out.twist.head<3>().norm(), 50.0 + 1e-9);
  EXPECT_LE(out.twist.tail<3>().norm(), 0.1 + 1e-12);
  // What the arm does with the joint velocities stays within the caps too (damping only slows it).
  const Twist achieved = data.jacobian * out.joint_velocity;
  EXPECT_LE(achieved.head<3>().norm(), 50.0 + 1e-6);
  EXPECT_LE(achieved.tail<3>().norm(), 0.1 + 1e-6);
  EXPECT_LE(out.joint_velocity.cwiseAbs().maxCoeff(), kPi + 1e-12);
  EXPECT_TRUE(out.joint_velocity.allFinite());
}

TEST(HybridPositionForceController, PrePositioningConvergesToAPoseWithinTheGateTolerances) {
  Rig rig;
  rig.floor_present = false;
  const Eigen::Isometry3d start = rig.tool();
  Eigen::Isometry3d target = start;
  target.translation() += Eigen::Vector3d(40.0, -30.0, 20.0);
  target.linear() = rot(0.15, {1, 0.3, 0}) * start.linear() * rot(0.2, Eigen::Vector3d::UnitZ());
  HybridControlOutput out;
  double converged = -1.0;
  for (int k = 0; k < 7500; ++k) {  // 15 s
    HybridControlInputs in = rig.inputs(target);
    in.contact_enabled = false;
    out = rig.step(in);
    ASSERT_EQ(out.status, HybridControlStatus::ok);
    EXPECT_EQ(out.phase, ProbePhase::position);
    EXPECT_FALSE(out.acquire) << "no image without contact";
    expect_within_caps(out, rig.data);
    if (converged < 0 && out.position_error.norm() < 0.5 && out.orientation.about_y < 0.01 &&
        out.orientation.about_z < 0.01) {
      converged = k * rig.dt;
    }
  }
  EXPECT_GT(converged, 0.0);
  EXPECT_LT(converged, 10.0);
  EXPECT_LT(out.position_error.norm(), 0.05);
  EXPECT_LT(out.orientation.about_y, 1e-3);
  EXPECT_LT(out.orientation.about_z, 1e-3);
  RecordProperty("pre_position_converged_s", std::to_string(converged));
}

// Speed caps: random targets up to 300 mm away with large orientation errors never exceed the caps,
// including the integral and force terms.
TEST(HybridPositionForceController, CapsHoldForFarTargets) {
  Rig rig;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    rig.arm = VelocityArm{};
    rig.state.reset();
    const Eigen::Isometry3d start = rig.tool();
    Eigen::Isometry3d target = start;
    const Eigen::Vector3d offset(u(rng), u(rng), u(rng));
    target.translation() += 300.0 * std::abs(u(rng)) * offset.normalized();
    target.linear() = rot(0.8 * u(rng), {u(rng), u(rng), u(rng)}) * start.linear();
    rig.floor.z = start.translation().z() - 100.0;
    for (int k = 0; k < 500; ++k) {
      const HybridControlOutput out = rig.step(rig.inputs(target));
      ASSERT_EQ(out.status, HybridControlStatus::ok);
      expect_within_caps(out, rig.data);  // rig.data: the Jacobian the controller used
    }
  }
}

struct ContactRun {
  double max_force = 0.0;
  double settle_time = -1.0;  // last entry into ±2 % of 0.8 N
  double final_force = 0.0;
  double switch_distance = -1.0;
  double largest_normal_step = 0.0;  // mm/s between consecutive commands around the switch
};

// The probe starts `height` mm above a spring floor of stiffness k (N/mm) and is sent to a surface point
// on it; the controller approaches under position control and switches to force control.
ContactRun run_contact(double stiffness, double height, double seconds, double dt = 0.002, double lag = 0.0) {
  Rig rig;
  rig.dt = dt;
  rig.arm.lag = lag;
  const Eigen::Isometry3d start = rig.tool();
  rig.floor.z = start.translation().z() - height;
  rig.floor.stiffness = stiffness;
  const Eigen::Isometry3d target =
      probe_target({start.translation().x(), start.translation().y(), rig.floor.z});
  ContactRun run;
  double last_normal = 0.0;
  ProbePhase last_phase = ProbePhase::position;
  for (int k = 0; k < static_cast<int>(seconds / dt); ++k) {
    const HybridControlInputs in = rig.inputs(target);
    const double f = -in.force.z();
    run.max_force = std::max(run.max_force, f);
    if (std::abs(f - 0.8) > 0.016)
      run.settle_time = -1.0;
    else if (run.settle_time < 0)
      run.settle_time = k * dt;
    const HybridControlOutput out = rig.step(in);
    EXPECT_EQ(out.status, HybridControlStatus::ok);
    const double normal = -out.twist.z();  // into the floor
    if (out.phase == ProbePhase::force && last_phase == ProbePhase::position) {
      run.switch_distance = out.normal_distance;
    }
    if (k > 0 && std::abs(out.normal_distance - 5.0) < 2.0) {
      run.largest_normal_step = std::max(run.largest_normal_step, std::abs(normal - last_normal));
    }
    last_normal = normal;
    last_phase = out.phase;
    run.final_force = f;
  }
  return run;
}

// Force regulation with our check simulation (1-D spring tissue, start 5 mm above): 0.8 N within ±2 %
// without overshoot, settling after 4.9 s (2 N/mm), 8.4 s (0.5 N/mm) and 27 s (0.1 N/mm).
TEST(HybridPositionForceController, RegulatesContactForceWithoutOvershoot) {
  const struct { double stiffness, seed_settle; } cases[] = {{2.0, 4.9}, {0.5, 8.4}, {0.1, 27.0}};
  for (const auto& c : cases) {
    const ContactRun run = run_contact(c.stiffness, 5.0, c.seed_settle + 8.0);
    EXPECT_LE(run.max_force, 0.8 + 1e-3) << c.stiffness << " N/mm: overshoot";
    EXPECT_NEAR(run.final_force, 0.8, 0.016) << c.stiffness << " N/mm";
    EXPECT_GT(run.settle_time, 0.0) << c.stiffness << " N/mm";
    EXPECT_NEAR(run.settle_time, c.seed_settle, 0.1 * c.seed_settle) << c.stiffness << " N/mm";
    RecordProperty("settle_s_at_" + std::to_string(c.stiffness) + "_N_per_mm",
                   std::to_string(run.settle_time));
  }
}

// From higher up the position law brings the probe down and hands over 5 mm above the surface point;
// a lagging arm (20 ms velocity time constant) and the article's 8 ms loop period still do not overshoot.
TEST(HybridPositionForceController, SwitchesToForceControlOnApproachWithoutOvershoot) {
  for (const double dt : {0.002, 0.008}) {
    const ContactRun run = run_contact(2.0, 60.0, 20.0, dt, 0.02);
    EXPECT_NEAR(run.switch_distance, 5.0, 0.1) << "dt " << dt;
    EXPECT_LE(run.max_force, 0.8 * 1.02) << "dt " << dt;
    EXPECT_NEAR(run.final_force, 0.8, 0.016) << "dt " << dt;
    // The position law was commanding ≈ 9 mm/s down at 5 mm; A10 continues from it instead of
    // dropping to its own 0.4 mm/s first step.
    EXPECT_LT(run.largest_normal_step, 3.0) << "dt " << dt;
  }
}

// A surface higher than planned: the force itself switches to force control, and the contact settles.
TEST(HybridPositionForceController, UnexpectedContactSwitchesToForceControl) {
  Rig rig;
  const Eigen::Isometry3d start = rig.tool();
  rig.floor.z = start.translation().z() - 20.0;
  rig.floor.stiffness = 0.5;
  const Eigen::Isometry3d target =
      probe_target(start.translation() - Eigen::Vector3d(0, 0, 40.0));  // 20 mm deep
  bool switched = false;
  HybridControlOutput out;
  for (int k = 0; k < 10000; ++k) {
    const HybridControlInputs in = rig.inputs(target);
    out = rig.step(in);
    if (!switched && out.phase == ProbePhase::force) {
      switched = true;
      EXPECT_GE(-in.force.z(), 0.1);
      EXPECT_GT(out.normal_distance, 5.0) << "the force, not the distance, switched";
    }
  }
  EXPECT_TRUE(switched);
  EXPECT_NEAR(out.normal_force, 0.8, 0.016);
}

// Acquisition gate: the gate opens only in contact with |E_∥| < 0.5 mm, E_θy, E_θz < 0.01 rad and |F_n − 0.8|
// ≤ 0.1 N held for 100 ms; it never opens while a condition fails and opens within 1 s of all holding.
TEST(HybridPositionForceController, AcquisitionGateOpensOnlyWhenEveryConditionHasHeld) {
  Rig rig;
  const Eigen::Isometry3d start = rig.tool();
  rig.floor.z = start.translation().z() - 8.0;
  rig.floor.stiffness = 1.0;
  // Target 3 mm to the side, spun 0.05 rad: lateral and orientation errors close only in contact.
  const Eigen::Isometry3d target =
      probe_target({start.translation().x() + 3.0, start.translation().y(), rig.floor.z}, 0.05);
  double holding_since = -1.0, opened = -1.0;
  for (int k = 0; k < 7500; ++k) {
    const double t = k * rig.dt;
    const HybridControlInputs in = rig.inputs(target);
    const HybridControlOutput out = rig.step(in);
    const bool conditions = out.phase == ProbePhase::force && out.gate_position_error < 0.5 &&
                            out.orientation.about_y < 0.01 && out.orientation.about_z < 0.01 &&
                            std::abs(out.normal_force - 0.8) <= 0.1;
    if (!conditions)
      holding_since = -1.0;
    else if (holding_since < 0)
      holding_since = t;
    if (out.acquire) {
      ASSERT_TRUE(conditions) << "gate open at " << t << " s with a condition violated";
      EXPECT_GE(t - holding_since, 0.1 - 1e-9);
      if (opened < 0) {
        opened = t;
        EXPECT_LE(t - holding_since, 1.0);
        EXPECT_NEAR(t - holding_since, 0.1, rig.dt);
      }
    }
  }
  ASSERT_GT(opened, 0.0) << "the gate never opened";
  RecordProperty("gate_open_s", std::to_string(opened));

  // Now in steady contact with the gate open, break each condition alone for one cycle.
  HybridControlInputs in = rig.inputs(target);
  ASSERT_TRUE(rig.controller.step(rig.model, rig.data, rig.state, in, rig.dt).acquire);
  const auto closes = [&](const HybridControlInputs& broken) {
    HybridControlState state = rig.state;
    const bool open = rig.controller.step(rig.model, rig.data, state, broken, rig.dt).acquire;
    // and it does not reopen until the hold has passed again
    const bool next = rig.controller.step(rig.model, rig.data, state, in, rig.dt).acquire;
    return !open && !next;
  };
  HybridControlInputs lateral = in;
  lateral.target.translation().x() += 0.6;
  EXPECT_TRUE(closes(lateral)) << "0.6 mm lateral error";
  HybridControlInputs spun = in;
  spun.target.linear() = in.target.linear() * rot(0.012, Eigen::Vector3d::UnitZ());
  EXPECT_TRUE(closes(spun)) << "E_θy = 0.012 rad";
  HybridControlInputs tilted = in;
  tilted.target.linear() = rot(0.012, Eigen::Vector3d::UnitY()) * in.target.linear();
  EXPECT_TRUE(closes(tilted)) << "E_θz = 0.012 rad";
  HybridControlInputs pressed = in;
  pressed.force.z() = -0.95;
  EXPECT_TRUE(closes(pressed)) << "0.95 N";
  HybridControlInputs lifted = in;
  lifted.contact_enabled = false;
  EXPECT_TRUE(closes(lifted)) << "position phase";
  // A normal offset alone (the tissue settles deeper than the planned surface point) does not matter.
  HybridControlInputs deeper = in;
  deeper.target.translation().z() -= 3.0;
  HybridControlState state = rig.state;
  EXPECT_TRUE(rig.controller.step(rig.model, rig.data, state, deeper, rig.dt).acquire);
}

TEST(HybridPositionForceController, LostForceSensorHolds) {
  Rig rig;
  const Eigen::Isometry3d start = rig.tool();
  rig.floor.z = start.translation().z() - 2.0;
  const Eigen::Isometry3d target =
      probe_target({start.translation().x(), start.translation().y(), rig.floor.z});
  for (int k = 0; k < 500; ++k) rig.step(rig.inputs(target));
  ASSERT_EQ(rig.state.phase, ProbePhase::force);
  HybridControlInputs in = rig.inputs(target);
  in.force_valid = false;
  in.force = Eigen::Vector3d::Constant(kNaN);  // whatever a dead sensor leaves there is not read
  const HybridControlOutput out = rig.step(in);
  EXPECT_EQ(out.status, HybridControlStatus::force_lost);
  EXPECT_TRUE(out.joint_velocity.isZero());
  EXPECT_FALSE(out.acquire);
  EXPECT_EQ(rig.state.force_velocity, 0.0);
  // Back: the force loop restarts from rest.
  const HybridControlOutput resumed = rig.step(rig.inputs(target));
  EXPECT_EQ(resumed.status, HybridControlStatus::ok);
  EXPECT_LE(std::abs(resumed.twist.z()), 0.5 * 0.8 + 1e-9);
}

TEST(HybridPositionForceController, BadInputsGiveZeroVelocitiesNeverNaN) {
  Rig rig;
  const Eigen::Isometry3d target = probe_target(rig.tool().translation() - Eigen::Vector3d(0, 0, 20));
  const HybridControlInputs good = rig.inputs(target);
  std::vector<std::pair<const char*, HybridControlInputs>> bad;
  HybridControlInputs in = good;
  in.q[3] = kNaN;
  bad.emplace_back("NaN joint", in);
  in = good;
  in.target.translation().y() = std::numeric_limits<double>::infinity();
  bad.emplace_back("infinite target", in);
  in = good;
  in.target.linear() *= 1.5;
  bad.emplace_back("target rotation not a rotation", in);
  in = good;
  in.force.x() = kNaN;
  bad.emplace_back("NaN force", in);
  in = good;
  in.surface_normal.z() = kNaN;
  bad.emplace_back("NaN normal", in);
  for (const auto& [what, input] : bad) {
    const HybridControlOutput out = rig.controller.step(rig.model, rig.data, rig.state, input, rig.dt);
    EXPECT_EQ(out.status, HybridControlStatus::invalid_input) << what;
    EXPECT_TRUE(out.joint_velocity.isZero()) << what;
    EXPECT_TRUE(out.twist.allFinite()) << what;
  }
  for (const double dt : {0.0, -0.002, kNaN}) {
    const HybridControlOutput out = rig.controller.step(rig.model, rig.data, rig.state, good, dt);
    EXPECT_EQ(out.status, HybridControlStatus::invalid_input) << "dt " << dt;
    EXPECT_TRUE(out.joint_velocity.isZero());
  }
  EXPECT_EQ(rig.controller.step(rig.model, rig.data, rig.state, good, 0.002).status, HybridControlStatus::ok);
}

TEST(HybridPositionForceController, RefusesOutOfRangeParameters) {
  HybridControlParameters p;
  p.force.integral_gain = 1.0;
  EXPECT_THROW(HybridPositionForceController{p}, std::invalid_argument);
  p = {};
  p.task.max_linear_speed = 0.0;
  EXPECT_THROW(HybridPositionForceController{p}, std::invalid_argument);
  p = {};
  p.gate.position_setpoint = kNaN;
  EXPECT_THROW(HybridPositionForceController{p}, std::invalid_argument);
  EXPECT_NO_THROW(HybridPositionForceController{HybridControlParameters{}});
}

TEST(HybridPositionForceController, StepDoesNotAllocate) {
  Rig rig;
  const Eigen::Isometry3d start = rig.tool();
  rig.floor.z = start.translation().z() - 6.0;
  const Eigen::Isometry3d target =
      probe_target({start.translation().x() + 2.0, start.translation().y(), rig.floor.z});
  std::array<HybridControlInputs, 1> in{};
  double sink = 0.0;
  const long before = tendril::testing::allocation_count.load();
  for (int k = 0; k < 3000; ++k) {
    in[0] = rig.inputs(target);
    in[0].force_valid = k % 700 != 0;
    sink += rig.step(in[0]).joint_velocity.sum();
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_EQ(rig.state.phase, ProbePhase::force);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
