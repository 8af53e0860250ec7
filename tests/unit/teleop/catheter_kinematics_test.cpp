#include "tendril/teleop/catheter_kinematics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <vector>

namespace tendril::teleop {
namespace {

using JV = ConstantCurvatureCatheter::JointVector;
constexpr double kPi = std::numbers::pi;

CatheterParameters params(double L1 = 10.0, double L2 = 20.0, double delta2 = 0.0) {
  CatheterParameters p;
  p.proximal_length = L1;
  p.distal_length = L2;
  p.plane_offset = delta2;
  p.proximal_curvature_gain = 1.4;
  p.distal_curvature_gain = 1.2;
  return p;
}

void expect_vec_near(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double tol) {
  EXPECT_NEAR((a - b).norm(), 0.0, tol) << "got " << a.transpose() << " expected " << b.transpose();
}

TEST(ConstantCurvatureCatheter, StraightCatheterPointsAlongZ) {
  const ConstantCurvatureCatheter cat(params(10.0, 20.0, -0.44));
  for (double roll : {0.0, 1.0, -2.5}) {
    const TipPose tip = cat.tip_pose(JV(7.0, roll, 0.0, 0.0));
    expect_vec_near(tip.position, {0.0, 0.0, 7.0 + 30.0}, 1e-12);
    expect_vec_near(tip.rotation.col(2), Eigen::Vector3d::UnitZ(), 1e-12);
    EXPECT_NEAR((tip.rotation.transpose() * tip.rotation - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
  }
}

TEST(ConstantCurvatureCatheter, NinetyDegreeProximalBendLandsOnTheArc) {
  const double L1 = 10.0, L2 = 20.0, q1 = 3.0;
  const ConstantCurvatureCatheter cat(params(L1, L2));
  const double q3 = (kPi / 2.0) / 1.4;  // bend = k·q = 90°
  EXPECT_NEAR(cat.proximal_bend(JV(q1, 0, q3, 0)), kPi / 2.0, 1e-15);
  const double radius = L1 / (kPi / 2.0);
  // Proximal tip at (r, 0, q1 + r) heading +x; the straight distal segment continues along +x.
  const TipPose tip = cat.tip_pose(JV(q1, 0.0, q3, 0.0));
  expect_vec_near(tip.position, {radius + L2, 0.0, q1 + radius}, 1e-12);
  expect_vec_near(tip.rotation.col(2), Eigen::Vector3d::UnitX(), 1e-12);

  // Every proximal backbone point is at distance r from the centre of curvature (r, 0, q1).
  std::vector<Eigen::Vector3d> pts(cat.backbone_point_count(16));
  ASSERT_EQ(cat.backbone(JV(q1, 0.0, q3, 0.0), 16, pts), pts.size());
  for (int i = 0; i <= 16; ++i) EXPECT_NEAR((pts[i] - Eigen::Vector3d(radius, 0, q1)).norm(), radius, 1e-12);
  expect_vec_near(pts.back(), tip.position, 1e-12);
}

TEST(ConstantCurvatureCatheter, RollRotatesTheShapeAboutZ) {
  const ConstantCurvatureCatheter cat(params(10.0, 20.0, 0.3));
  const double roll = 0.9;
  const JV q0(4.0, 0.0, 0.6, -0.4), qr(4.0, roll, 0.6, -0.4);
  const Eigen::Matrix3d Rz = Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const TipPose a = cat.tip_pose(q0), b = cat.tip_pose(qr);
  expect_vec_near(b.position, Rz * a.position, 1e-12);
  EXPECT_NEAR((b.rotation - Rz * a.rotation).norm(), 0.0, 1e-12);
  EXPECT_GT(std::hypot(a.position.x(), a.position.y()), 1.0);  // really bent, so roll matters
}

TEST(ConstantCurvatureCatheter, PlaneOffsetMovesTheDistalSegmentOutOfTheProximalPlane) {
  const JV q(0.0, 0.0, 0.5, 0.7);
  const TipPose planar = ConstantCurvatureCatheter(params(10.0, 20.0, 0.0)).tip_pose(q);
  EXPECT_NEAR(planar.position.y(), 0.0, 1e-12);
  const TipPose offset = ConstantCurvatureCatheter(params(10.0, 20.0, 0.6)).tip_pose(q);
  EXPECT_GT(std::abs(offset.position.y()), 1.0);
  // δ2 = 90° with a straight proximal segment: the distal bend lies entirely in the y–z plane.
  const TipPose quarter = ConstantCurvatureCatheter(params(10.0, 20.0, kPi / 2)).tip_pose(JV(0, 0, 0, 0.7));
  EXPECT_NEAR(quarter.position.x(), 0.0, 1e-12);
  const double bend = 1.2 * 0.7, r = 20.0 / bend;
  EXPECT_NEAR(quarter.position.y(), r * (1 - std::cos(bend)), 1e-12);
  EXPECT_NEAR(quarter.position.z(), 10.0 + r * std::sin(bend), 1e-12);
}

TEST(ConstantCurvatureCatheter, ContinuousAsCurvatureGoesToZero) {
  const ConstantCurvatureCatheter cat(params());
  const Eigen::Vector3d straight = cat.tip_pose(JV(0, 0, 0, 0)).position;
  for (double q3 : {1e-12, 1e-9, 1e-7, 1e-5}) {
    const Eigen::Vector3d p = cat.tip_pose(JV(0, 0, q3, q3)).position;
    ASSERT_TRUE(p.allFinite());
    // First-order prediction: x = [k1·(L1/2 + L2) + k2·L2/2]·q = 47·q, error O(q²).
    const Eigen::Vector3d linear = straight + Eigen::Vector3d(47.0 * q3, 0.0, 0.0);
    EXPECT_LT((p - linear).norm(), 100.0 * q3 * q3 + 1e-12);
  }
  // Across the switch between the series and the closed form (bend 1e-4 rad) the value is smooth.
  const double q_switch = 1e-4 / 1.4;
  const Eigen::Vector3d below = cat.tip_pose(JV(0, 0, q_switch * (1 - 1e-9), 0)).position;
  const Eigen::Vector3d above = cat.tip_pose(JV(0, 0, q_switch * (1 + 1e-9), 0)).position;
  EXPECT_LT((below - above).norm(), 1e-10);
  const Eigen::Matrix<double, 3, 4> J = cat.tip_position_jacobian(JV(0, 0, 0, 0));
  EXPECT_TRUE(J.allFinite());
}

TEST(ConstantCurvatureCatheter, InsertionTranslatesAlongZ) {
  const ConstantCurvatureCatheter cat(params(10.0, 20.0, -0.44));
  const JV q(0.0, 0.4, 0.5, -0.6);
  JV moved = q;
  moved[0] = 12.5;
  expect_vec_near(cat.tip_pose(moved).position - cat.tip_pose(q).position, {0, 0, 12.5}, 1e-12);
}

TEST(ConstantCurvatureCatheter, JacobianMatchesAnalyticColumns) {
  const double L1 = 10.0, L2 = 20.0;
  const ConstantCurvatureCatheter cat(params(L1, L2, -0.44));
  const JV q(5.0, 0.3, 0.4, -0.5);
  const auto J = cat.tip_position_jacobian(q);
  const Eigen::Vector3d p = cat.tip_pose(q).position;
  expect_vec_near(J.col(0), Eigen::Vector3d::UnitZ(), 1e-7);
  expect_vec_near(J.col(1), Eigen::Vector3d::UnitZ().cross(p), 1e-6);
  // At the straight pose a small proximal bend φ moves the tip sideways by (L1/2 + L2)·φ.
  const auto J0 = cat.tip_position_jacobian(JV(0, 0, 0, 0));
  EXPECT_NEAR(J0(0, 2), 1.4 * (L1 / 2 + L2), 1e-6);
  EXPECT_NEAR(J0(2, 2), 0.0, 1e-6);
}

TEST(ConstantCurvatureCatheter, BackboneWithShaftAndBadSizes) {
  CatheterParameters p = params();
  p.shaft_length = 50.0;
  const ConstantCurvatureCatheter cat(p);
  std::vector<Eigen::Vector3d> pts(cat.backbone_point_count(8));
  ASSERT_EQ(pts.size(), 1u + 1u + 16u);
  const JV q(20.0, 0.0, 0.3, 0.2);
  ASSERT_EQ(cat.backbone(q, 8, pts), pts.size());
  expect_vec_near(pts[0], {0, 0, -30.0}, 1e-12);
  expect_vec_near(pts[1], {0, 0, 20.0}, 1e-12);
  // Chords are at most the arc step and close to it for these gentle bends.
  for (std::size_t i = 2; i < pts.size(); ++i) {
    const double step = (i <= 9) ? 10.0 / 8 : 20.0 / 8;
    const double chord = (pts[i] - pts[i - 1]).norm();
    EXPECT_LE(chord, step + 1e-12);
    EXPECT_GT(chord, 0.99 * step);
  }
  std::vector<Eigen::Vector3d> small(5);
  EXPECT_EQ(cat.backbone(q, 8, small), 0u);
  EXPECT_EQ(cat.backbone(q, 0, pts), 0u);
  p.proximal_length = 0.0;
  EXPECT_THROW(ConstantCurvatureCatheter{p}, std::invalid_argument);
}

}  // namespace
}  // namespace tendril::teleop
