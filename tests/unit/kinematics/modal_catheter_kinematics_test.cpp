#include "tendril/teleop/modal_catheter_kinematics.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"

namespace tendril::teleop {
namespace {

using JointVector = ModalCatheterKinematics::JointVector;

CatheterParameters flexed_parameters() {
  CatheterParameters p;
  p.proximal_length = 10.5;
  p.distal_length = 23.5;
  p.plane_offset = -0.44;
  p.proximal_curvature_gain = 1.4;
  p.distal_curvature_gain = 1.1;
  p.flexure = 0.2;
  return p;
}

// A non-trivial cubic-in-s, quadratic-in-q shape (n = 4, m = 3).
ModalCatheterParameters cubic_parameters() {
  ModalCatheterParameters p;
  p.proximal.length = 10.5;
  p.proximal.shape_matrix.resize(4, 3);
  p.proximal.shape_matrix << std::numbers::pi / 2, 0.01, 0.0,  //
      0.0, -0.09, 0.01,                                        //
      0.0, -0.004, 0.0005,                                     //
      0.0, 0.0002, -0.00002;
  p.distal.length = 13.8;
  p.distal.shape_matrix.resize(4, 2);
  p.distal.shape_matrix << std::numbers::pi / 2, 0.0,  //
      0.0, -0.06,                                      //
      0.0, -0.003,                                     //
      0.0, 0.0001;
  p.plane_offset = 0.07;
  p.flexure = -0.15;
  p.simpson_intervals = 64;
  return p;
}

const std::array<JointVector, 5> kJointSamples = {
    JointVector(0.0, 0.0, 0.0, 0.0), JointVector(5.0, 0.3, 0.5, -0.4), JointVector(-2.0, -1.2, -0.9, 1.0),
    JointVector(12.0, 2.5, 1.0, 0.8), JointVector(0.0, 0.0, 0.05, 0.0)};

TEST(ModalCatheterKinematics, ConstantCurvatureShapeMatrixMatchesClosedFormModel) {
  const auto cc_parameters = flexed_parameters();
  const ConstantCurvatureCatheter closed_form(cc_parameters);
  ModalCatheterParameters modal_parameters = constant_curvature_modal_parameters(cc_parameters);
  modal_parameters.simpson_intervals = 64;
  // The brief's shape matrix written out, so the test does not rely on the helper alone.
  EXPECT_DOUBLE_EQ(modal_parameters.proximal.shape_matrix(0, 0), std::numbers::pi / 2);
  EXPECT_DOUBLE_EQ(modal_parameters.proximal.shape_matrix(1, 1), -1.4 / 10.5);
  const ModalCatheterKinematics modal(modal_parameters);

  for (const auto& q : kJointSamples) {
    const TipPose expected = closed_form.tip_pose(q);
    const TipPose actual = modal.tip_pose(q);
    EXPECT_LT((actual.position - expected.position).norm(), 1e-6) << "q = " << q.transpose();
    EXPECT_LT((actual.rotation - expected.rotation).norm(), 1e-9) << "q = " << q.transpose();
    EXPECT_NEAR(std::numbers::pi / 2 - modal.tip_angle(CatheterSegment::kProximal, q[2]),
                closed_form.proximal_bend(q), 1e-12);
    EXPECT_NEAR(std::numbers::pi / 2 - modal.tip_angle(CatheterSegment::kDistal, q[3]),
                closed_form.distal_bend(q), 1e-12);

    std::vector<Eigen::Vector3d> expected_backbone(closed_form.backbone_point_count(7));
    std::vector<Eigen::Vector3d> actual_backbone(modal.backbone_point_count(7));
    ASSERT_EQ(closed_form.backbone(q, 7, expected_backbone), expected_backbone.size());
    ASSERT_EQ(modal.backbone(q, 7, actual_backbone), actual_backbone.size());
    for (std::size_t i = 0; i < actual_backbone.size(); ++i) {
      EXPECT_LT((actual_backbone[i] - expected_backbone[i]).norm(), 1e-6) << "point " << i;
    }
  }
}

TEST(ModalCatheterKinematics, PositiveProximalActuationBendsTowardPlusX) {
  auto p = flexed_parameters();
  p.flexure = 0.0;  // a passive flexure would tilt even a straight catheter
  const ModalCatheterKinematics modal(constant_curvature_modal_parameters(p));
  const Eigen::Vector3d straight = modal.segment_displacement(CatheterSegment::kProximal, 10.5, 0.0);
  EXPECT_NEAR(straight.x(), 0.0, 1e-12);
  EXPECT_NEAR(straight.z(), 10.5, 1e-9);
  const Eigen::Vector3d bent = modal.segment_displacement(CatheterSegment::kProximal, 10.5, 0.5);
  EXPECT_GT(bent.x(), 0.5);
  EXPECT_LT(bent.z(), 10.5);
  // Straight catheter tip along +z at q1 + L1 + L2.
  const TipPose tip = modal.tip_pose(JointVector(3.0, 0.0, 0.0, 0.0));
  EXPECT_LT((tip.position - Eigen::Vector3d(0, 0, 3.0 + 10.5 + 23.5)).norm(), 1e-9);
}

TEST(ModalCatheterKinematics, SimpsonConvergesAtFourthOrder) {
  // Constant curvature has the closed form d = L·[(1 − cos b)/b, 0, sin b/b], b = k·q.
  const double L = 10.5, k = 1.4, q = 1.0, b = k * q;
  const Eigen::Vector3d exact(L * (1 - std::cos(b)) / b, 0.0, L * std::sin(b) / b);
  std::vector<double> errors;
  for (int intervals : {2, 4, 8, 16, 32}) {
    auto p = constant_curvature_modal_parameters(flexed_parameters());
    p.simpson_intervals = intervals;
    const ModalCatheterKinematics modal(p);
    errors.push_back((modal.segment_displacement(CatheterSegment::kProximal, L, q) - exact).norm());
  }
  for (std::size_t i = 1; i < errors.size(); ++i) {
    const double ratio = errors[i - 1] / errors[i];
    EXPECT_GT(ratio, 14.0) << "halving h should cut the error ~16×, step " << i;
    EXPECT_LT(ratio, 18.0) << "step " << i;
  }
  EXPECT_LT(errors.back(), 1e-6);
}

TEST(ModalCatheterKinematics, TipAngleRateMatchesFiniteDifferenceAndIsConstantForLinearActuation) {
  const ModalCatheterKinematics modal(cubic_parameters());
  for (double q : {-0.8, 0.0, 0.4, 1.1}) {
    const double h = 1e-6;
    const double numeric = (modal.tip_angle(CatheterSegment::kProximal, q + h) -
                            modal.tip_angle(CatheterSegment::kProximal, q - h)) /
                           (2 * h);
    EXPECT_NEAR(modal.tip_angle_rate(CatheterSegment::kProximal, q), numeric, 1e-7);
  }
  // m = 2: ∂θ_L/∂q = Ψ(L)ᵀ·A·[0, 1]ᵀ, independent of q.
  const double L2 = 13.8;
  const double expected = -0.06 * L2 - 0.003 * L2 * L2 + 0.0001 * L2 * L2 * L2;
  EXPECT_NEAR(modal.tip_angle_rate(CatheterSegment::kDistal, -0.5), expected, 1e-12);
  EXPECT_NEAR(modal.tip_angle_rate(CatheterSegment::kDistal, 0.9), expected, 1e-12);
}

TEST(ModalCatheterKinematics, PositionJacobianMatchesCentralDifferences) {
  const ModalCatheterKinematics modal(cubic_parameters());
  for (const auto& q : kJointSamples) {
    const auto J = modal.tip_position_jacobian(q);
    for (int j = 0; j < 4; ++j) {
      JointVector plus = q, minus = q;
      const double h = 1e-5;
      plus[j] += h;
      minus[j] -= h;
      const Eigen::Vector3d numeric =
          (modal.tip_pose(plus).position - modal.tip_pose(minus).position) / (2 * h);
      EXPECT_LT((J.col(j) - numeric).norm(), 1e-6) << "column " << j << " at q = " << q.transpose();
    }
  }
}

TEST(ModalCatheterKinematics, EvaluationDoesNotAllocate) {
  const ModalCatheterKinematics modal(cubic_parameters());
  std::array<Eigen::Vector3d, 21> backbone{};
  const JointVector q(4.0, 0.5, 0.6, -0.3);
  const long before = tendril::testing::allocation_count.load();
  const TipPose tip = modal.tip_pose(q);
  const auto J = modal.tip_position_jacobian(q);
  const std::size_t written = modal.backbone(q, 10, backbone);
  const double angle = modal.tip_angle(CatheterSegment::kDistal, q[3]);
  const long after = tendril::testing::allocation_count.load();
  EXPECT_EQ(after, before);
  EXPECT_EQ(written, 21u);
  EXPECT_TRUE(tip.position.allFinite() && J.allFinite() && std::isfinite(angle));
  // The backbone integrates piece by piece with at least a whole segment's Simpson step (here 4 of
  // 10 pieces' intervals against 32 for the tip), so the two quadratures agree far below a nanometre.
  EXPECT_LT((backbone.back() - tip.position).norm(), 1e-7);
}

TEST(ModalCatheterKinematics, BackboneRejectsTooSmallOutput) {
  const ModalCatheterKinematics modal(cubic_parameters());
  std::array<Eigen::Vector3d, 5> small{};
  EXPECT_EQ(modal.backbone(JointVector::Zero(), 10, small), 0u);
  EXPECT_EQ(modal.backbone(JointVector::Zero(), 0, small), 0u);
}

TEST(ModalCatheterKinematics, ConstructorRejectsBadParameters) {
  auto expect_rejected = [](ModalCatheterParameters p, const char* fragment) {
    try {
      ModalCatheterKinematics modal(p);
      ADD_FAILURE() << "accepted parameters that should fail with '" << fragment << "'";
    } catch (const std::invalid_argument& error) {
      EXPECT_NE(std::string(error.what()).find(fragment), std::string::npos) << error.what();
    }
  };
  auto p = cubic_parameters();
  p.proximal.length = 0.0;
  expect_rejected(p, "length");
  p = cubic_parameters();
  p.distal.shape_matrix(2, 1) = std::nan("");
  expect_rejected(p, "NaN");
  p = cubic_parameters();
  p.distal.shape_matrix = Eigen::MatrixXd::Zero(7, 2);
  expect_rejected(p, "shape matrix must be n×m");
  p = cubic_parameters();
  p.proximal.shape_matrix.resize(0, 0);
  expect_rejected(p, "shape matrix must be n×m");
  p = cubic_parameters();
  p.simpson_intervals = 7;
  expect_rejected(p, "simpson_intervals");
  p = cubic_parameters();
  p.plane_offset = INFINITY;
  expect_rejected(p, "finite");
}

}  // namespace
}  // namespace tendril::teleop
