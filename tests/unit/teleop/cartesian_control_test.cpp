#include "tendril/teleop/cartesian_control.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <stdexcept>

#include "allocation_counter.hpp"
#include "arm_test_support.hpp"

namespace tendril::teleop {
namespace {

using test::VelocityArm;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Eigen::Matrix3d rot(double angle, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

double angle_between(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a * b.transpose()).angle();
}

struct Arm {
  SerialArmKinematics model{ur5_parameters()};
  SerialArmData data = model.make_data();
  VelocityArm arm;
  Eigen::Isometry3d tool() {
    Eigen::Isometry3d pose;
    measured_cp(model, data, arm.q, pose);
    return pose;
  }
};

TEST(CartesianControl, MeasuredPoseAndTwistComeFromTheJoints) {
  Arm a;
  a.arm.q << 0.2, -1.0, 1.3, -0.8, 1.1, 0.4;
  ArmVector qd;
  qd << 0.1, -0.2, 0.15, 0.05, -0.1, 0.3;
  Eigen::Isometry3d pose;
  ASSERT_TRUE(measured_cp(a.model, a.data, a.arm.q, pose));
  Twist twist;
  ASSERT_TRUE(measured_cv(a.model, a.data, a.arm.q, qd, twist));
  // Against the motion of the measured pose over a short step.
  constexpr double h = 1e-6;
  Eigen::Isometry3d later;
  ASSERT_TRUE(measured_cp(a.model, a.data, a.arm.q + h * qd, later));
  EXPECT_NEAR((twist.head<3>() - (later.translation() - pose.translation()) / h).norm(), 0.0, 1e-3);
  const Eigen::AngleAxisd turn(later.linear() * pose.linear().transpose());
  EXPECT_NEAR((twist.tail<3>() - turn.angle() / h * turn.axis()).norm(), 0.0, 1e-6);
  ArmVector bad = qd;
  bad[0] = kNaN;
  EXPECT_FALSE(measured_cv(a.model, a.data, a.arm.q, bad, twist));
}

TEST(CartesianControl, ServoCvFollowsATwistWithinTheCaps) {
  Arm a;
  Twist v;
  v << 20.0, -10.0, 5.0, 0.02, 0.0, -0.05;
  CartesianCommandResult r = servo_cv(a.model, a.data, a.arm.q, v, CartesianLimits{}, 0.002);
  ASSERT_TRUE(r.joints.valid);
  EXPECT_FALSE(r.twist_limited);
  EXPECT_NEAR((a.data.jacobian * r.joints.joint_velocity - v).norm(), 0.0, 1e-9);
  // Too fast: each part scaled to its cap, directions kept.
  Twist fast;
  fast << 300.0, 400.0, 0.0, 0.0, 0.0, 1.0;
  r = servo_cv(a.model, a.data, a.arm.q, fast, CartesianLimits{}, 0.002);
  EXPECT_TRUE(r.twist_limited);
  EXPECT_NEAR(r.twist.head<3>().norm(), 50.0, 1e-9);
  EXPECT_NEAR(r.twist.tail<3>().norm(), 0.1, 1e-12);
  EXPECT_NEAR(r.twist.head<3>().normalized().dot(Eigen::Vector3d(0.6, 0.8, 0.0)), 1.0, 1e-12);
  // Integrating the commanded joint velocities moves the tool by v·t.
  const Eigen::Isometry3d start = a.tool();
  for (int k = 0; k < 500; ++k) {
    r = servo_cv(a.model, a.data, a.arm.q, v, CartesianLimits{}, 0.002);
    a.arm.step(r.joints.joint_velocity, 0.002);
  }
  EXPECT_NEAR((a.tool().translation() - start.translation() - v.head<3>()).norm(), 0.0, 0.05);
  // Bad input: zero.
  fast[2] = kNaN;
  r = servo_cv(a.model, a.data, a.arm.q, fast, CartesianLimits{}, 0.002);
  EXPECT_FALSE(r.joints.valid);
  EXPECT_TRUE(r.joints.joint_velocity.isZero());
}

TEST(CartesianControl, ServoCpConvergesToAStreamedPose) {
  Arm a;
  const Eigen::Isometry3d start = a.tool();
  Eigen::Isometry3d goal = start;
  goal.translation() += Eigen::Vector3d(-60.0, 25.0, 40.0);
  goal.linear() = rot(0.25, {0.2, 1.0, 0.1}) * start.linear();
  const TaskSpaceGains gains;
  double peak_speed = 0.0;
  for (int k = 0; k < 7500; ++k) {
    const CartesianCommandResult r =
        servo_cp(a.model, a.data, a.arm.q, goal, gains, CartesianLimits{}, 0.002);
    ASSERT_TRUE(r.joints.valid);
    peak_speed = std::max(peak_speed, (a.data.jacobian * r.joints.joint_velocity).head<3>().norm());
    a.arm.step(r.joints.joint_velocity, 0.002);
  }
  EXPECT_LT((a.tool().translation() - goal.translation()).norm(), 0.05);
  EXPECT_LT(angle_between(a.tool().linear(), goal.linear()), 1e-3);
  EXPECT_LE(peak_speed, 50.0 + 1e-6);
  Eigen::Isometry3d bad = goal;
  bad.linear() *= 2.0;
  EXPECT_FALSE(servo_cp(a.model, a.data, a.arm.q, bad, gains, CartesianLimits{}, 0.002).joints.valid);
}

TEST(CartesianControl, TrajectoryIsQuinticInPositionAndSlerpInOrientation) {
  Eigen::Isometry3d start = Eigen::Isometry3d::Identity(), goal = Eigen::Isometry3d::Identity();
  start.translation() = Eigen::Vector3d(100.0, 0.0, 300.0);
  start.linear() = rot(0.3, {1, 0, 0});
  goal.translation() = Eigen::Vector3d(40.0, 80.0, 300.0);  // 100 mm away
  goal.linear() = rot(0.3, {1, 0, 0}) * rot(0.2, {0, 1, 1});
  const CartesianLimits limits;
  CartesianTrajectory traj;
  ASSERT_TRUE(traj.plan(start, goal, limits, 2.0));
  // 100 mm at 50 mm/s: T = 15/8 · 100/50 = 3.75 s (the acceleration needs √(5.77·100/100) = 2.4 s, the
  // 0.2 rad turn 15/8 · 0.2/0.1 = 3.75 s too).
  EXPECT_NEAR(traj.duration(), 3.75, 1e-9);
  CartesianTrajectory::Sample s = traj.sample(2.0);
  EXPECT_TRUE(s.pose.isApprox(start, 1e-12));
  EXPECT_NEAR(s.twist.norm(), 0.0, 1e-12);
  s = traj.sample(2.0 + traj.duration());
  EXPECT_NEAR((s.pose.translation() - goal.translation()).norm(), 0.0, 1e-9);
  EXPECT_NEAR(angle_between(s.pose.linear(), goal.linear()), 0.0, 1e-9);
  EXPECT_NEAR(s.twist.norm(), 0.0, 1e-12);
  EXPECT_TRUE(traj.done(2.0 + traj.duration()));
  // Halfway: half the way, half the turn, at the peak speed 15/8·D/T.
  s = traj.sample(2.0 + traj.duration() / 2);
  EXPECT_NEAR((s.pose.translation() - (start.translation() + goal.translation()) / 2).norm(), 0.0, 1e-9);
  EXPECT_NEAR(angle_between(s.pose.linear(), start.linear()), 0.1, 1e-9);
  EXPECT_NEAR(s.twist.head<3>().norm(), 50.0, 1e-9);
  // The feed-forward twist is the derivative of the sampled pose, and no sample exceeds the limits.
  constexpr double h = 1e-6;
  for (int i = 0; i <= static_cast<int>(traj.duration() / 0.01); ++i) {
    const double t = 2.0 + 0.01 * i;
    const auto a = traj.sample(t), b = traj.sample(t + h);
    EXPECT_NEAR((a.twist.head<3>() - (b.pose.translation() - a.pose.translation()) / h).norm(), 0.0, 1e-3);
    const Eigen::AngleAxisd turn(b.pose.linear() * a.pose.linear().transpose());
    EXPECT_NEAR((a.twist.tail<3>() - turn.angle() / h * turn.axis()).norm(), 0.0, 1e-5);
    EXPECT_LE(a.twist.head<3>().norm(), limits.max_linear_speed + 1e-9);
    EXPECT_LE(a.twist.tail<3>().norm(), limits.max_angular_speed + 1e-12);
  }
  // Bad input leaves the trajectory as it was.
  Eigen::Isometry3d bad = goal;
  bad.translation().x() = kNaN;
  EXPECT_FALSE(traj.plan(start, bad, limits, 0.0));
  EXPECT_NEAR(traj.duration(), 3.75, 1e-9);
  EXPECT_THROW(validate(CartesianLimits{.max_linear_speed = 0.0}), std::invalid_argument);
}

TEST(CartesianControl, MoveCpTracksTheTrajectoryToTheGoal) {
  Arm a;
  a.arm.lag = 0.01;
  const Eigen::Isometry3d start = a.tool();
  Eigen::Isometry3d goal = start;
  goal.translation() += Eigen::Vector3d(80.0, -50.0, -30.0);
  goal.linear() = rot(-0.3, {1.0, 0.5, 0.0}) * start.linear();
  CartesianTrajectory traj;
  ASSERT_TRUE(traj.plan(start, goal, CartesianLimits{}, 0.0));
  const TaskSpaceGains gains;
  double worst_lag = 0.0;
  const double dt = 0.002;
  for (int k = 0; k < static_cast<int>((traj.duration() + 2.0) / dt); ++k) {
    const CartesianTrajectory::Sample ref = traj.sample(k * dt);
    const CartesianCommandResult r = track(a.model, a.data, a.arm.q, ref, gains, CartesianLimits{}, dt);
    ASSERT_TRUE(r.joints.valid);
    worst_lag = std::max(worst_lag, (a.data.tool.translation() - ref.pose.translation()).norm());
    EXPECT_LE(r.twist.head<3>().norm(), 50.0 + 1e-9);
    EXPECT_LE(r.twist.tail<3>().norm(), 0.1 + 1e-12);
    a.arm.step(r.joints.joint_velocity, dt);
  }
  EXPECT_LT((a.tool().translation() - goal.translation()).norm(), 0.05);
  EXPECT_LT(angle_between(a.tool().linear(), goal.linear()), 1e-3);
  EXPECT_LT(worst_lag, 1.0) << "feed-forward keeps the tool on the planned line";
  RecordProperty("move_cp_worst_tracking_error_mm", std::to_string(worst_lag));
}

TEST(CartesianControl, CommandsDoNotAllocate) {
  Arm a;
  CartesianTrajectory traj;
  Eigen::Isometry3d goal = a.tool();
  goal.translation().x() += 30.0;
  Twist v;
  v << 5.0, 0.0, -3.0, 0.0, 0.01, 0.0;
  const TaskSpaceGains gains;
  double sink = 0.0;
  const long before = tendril::testing::allocation_count.load();
  traj.plan(a.tool(), goal, CartesianLimits{}, 0.0);
  for (int k = 0; k < 1000; ++k) {
    sink += servo_cv(a.model, a.data, a.arm.q, v, CartesianLimits{}, 0.002).twist.sum();
    sink += servo_cp(a.model, a.data, a.arm.q, goal, gains, CartesianLimits{}, 0.002).twist.sum();
    sink +=
        track(a.model, a.data, a.arm.q, traj.sample(k * 0.002), gains, CartesianLimits{}, 0.002).twist.sum();
    Twist measured;
    measured_cv(a.model, a.data, a.arm.q, a.arm.qd, measured);
    sink += measured.sum();
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
