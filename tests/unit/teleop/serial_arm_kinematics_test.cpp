#include "tendril/teleop/serial_arm_kinematics.hpp"

#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <cmath>
#include <memory>
#include <numbers>
#include <random>
#include <stdexcept>

#include "allocation_counter.hpp"

namespace tendril::teleop {
namespace {

constexpr double kPi = std::numbers::pi;

ArmVector joints(double q1, double q2, double q3, double q4, double q5, double q6) {
  ArmVector q;
  q << q1, q2, q3, q4, q5, q6;
  return q;
}

Eigen::Matrix3d columns(const Eigen::Vector3d& x, const Eigen::Vector3d& y, const Eigen::Vector3d& z) {
  Eigen::Matrix3d r;
  r << x, y, z;
  return r;
}

void expect_pose(const Eigen::Isometry3d& pose, const Eigen::Vector3d& p, const Eigen::Matrix3d& r) {
  EXPECT_NEAR((pose.translation() - p).norm(), 0.0, 1e-9)
      << "position " << pose.translation().transpose() << ", expected " << p.transpose();
  EXPECT_NEAR((pose.linear() - r).norm(), 0.0, 1e-12) << "rotation\n" << pose.linear() << "\nexpected\n" << r;
}

// UR5 DH constants (mm), for the hand derivations below.
constexpr double d1 = 89.159, a2 = -425.0, a3 = -392.25, d4 = 109.15, d5 = 94.65, d6 = 82.3;
const Eigen::Vector3d X = Eigen::Vector3d::UnitX(), Y = Eigen::Vector3d::UnitY(),
                      Z = Eigen::Vector3d::UnitZ();

// q = 0 by hand: α1 = π/2 gives x1 = x0, y1 = z0, z1 = −y0; links 2, 3 keep those axes and reach
// (a2 + a3, 0, d1); α4 = π/2 gives z4 = −z0 after d4 along z3 = −y0; α5 = −π/2 gives z5 = −y0 after
// d5 along z4; d6 along z5. Flange (a2 + a3, −(d4 + d6), d1 − d5) = (−817.25, −191.45, −5.491) mm, the
// UR5's well-known zero pose, axes x6 = x0, y6 = z0, z6 = −y0.
TEST(SerialArmKinematics, Ur5ZeroPoseMatchesHandDerivation) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ASSERT_TRUE(arm.forward_kinematics(ArmVector::Zero(), data));
  expect_pose(data.tool, {a2 + a3, -(d4 + d6), d1 - d5}, columns(X, Z, -Y));
  EXPECT_NEAR(data.tool.translation().x(), -817.25, 1e-9);
  EXPECT_NEAR(data.tool.translation().y(), -191.45, 1e-9);
  EXPECT_NEAR(data.tool.translation().z(), -5.491, 1e-9);
  // Intermediate frames: the elbow (frame 2) and the wrist centre (frame 3).
  EXPECT_NEAR((data.frames[1].translation() - Eigen::Vector3d(0, 0, d1)).norm(), 0.0, 1e-9);
  EXPECT_NEAR((data.frames[2].translation() - Eigen::Vector3d(a2, 0, d1)).norm(), 0.0, 1e-9);
  EXPECT_NEAR((data.frames[3].translation() - Eigen::Vector3d(a2 + a3, 0, d1)).norm(), 0.0, 1e-9);
}

// The base joint turns the zero pose about z0: (x, y, z) → (−y, x, z).
TEST(SerialArmKinematics, Ur5BaseQuarterTurnRotatesTheZeroPose) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ASSERT_TRUE(arm.forward_kinematics(joints(kPi / 2, 0, 0, 0, 0, 0), data));
  expect_pose(data.tool, {d4 + d6, a2 + a3, d1 - d5}, columns(Y, Z, X));
}

// q = (0, −π/2, 0, −π/2, 0, 0), the arm pointing straight up. θ2 = −π/2 about z1 = −y0 turns x2 onto −z0,
// so a2 < 0 and a3 < 0 both climb: wrist centre (0, 0, d1 − a2 − a3). θ4 = −π/2 with α4 = π/2 gives
// x4 = −x0, y4 = −y0, z4 = z0 after d4 along z3 = −y0; α5 = −π/2 gives x5 = −x0, y5 = −z0, z5 = −y0 after
// d5 along z4 = +z0; d6 along z5. Flange (0, −(d4 + d6), d1 − a2 − a3 + d5) = (0, −191.45, 1001.059).
TEST(SerialArmKinematics, Ur5UprightPoseMatchesHandDerivation) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ASSERT_TRUE(arm.forward_kinematics(joints(0, -kPi / 2, 0, -kPi / 2, 0, 0), data));
  expect_pose(data.tool, {0.0, -(d4 + d6), d1 - a2 - a3 + d5}, columns(-X, -Z, -Y));
  EXPECT_NEAR(data.tool.translation().z(), 1001.059, 1e-9);
}

// q3 = π/2 alone: the forearm hangs down from the elbow at (a2, 0, d1): x3 = z0, so a3 < 0 drops the
// wrist to z = d1 + a3; α4 = π/2 gives z4 = x0 after d4 along z3 = −y0; α5 = −π/2 gives z5 = −y0 after d5
// along z4 = x0. Flange (a2 + d5, −(d4 + d6), d1 + a3) = (−330.35, −191.45, −303.091), axes x6 = z0,
// y6 = −x0, z6 = −y0.
TEST(SerialArmKinematics, Ur5ElbowBentPoseMatchesHandDerivation) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  ASSERT_TRUE(arm.forward_kinematics(joints(0, 0, kPi / 2, 0, 0, 0), data));
  expect_pose(data.tool, {a2 + d5, -(d4 + d6), d1 + a3}, columns(Z, -X, -Y));
}

// The last joint spins the flange about its own z axis: the position stays, x and y turn.
TEST(SerialArmKinematics, WristThreeSpinsTheFlangeAboutItsAxis) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData a = arm.make_data(), b = arm.make_data();
  const ArmVector q = joints(0.3, -1.1, 1.4, -0.9, 0.7, 0.0);
  ASSERT_TRUE(arm.forward_kinematics(q, a));
  ASSERT_TRUE(arm.forward_kinematics(q + joints(0, 0, 0, 0, 0, 0.6), b));
  EXPECT_NEAR((a.tool.translation() - b.tool.translation()).norm(), 0.0, 1e-9);
  EXPECT_NEAR((a.tool.linear().col(2) - b.tool.linear().col(2)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(std::acos(a.tool.linear().col(0).dot(b.tool.linear().col(0))), 0.6, 1e-9);
}

TEST(SerialArmKinematics, ToolTransformOffsetsTheToolPoint) {
  SerialArmParameters p = ur5_parameters();
  p.tool = Eigen::Translation3d(0.0, 0.0, 150.0) * Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ());
  const SerialArmKinematics arm(p);
  SerialArmData data = arm.make_data();
  ASSERT_TRUE(arm.forward_kinematics(ArmVector::Zero(), data));
  // Flange z6 = −y0 at zero, so a 150 mm probe reaches 150 mm further along −y0.
  EXPECT_NEAR((data.tool.translation() - Eigen::Vector3d(a2 + a3, -(d4 + d6) - 150.0, d1 - d5)).norm(), 0.0,
              1e-9);
  EXPECT_NEAR((data.tool.linear().col(2) - (-Y)).norm(), 0.0, 1e-12);
}

// Rotation vector of R (log map), for the angular finite difference.
Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& r) {
  const Eigen::AngleAxisd aa(r);
  return aa.angle() * aa.axis();
}

TEST(SerialArmKinematics, JacobianMatchesFiniteDifferencesAtRandomPoses) {
  SerialArmParameters p = ur5_parameters();
  p.tool = Eigen::Translation3d(10.0, -20.0, 120.0) *
           Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 1, 0).normalized());
  const SerialArmKinematics arm(p);
  SerialArmData data = arm.make_data(), plus = arm.make_data(), minus = arm.make_data();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  constexpr double h = 1e-6;
  for (int trial = 0; trial < 50; ++trial) {
    ArmVector q;
    for (auto& v : q) v = angle(rng);
    ASSERT_TRUE(arm.update(q, data));
    for (Eigen::Index j = 0; j < 6; ++j) {
      ArmVector dq = ArmVector::Zero();
      dq[j] = h;
      arm.forward_kinematics(q + dq, plus);
      arm.forward_kinematics(q - dq, minus);
      const Eigen::Vector3d v = (plus.tool.translation() - minus.tool.translation()) / (2 * h);
      const Eigen::Vector3d w =
          rotation_vector(plus.tool.linear() * minus.tool.linear().transpose()) / (2 * h);
      EXPECT_NEAR((data.jacobian.block<3, 1>(0, j) - v).norm(), 0.0, 1e-5)
          << "trial " << trial << " joint " << j;
      EXPECT_NEAR((data.jacobian.block<3, 1>(3, j) - w).norm(), 0.0, 1e-8)
          << "trial " << trial << " joint " << j;
    }
  }
}

TEST(SerialArmKinematics, UndampedAwayFromSingularitiesSoTheTwistIsReproducedExactly) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  // A probe-down scanning pose (w ≈ 0.10 m³).
  ASSERT_TRUE(arm.update(joints(0.0, -1.2, 1.6, -1.97, -kPi / 2, 0.0), data));
  Twist v;
  v << 30.0, -20.0, 10.0, 0.05, -0.02, 0.08;
  ArmVector qd;
  ASSERT_TRUE(arm.damped_least_squares(data, v, qd));
  EXPECT_GT(data.manipulability, 0.05);
  EXPECT_EQ(data.damping, 0.0);
  EXPECT_NEAR((data.jacobian * qd - v).norm(), 0.0, 1e-9);
}

TEST(SerialArmKinematics, DampingGrowsSmoothlyAsManipulabilityFalls) {
  const SerialArmKinematics arm(ur5_parameters());
  const DampingParameters& d = arm.parameters().damping;
  EXPECT_EQ(arm.damping_for(d.manipulability_threshold), 0.0);
  EXPECT_EQ(arm.damping_for(1.0), 0.0);
  EXPECT_NEAR(arm.damping_for(0.0), d.max_damping, 1e-15);
  EXPECT_NEAR(arm.damping_for(0.5 * d.manipulability_threshold), 0.5 * d.max_damping, 1e-15);
  EXPECT_NEAR(arm.damping_for(0.999999 * d.manipulability_threshold), 0.0, 1e-6);
}

// Sweeps a joint through a singularity and checks every twist the article's caps allow (50 mm/s, 0.1 rad/s,
// along each axis and in random directions) maps to joint speeds within the UR5's 180°/s before any
// clamping, and within ‖V‖/(2ρ_max) at the singularity itself.
void expect_bounded_through(const SerialArmKinematics& arm, ArmVector q, Eigen::Index joint, double centre) {
  SerialArmData data = arm.make_data();
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, 1.0);
  std::array<Twist, 16> twists;
  for (std::size_t i = 0; i < twists.size(); ++i) {
    Twist v = Twist::Zero();
    if (i < 6) {
      v[static_cast<Eigen::Index>(i)] = 1.0;
    } else {
      for (auto& c : v) c = n(rng);
    }
    // Scale each part to its cap.
    const double lin = v.head<3>().norm(), ang = v.tail<3>().norm();
    if (lin > 0) v.head<3>() *= 50.0 / lin;
    if (ang > 0) v.tail<3>() *= 0.1 / ang;
    twists[i] = v;
  }
  double worst = 0.0;
  for (int i = -600; i <= 600; ++i) {
    const double e = 5e-4 * i;
    q[joint] = centre + e;
    ASSERT_TRUE(arm.update(q, data));
    for (const Twist& v : twists) {
      ArmVector qd;
      ASSERT_TRUE(arm.damped_least_squares(data, v, qd));
      worst = std::max(worst, qd.norm());
      EXPECT_LT(qd.cwiseAbs().maxCoeff(), kPi) << "offset " << e;
    }
  }
  q[joint] = centre;
  ASSERT_TRUE(arm.update(q, data));
  Twist v;
  v << 50.0, 0.0, 0.0, 0.0, 0.0, 0.1;
  ArmVector qd;
  ASSERT_TRUE(arm.damped_least_squares(data, v, qd));
  EXPECT_LT(data.manipulability, 1e-9) << "the pose is singular";
  EXPECT_NEAR(data.damping, arm.parameters().damping.max_damping, 1e-9);
  const double v_si = std::hypot(0.05, 0.1);
  EXPECT_LE(qd.norm(), v_si / (2 * data.damping) + 1e-9);
  ::testing::Test::RecordProperty("worst_joint_speed_rad_s", std::to_string(worst));
}

TEST(SerialArmKinematics, DampedInverseStaysBoundedThroughTheWristSingularity) {
  const SerialArmKinematics arm(ur5_parameters());
  expect_bounded_through(arm, joints(0.3, -1.2, 1.6, -1.97, 0.0, 0.4), 4, 0.0);  // q5 = 0
}

TEST(SerialArmKinematics, DampedInverseStaysBoundedThroughTheElbowSingularity) {
  const SerialArmKinematics arm(ur5_parameters());
  expect_bounded_through(arm, joints(0.3, -1.2, 0.0, -1.97, 1.2, 0.4), 2, 0.0);  // q3 = 0
}

// Shoulder singularity: the wrist centre on the base axis, a2·c2 + a3·c23 + d5·s234 = 0; q2 = −π/2,
// q3 = 0 puts the arm upright and q4 = π/2 makes s234 = 0.
TEST(SerialArmKinematics, DampedInverseStaysBoundedThroughTheShoulderSingularity) {
  const SerialArmKinematics arm(ur5_parameters());
  expect_bounded_through(arm, joints(0.0, -kPi / 2, 0.0, kPi / 2, 1.0, 0.0), 3, kPi / 2);
}

TEST(SerialArmKinematics, NonFiniteInputsAreRefusedWithoutTouchingTheData) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  const ArmVector good = joints(0.1, -1.0, 1.0, -1.0, 1.0, 0.0);
  ASSERT_TRUE(arm.update(good, data));
  const Eigen::Isometry3d before = data.tool;
  ArmVector bad = good;
  bad[2] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(arm.update(bad, data));
  EXPECT_TRUE(data.tool.isApprox(before));
  EXPECT_EQ(data.q, good);
  Twist v = Twist::Zero();
  v[4] = std::numeric_limits<double>::infinity();
  ArmVector qd = ArmVector::Ones();
  EXPECT_FALSE(arm.damped_least_squares(data, v, qd));
  EXPECT_TRUE(qd.isZero());
}

TEST(SerialArmKinematics, VelocityClampKeepsTheDirection) {
  const SerialArmKinematics arm(ur5_parameters());
  ArmVector qd = joints(1.0, -6.0, 2.0, 0.5, 0.0, 3.0);
  const ArmVector before = qd;
  EXPECT_TRUE(arm.clamp_to_velocity_limits(qd));
  EXPECT_NEAR(qd.cwiseAbs().maxCoeff(), kPi, 1e-12);
  EXPECT_NEAR(qd.normalized().dot(before.normalized()), 1.0, 1e-12);
  ArmVector slow = joints(0.1, -0.2, 0.3, 0, 0, 0);
  EXPECT_FALSE(arm.clamp_to_velocity_limits(slow));
  EXPECT_EQ(slow, joints(0.1, -0.2, 0.3, 0, 0, 0));
}

TEST(SerialArmKinematics, PositionClampStopsAJointAtItsLimit) {
  SerialArmParameters p = ur5_parameters();
  p.limits[1].lower = -2.0;
  p.limits[1].upper = 0.5;
  const SerialArmKinematics arm(p);
  ArmVector q = joints(0, 0.499, 0, 0, 0, 0);
  ArmVector qd = joints(0.5, 1.0, 0, 0, 0, 0);
  EXPECT_TRUE(arm.clamp_to_position_limits(q, qd, 0.002));
  EXPECT_NEAR(qd[1], 0.5, 1e-9);  // reaches 0.5 exactly in 2 ms
  EXPECT_EQ(qd[0], 0.5);          // the others untouched
  // Moving away from the limit is always allowed.
  q[1] = 0.5;
  qd[1] = -1.0;
  EXPECT_FALSE(arm.clamp_to_position_limits(q, qd, 0.002));
  EXPECT_EQ(qd[1], -1.0);
  EXPECT_TRUE(arm.within_limits(q));
  q[1] = 0.6;
  EXPECT_FALSE(arm.within_limits(q));
}

TEST(SerialArmKinematics, BadParametersAreRefusedWithTheJointNamed) {
  SerialArmParameters p = ur5_parameters();
  p.limits[3].max_velocity = 0.0;
  try {
    const SerialArmKinematics arm(p);
    FAIL() << "accepted a zero velocity limit";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("joint 4"), std::string::npos) << e.what();
  }
  p = ur5_parameters();
  p.links[0].d = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(SerialArmKinematics{p}, std::invalid_argument);
  p = ur5_parameters();
  p.tool.linear() *= 2.0;
  EXPECT_THROW(SerialArmKinematics{p}, std::invalid_argument);
  p = ur5_parameters();
  p.damping.manipulability_threshold = 0.0;
  EXPECT_THROW(SerialArmKinematics{p}, std::invalid_argument);
}

TEST(SerialArmKinematics, KinematicsJacobianAndDampedInverseDoNotAllocate) {
  const SerialArmKinematics arm(ur5_parameters());
  SerialArmData data = arm.make_data();
  Twist v;
  v << 10.0, -5.0, 3.0, 0.01, 0.02, -0.03;
  ArmVector qd;
  double sink = 0.0;
  const long before = tendril::testing::allocation_count.load();
  for (int i = 0; i < 1000; ++i) {
    const double s = 1e-3 * i;
    // Pass through the wrist singularity so both branches of the damping run.
    arm.update(joints(s, -1.2 + s, 1.6, -1.97, 0.5 - s, 0.1), data);
    arm.damped_least_squares(data, v, qd);
    arm.clamp_to_velocity_limits(qd);
    arm.clamp_to_position_limits(data.q, qd, 0.002);
    sink += qd.sum() + data.tool.translation().x();
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  tendril::testing::allocate_probe();  // the counter works
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
