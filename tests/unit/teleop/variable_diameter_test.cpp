// The variable-diameter multi-backbone continuum robot (MBCR, Abah 2022, ch. 2): angulated scissor
// linkage (ASL) numbers for the geometry of Table 2.3, Jacobians against finite differences, statics against
// the virtual-work balance, and the dissertation's circle experiment (Abah 2022, §2.7.2): the diameter grows,
// is pushed back by disk interference, grows again, and the RMS actuation force drops against a fixed
// diameter.
#include <gtest/gtest.h>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

#include "allocation_counter.hpp"
#include "tendril/teleop/variable_diameter_linkage.hpp"
#include "tendril/teleop/variable_diameter_robot.hpp"
#include "tendril/teleop/variable_diameter_segment.hpp"
#include "tendril/teleop/variable_diameter_simulation.hpp"

namespace tendril::teleop {
namespace {

constexpr double kPi = std::numbers::pi;

ScissorLinkageParameters linkage_with(int n, double d = 2.0) {
  ScissorLinkageParameters p;
  p.rhombus_count = n;
  p.hinge_diameter = d;
  return p;
}

// ---------------------------------------------------------------------------------------------------
// ASL position analysis and limits (Abah 2022, §2.3)

TEST(ScissorLinkage, ElbowAngleIsConstantForEqualArmsT21) {
  for (int n = 3; n <= 10; ++n) {
    const ScissorLinkage linkage(linkage_with(n, 1.0));
    const double expected = kPi - 2.0 * kPi / n;
    for (double r = 20.0; r <= linkage.configuration_radius_max(); r += 0.25) {
      EXPECT_NEAR(linkage.elbow_angle(r), expected, 1e-6) << "n = " << n << ", r = " << r;
    }
  }
  const ScissorLinkage table_2_3(linkage_with(8));
  EXPECT_NEAR(table_2_3.elbow_angle(30.0) * 180.0 / kPi, 135.0, 1e-6);  // Table 2.3
}

TEST(ScissorLinkage, OuterRadiusPeakT22) {
  const ScissorLinkage linkage(linkage_with(8));
  EXPECT_NEAR(linkage.outer_radius_peak(), 52.263, 1e-3);
  EXPECT_NEAR(linkage.configuration_radius_at_outer_peak(), 48.284, 1e-3);
  EXPECT_NEAR(linkage.outer_radius(48.284271), 52.263, 1e-3);
  EXPECT_NEAR(linkage.outer_radius_rate(linkage.configuration_radius_at_outer_peak()), 0.0, 1e-12);  // (2.12)
  EXPECT_NEAR(linkage.outer_radius_max(), 52.263, 1e-3);
}

TEST(ScissorLinkage, RangeOfMotionT23) {
  const ScissorLinkage linkage(linkage_with(8, 2.0));
  EXPECT_NEAR(linkage.configuration_radius_min(), 22.389, 1e-3);
  EXPECT_NEAR(linkage.configuration_radius_max(), 52.197, 1e-3);
  EXPECT_NEAR(linkage.inner_radius_min(), 2.613, 1e-3);
  EXPECT_NEAR(linkage.inner_radius_max(), 47.224, 1e-3);
  EXPECT_NEAR(linkage.outer_radius_min(), 38.757, 1e-3);
  // The two limits are what they are named after: (2.7) inner hinges touch at r_min, and the inner
  // hinges touch the outer ones (b − a = d) at r_max.
  EXPECT_NEAR(linkage.inner_radius_min(), 2.0 / (2.0 * std::sin(kPi / 8)), 1e-9);
  const double r_max = linkage.configuration_radius_max();
  EXPECT_NEAR(linkage.outer_radius(r_max) - linkage.inner_radius(r_max), 2.0, 1e-9);
  // The dissertation's "26 % change of the outer diameter" for n = 8, with our d = 2 mm (Abah 2022, §2.3.4).
  const double change =
      (linkage.outer_radius_max() - linkage.outer_radius_min()) / linkage.outer_radius_max();
  EXPECT_NEAR(change, 0.26, 0.005);
}

TEST(ScissorLinkage, OuterMinimumSwitchesBranchAtSixRhombusesT24) {
  for (int n = 3; n <= 12; ++n) {
    const ScissorLinkage linkage(linkage_with(n, 1.0));
    const double at_min = linkage.outer_radius(linkage.configuration_radius_min());
    const double at_max = linkage.outer_radius(linkage.configuration_radius_max());
    if (n < 6) {
      EXPECT_DOUBLE_EQ(linkage.outer_radius_min(), at_max) << "n = " << n;
      EXPECT_LT(at_max, at_min) << "n = " << n << ": b must move against r";
    } else {
      EXPECT_DOUBLE_EQ(linkage.outer_radius_min(), at_min) << "n = " << n;
      EXPECT_LE(at_min, at_max + 1e-9) << "n = " << n;  // equal for n = 6
    }
  }
}

TEST(ScissorLinkage, InnerRadiusRisesWithConfigurationRadiusT25) {
  for (int n = 3; n <= 12; ++n) {
    const ScissorLinkage linkage(linkage_with(n, 1.0));
    const double lo = linkage.configuration_radius_min(), hi = linkage.configuration_radius_max();
    for (int i = 0; i <= 200; ++i) {
      const double r = lo + (hi - lo) * i / 200.0;
      EXPECT_GT(linkage.inner_radius_rate(r), 0.0) << "n = " << n << ", r = " << r;
    }
  }
}

TEST(ScissorLinkage, InverseAndDerivativesAgree) {
  const ScissorLinkage linkage(linkage_with(8));
  for (double r = linkage.configuration_radius_min(); r <= linkage.configuration_radius_max(); r += 1.0) {
    const double a = linkage.inner_radius(r);
    EXPECT_NEAR(linkage.configuration_radius(a), r, 1e-9);  // (2.8) inverts (2.1)
    const double h = 1e-6;
    EXPECT_NEAR(linkage.inner_radius_rate(r),
                (linkage.inner_radius(r + h) - linkage.inner_radius(r - h)) / (2 * h), 1e-6);
    EXPECT_NEAR(linkage.outer_radius_rate(r),
                (linkage.outer_radius(r + h) - linkage.outer_radius(r - h)) / (2 * h), 1e-6);
    EXPECT_NEAR(linkage.configuration_radius_rate(a),
                (linkage.configuration_radius(a + h) - linkage.configuration_radius(a - h)) / (2 * h), 1e-6);
  }
  // Outside (2.3) there is no linkage: NaN, not a number that looks right.
  EXPECT_TRUE(std::isnan(linkage.inner_radius(20.0 / std::sin(kPi / 8) + 0.1)));
  EXPECT_TRUE(std::isnan(linkage.outer_radius(std::nan(""))));
}

TEST(ScissorLinkage, ConfigurationRadiusForAnOuterLimit) {
  const ScissorLinkage linkage(linkage_with(8));
  for (double b = 39.0; b < 52.2; b += 1.0) {
    const double r = linkage.configuration_radius_for_outer_limit(b);
    EXPECT_NEAR(linkage.outer_radius(r), b, 1e-9);
    EXPECT_LE(r, linkage.configuration_radius_at_outer_max());
  }
  EXPECT_DOUBLE_EQ(linkage.configuration_radius_for_outer_limit(60.0), linkage.configuration_radius_max());
  EXPECT_TRUE(std::isnan(linkage.configuration_radius_for_outer_limit(30.0)));  // below b_min
}

TEST(ScissorLinkage, RejectsImpossibleLinkagesWithAClearMessage) {
  auto message = [](const ScissorLinkageParameters& p) {
    try {
      ScissorLinkage linkage(p);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no exception");
  };
  EXPECT_NE(message(linkage_with(2)).find("rhombus_count (n)"), std::string::npos);
  EXPECT_NE(message(linkage_with(8, -1.0)).find("hinge_diameter (d)"), std::string::npos);
  EXPECT_NE(message(linkage_with(8, 45.0)).find("hinge_diameter (d)"), std::string::npos);
  ScissorLinkageParameters nan_arm = linkage_with(8);
  nan_arm.inner_arm_length = std::nan("");
  EXPECT_NE(message(nan_arm).find("inner_arm_length (l1)"), std::string::npos);
  ScissorLinkageParameters short_outer = linkage_with(8);
  short_outer.outer_arm_length = 10.0;
  EXPECT_NE(message(short_outer).find("outer_arm_length (l2)"), std::string::npos);
}

// ---------------------------------------------------------------------------------------------------
// Disk interference (Abah 2022, §2.4)

TEST(DiskInterference, DimensionalAndPackingFractionFormsAgreeT26) {
  const DiskInterferenceParameters disks;  // Table 2.3: L = 200, n_d = 8, h_d = 10 (PF 0.4)
  validate(disks);
  const double pf = disks.disk_count * disks.disk_height / disks.segment_length;
  EXPECT_NEAR(pf, 0.4, 1e-12);
  for (double bend = 0.05; bend < kPi; bend += 0.05) {
    const double b = interference_outer_radius_limit(disks, -bend);
    EXPECT_NEAR(b / disks.segment_length, interference_outer_radius_ratio(pf, disks.disk_count, -bend),
                1e-12);
    // (2.15), the triangle it came from.
    const double rho = (disks.segment_length - disks.disk_height) / bend;
    EXPECT_NEAR(std::tan(bend / (2.0 * (disks.disk_count - 1))), disks.disk_height / 2.0 / (rho - b), 1e-12);
    EXPECT_DOUBLE_EQ(b, interference_outer_radius_limit(disks, bend)) << "even in the bend";
    EXPECT_LT(interference_outer_radius_limit(disks, bend + 0.05), b) << "more bending, less room";
  }
  EXPECT_TRUE(std::isinf(interference_outer_radius_limit(disks, 0.0)));
  // A bend of 90° leaves ~77 mm; the linkage's 52.3 mm reaches the limit only beyond ~132° (2.31 rad).
  EXPECT_NEAR(interference_outer_radius_limit(disks, -kPi / 2), 76.58, 0.01);
  DiskInterferenceParameters crowded = disks;
  crowded.disk_height = 30.0;
  EXPECT_THROW(validate(crowded), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------------
// One segment: kinematics (§2.5) and statics (§2.6.1)

constexpr double kLength = 200.0;

SegmentConfiguration random_configuration(std::mt19937& rng) {
  std::uniform_real_distribution<double> bend(-2.5, 2.5), plane(-kPi, kPi);
  return {kStraightTangentAngle + bend(rng), plane(rng)};
}

Eigen::Vector3d rotation_rate(const Eigen::Matrix3d& plus, const Eigen::Matrix3d& minus,
                              const Eigen::Matrix3d& at, double h) {
  const Eigen::Matrix3d w = (plus - minus) / (2.0 * h) * at.transpose();
  return {w(2, 1), w(0, 2), w(1, 0)};
}

TEST(VariableDiameterSegment, BackboneJacobianMatchesFiniteDifferences) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 50; ++trial) {
    const SegmentConfiguration psi = random_configuration(rng);
    const SegmentJointJacobian j = backbone_jacobian(psi, 30.0);
    for (int c = 0; c < 2; ++c) {
      const double h = 1e-6;
      SegmentConfiguration plus = psi, minus = psi;
      plus[c] += h;
      minus[c] -= h;
      const Eigen::Vector4d fd =
          (backbone_displacements(plus, 30.0) - backbone_displacements(minus, 30.0)) / (2 * h);
      EXPECT_LT((j.col(c) - fd).norm(), 1e-6);
    }
  }
}

TEST(VariableDiameterSegment, AugmentedJacobianIsConsistentT27) {
  std::mt19937 rng(11);
  const ScissorLinkage linkage(linkage_with(8));
  for (int trial = 0; trial < 50; ++trial) {
    const SegmentConfiguration psi = random_configuration(rng);
    const double a = 3.0 + trial * 0.8;
    const double r = linkage.configuration_radius(a), dr_da = linkage.configuration_radius_rate(a);
    const SegmentAugmentation big_a = augmentation_matrix(psi, dr_da);
    const SegmentAugmentedJacobian j = augmented_jacobian(psi, r, dr_da);
    EXPECT_LT((big_a * j - backbone_jacobian(psi, r)).norm(), 1e-9);  // A·J_q̃ψ = J_qψ
    // The closed-form A⁺ is the Moore–Penrose one.
    const Eigen::Matrix<double, 5, 4> pinv = big_a.completeOrthogonalDecomposition().pseudoInverse();
    EXPECT_LT((pinv * backbone_jacobian(psi, r) - j).norm(), 1e-9);
  }
}

TEST(VariableDiameterSegment, TwistJacobianMatchesFiniteDifferencesIncludingStraight) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 60; ++trial) {
    SegmentConfiguration psi = random_configuration(rng);
    if (trial < 5) psi[0] = kStraightTangentAngle + (trial - 2) * 3e-5;  // the Taylor branch
    const SegmentTwistJacobian j = segment_twist_jacobian(psi, kLength);
    for (int c = 0; c < 2; ++c) {
      const double h = 1e-6;
      SegmentConfiguration plus = psi, minus = psi;
      plus[c] += h;
      minus[c] -= h;
      const Eigen::Isometry3d pp = segment_end_pose(plus, kLength), pm = segment_end_pose(minus, kLength);
      const Eigen::Vector3d v = (pp.translation() - pm.translation()) / (2 * h);
      const Eigen::Vector3d w =
          rotation_rate(pp.linear(), pm.linear(), segment_end_pose(psi, kLength).linear(), h);
      EXPECT_LT((j.block<3, 1>(0, c) - v).norm(), 1e-5) << "trial " << trial << " column " << c;
      EXPECT_LT((j.block<3, 1>(3, c) - w).norm(), 1e-7) << "trial " << trial << " column " << c;
    }
  }
  const Eigen::Isometry3d straight = segment_end_pose({kStraightTangentAngle, 0.3}, kLength);
  EXPECT_LT((straight.translation() - Eigen::Vector3d(0, 0, kLength)).norm(), 1e-12);
  // Bent by 90° towards δ = 0: the end sits on a quarter circle of radius 2L/π towards +x, facing +x.
  const Eigen::Isometry3d quarter = segment_end_pose({0.0, 0.0}, kLength);
  EXPECT_LT((quarter.translation() - 2 * kLength / kPi * Eigen::Vector3d(1, 0, 1)).norm(), 1e-9);
  EXPECT_LT((quarter.linear().col(2) - Eigen::Vector3d::UnitX()).norm(), 1e-12);
  // ... where backbone 1 (at +x) is the shortened one.
  EXPECT_LT(backbone_displacements({0.0, 0.0}, 30.0)[0], 0.0);
}

TEST(VariableDiameterSegment, EnergyGradientsMatchFiniteDifferencesWithTheCorrectedSquare) {
  std::mt19937 rng(5);
  const double ei = backbone_bending_stiffness(74000.0, 1.0);
  EXPECT_NEAR(ei, 74000.0 * kPi / 64.0, 1e-9);  // ≈ 3.6e3 N·mm² (E = 74 GPa)
  for (int trial = 0; trial < 30; ++trial) {
    const SegmentConfiguration psi = random_configuration(rng);
    const double r = 25.0 + trial, h = 1e-5;
    const double du_dr =
        (elastic_energy(psi, r + h, kLength, ei) - elastic_energy(psi, r - h, kLength, ei)) / (2 * h);
    EXPECT_NEAR(elastic_energy_radius_gradient(psi, r, kLength, ei), du_dr, 1e-6 * (1 + std::abs(du_dr)));
    const Eigen::Vector2d grad = elastic_energy_configuration_gradient(psi, r, kLength, ei);
    for (int c = 0; c < 2; ++c) {
      SegmentConfiguration plus = psi, minus = psi;
      plus[c] += h;
      minus[c] -= h;
      const double fd =
          (elastic_energy(plus, r, kLength, ei) - elastic_energy(minus, r, kLength, ei)) / (2 * h);
      EXPECT_NEAR(grad[c], fd, 1e-6 * (1 + std::abs(fd)));
    }
  }
}

TEST(VariableDiameterSegment, StaticsBalanceVirtualWork) {
  std::mt19937 rng(13);
  const ScissorLinkage linkage(linkage_with(8));
  const double ei = backbone_bending_stiffness(74000.0, 1.0);
  std::uniform_real_distribution<double> load(-20.0, 20.0);
  for (int trial = 0; trial < 40; ++trial) {
    const SegmentConfiguration psi = random_configuration(rng);
    const double a = 5.0 + trial, r = linkage.configuration_radius(a),
                 dr_da = linkage.configuration_radius_rate(a);
    Wrench w;
    w << load(rng), load(rng), load(rng), 100 * load(rng), 100 * load(rng), 100 * load(rng);
    SegmentStatics statics;
    ASSERT_TRUE(segment_statics(psi, r, dr_da, kLength, ei, w, statics));
    // (2.25) for every virtual displacement Δψ: W_eᵀΔx + τ̃ᵀΔq̃ − ∇U_rΔr − ∇U_ψᵀΔψ = 0.
    const SegmentTwistJacobian jx = segment_twist_jacobian(psi, kLength);
    const double grad_r = elastic_energy_radius_gradient(psi, r, kLength, ei);
    const Eigen::Vector2d grad_psi = elastic_energy_configuration_gradient(psi, r, kLength, ei);
    for (int c = 0; c < 2; ++c) {
      const Eigen::Vector2d d = Eigen::Vector2d::Unit(c);
      const double work = w.dot(jx * d) + statics.actuation.dot(statics.augmented_jacobian * d) -
                          grad_r * statics.radius_jacobian.dot(d) - grad_psi.dot(d);
      EXPECT_NEAR(work, 0.0, 1e-8 * (1.0 + w.norm() * kLength)) << "trial " << trial;
    }
  }
  SegmentStatics bad;
  EXPECT_FALSE(segment_statics({std::nan(""), 0.0}, 30.0, 1.0, kLength, ei, Wrench::Zero(), bad));
  EXPECT_TRUE(bad.actuation.isZero());
}

// ---------------------------------------------------------------------------------------------------
// The three-segment robot (§2.7.1)

StackConfiguration random_stack(std::mt19937& rng) {
  StackConfiguration psi;
  for (int k = 0; k < 3; ++k) psi.segment<2>(2 * k) = random_configuration(rng);
  return psi;
}

TEST(VariableDiameterRobot, StackedTwistJacobianMatchesFiniteDifferences) {
  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  VariableDiameterData data = robot.make_data();
  StackConfiguration straight;
  straight << kStraightTangentAngle, 0, kStraightTangentAngle, 0, kStraightTangentAngle, 0;
  EXPECT_LT((robot.tip_pose(straight, data).translation() - Eigen::Vector3d(0, 0, 600)).norm(), 1e-9);
  std::mt19937 rng(17);
  for (int trial = 0; trial < 20; ++trial) {
    const StackConfiguration psi = random_stack(rng);
    const Eigen::Isometry3d pose = robot.tip_pose(psi, data);
    const StackTwistJacobian j = data.task_jacobian;
    for (int c = 0; c < 6; ++c) {
      const double h = 1e-6;
      StackConfiguration plus = psi, minus = psi;
      plus[c] += h;
      minus[c] -= h;
      const Eigen::Isometry3d pp = robot.tip_pose(plus, data), pm = robot.tip_pose(minus, data);
      EXPECT_LT((j.block<3, 1>(0, c) - (pp.translation() - pm.translation()) / (2 * h)).norm(), 1e-4);
      EXPECT_LT((j.block<3, 1>(3, c) - rotation_rate(pp.linear(), pm.linear(), pose.linear(), h)).norm(),
                1e-7);
    }
  }
}

TEST(VariableDiameterRobot, NullSpaceMotionLeavesTheConfigurationUnchangedT28) {
  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  std::mt19937 rng(19);
  std::normal_distribution<double> normal;
  for (int trial = 0; trial < 20; ++trial) {
    const StackConfiguration psi = random_stack(rng);
    const double a = 3.0 + 2.0 * trial;
    const Eigen::Matrix<double, 6, 7> as = robot.augmentation_matrix(psi, a);
    const Eigen::Matrix<double, 7, 6> pinv = as.completeOrthogonalDecomposition().pseudoInverse();
    StackJoints eta;
    for (int i = 0; i < 7; ++i) eta[i] = normal(rng);
    const StackJoints projected = (Eigen::Matrix<double, 7, 7>::Identity() - pinv * as) * eta;
    EXPECT_LT((as * projected).norm(), 1e-10);  // A_s(I − A_s⁺A_s)η = 0
    const StackJoints n = robot.null_space_direction(psi, a);
    EXPECT_LT((as * n).norm(), 1e-12);
    EXPECT_LT((projected - n * n.dot(eta)).norm(), 1e-9);  // I − A_s⁺A_s = nnᵀ
    // Moving along n changes the backbones exactly as (2.19) does when a changes at fixed ψ.
    const double h = 1e-6;
    const StackJoints fd = (robot.joints(psi, a + h) - robot.joints(psi, a - h)) / (2 * h);
    EXPECT_LT((fd / fd[6] - n / n[6]).norm(), 1e-6);
  }
}

TEST(VariableDiameterRobot, StackedStaticsBalanceVirtualWork) {
  VariableDiameterRobotParameters params;
  const VariableDiameterRobot robot(params);
  VariableDiameterData data = robot.make_data();
  std::mt19937 rng(23);
  const Wrench payload = (Wrench() << 0.0, 0.0, -19.62, 0.0, 0.0, 0.0).finished();
  for (int trial = 0; trial < 20; ++trial) {
    const StackConfiguration psi = random_stack(rng);
    const double a = 3.0 + 2.0 * trial;
    StackActuation tau;
    ASSERT_TRUE(robot.actuation(psi, a, payload, data, tau));
    // (2.29): J_q̃ψᵀτ̃ equals the generalised load, i.e. the virtual work of every Δψ balances.
    EXPECT_LT((data.augmented_jacobian.transpose() * tau - data.generalized_load).norm(),
              1e-8 * (1.0 + data.generalized_load.norm()));
    // The payload's share: with a negligible stiffness, W_eᵀJ_xψΔψ + τ̃ᵀJ_q̃ψΔψ = 0.
  }
  params.youngs_modulus = 1e-9;
  const VariableDiameterRobot limp(params);
  for (int trial = 0; trial < 10; ++trial) {
    const StackConfiguration psi = random_stack(rng);
    StackActuation tau;
    ASSERT_TRUE(limp.actuation(psi, 20.0, payload, data, tau));
    const Eigen::Matrix<double, 1, 6> work =
        payload.transpose() * data.task_jacobian + tau.transpose() * data.augmented_jacobian;
    EXPECT_LT(work.norm(), 1e-8 * 19.62 * 600.0);
  }
  StackActuation tau;
  EXPECT_FALSE(robot.actuation(random_stack(rng), 100.0, payload, data, tau)) << "a beyond the linkage";
  EXPECT_TRUE(tau.isZero());
}

TEST(VariableDiameterRobot, DiameterLimitsFollowTheBend) {
  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  const ScissorLinkage& linkage = robot.linkage();
  StackConfiguration psi;
  psi << kStraightTangentAngle, 0, kStraightTangentAngle, 0, kStraightTangentAngle, 0;
  DiameterLimits limits = robot.diameter_limits(psi);
  EXPECT_DOUBLE_EQ(limits.lower, linkage.inner_radius_min());
  EXPECT_DOUBLE_EQ(limits.upper, linkage.inner_radius_max());
  EXPECT_TRUE(std::isinf(limits.interference));
  // Bend one segment by 2.6 rad: its disks allow b ≈ 46.6 mm, so a must stay below the matching a.
  psi[2] = kStraightTangentAngle - 2.6;
  limits = robot.diameter_limits(psi);
  const double b_limit = interference_outer_radius_limit(robot.parameters().disks, -2.6);
  EXPECT_LT(limits.upper, linkage.inner_radius_max());
  EXPECT_NEAR(linkage.outer_radius(linkage.configuration_radius(limits.upper)), b_limit, 1e-9);
  EXPECT_FALSE(limits.interference_unavoidable);
  // Past ~3.13 rad (179°) even the folded linkage's disks touch.
  psi[4] = kStraightTangentAngle - 3.2;
  limits = robot.diameter_limits(psi);
  EXPECT_TRUE(limits.interference_unavoidable);
  EXPECT_DOUBLE_EQ(limits.upper, limits.lower);
}

TEST(VariableDiameterRobot, LimitCostGradientMatchesFiniteDifferences) {
  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  const DiameterLimits limits{.lower = 2.6, .upper = 30.0, .interference = 30.0};
  StackJoints q;
  q << -150.0, 20.0, 0.0, 199.0, -10.0, 50.0, 27.0;
  StackJoints gradient;
  robot.limit_cost(q, limits, &gradient);
  for (int i = 0; i < 7; ++i) {
    const double h = 1e-6;
    StackJoints plus = q, minus = q;
    plus[i] += h;
    minus[i] -= h;
    const double fd =
        (robot.limit_cost(plus, limits, nullptr) - robot.limit_cost(minus, limits, nullptr)) / (2 * h);
    EXPECT_NEAR(gradient[i], fd, 1e-6 * (1 + std::abs(fd))) << "joint " << i;
  }
}

TEST(VariableDiameterRobot, RejectsBadParametersAndBadInput) {
  VariableDiameterRobotParameters p;
  p.youngs_modulus = 0.0;
  EXPECT_THROW(VariableDiameterRobot{p}, std::invalid_argument);
  p = {};
  p.backbone_lower = 10.0;
  EXPECT_THROW(VariableDiameterRobot{p}, std::invalid_argument);
  p = {};
  p.redundancy.step_gain = -1.0;
  EXPECT_THROW(VariableDiameterRobot{p}, std::invalid_argument);
  p = {};
  p.disks.disk_count = 1;
  EXPECT_THROW(VariableDiameterRobot{p}, std::invalid_argument);

  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  VariableDiameterData data = robot.make_data();
  VariableDiameterState state;
  state.configuration << 1.0, 0.2, 1.2, 0.3, 1.1, -0.4;
  state.diameter_joint = 10.0;
  const VariableDiameterState before = state;
  Eigen::Isometry3d target = robot.tip_pose(state.configuration, data);
  StackTwist twist = StackTwist::Zero();
  twist[0] = std::nan("");
  const auto report = robot.step(state, target, twist, Wrench::Zero(), 1e-3, true, data);
  EXPECT_EQ(report.status, VariableDiameterStatus::kNonFinite);
  EXPECT_EQ(state.configuration, before.configuration);
  EXPECT_EQ(state.diameter_joint, before.diameter_joint);
}

TEST(VariableDiameterRobot, StepDoesNotAllocate) {
  const VariableDiameterRobot robot{VariableDiameterRobotParameters{}};
  const CircleTrajectoryParameters circle;
  VariableDiameterData data = robot.make_data();
  VariableDiameterState varying, fixed;
  varying.configuration = circle_start_configuration(robot, circle);
  varying.diameter_joint = robot.linkage().inner_radius_min() + 0.05;
  fixed = varying;
  fixed.diameter_joint = robot.linkage().inner_radius_min();
  double sink = 0.0;
  const long before = tendril::testing::allocation_count.load();
  for (int i = 0; i < 200; ++i) {
    const double t = (i + 1) * circle.dt;
    sink += robot
                .step(varying, circle_pose(circle, t), circle_twist(circle, t), circle.payload, circle.dt,
                      true, data)
                .force_norm;
    sink += robot
                .step(fixed, circle_pose(circle, t), circle_twist(circle, t), circle.payload, circle.dt,
                      false, data)
                .force_norm;
    sink += robot.diameter_limits(varying.configuration).upper;
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
  EXPECT_GT(varying.diameter_joint, fixed.diameter_joint) << "the diameter moved off a_min";
}

// ---------------------------------------------------------------------------------------------------
// The dissertation's circle experiment (Abah 2022, §2.7.2)

struct CircleOutcome {
  CircleRun fixed, variable;
  ForceComparison forces;
};

CircleOutcome run_circle(const VariableDiameterRobotParameters& params, CircleBranch branch,
                         const char* label) {
  const VariableDiameterRobot robot(params);
  const CircleTrajectoryParameters circle;
  const StackConfiguration start = circle_start_configuration(robot, circle, branch);
  VariableDiameterData data = robot.make_data();
  EXPECT_LT(pose_error(circle_pose(circle, 0.0), robot.tip_pose(start, data)).norm(), 1e-6);
  CircleOutcome out{
      simulate_circle(robot, circle, start, false), simulate_circle(robot, circle, start, true), {}};
  out.forces = compare_forces(out.fixed, out.variable);
  std::printf(
      "[%s] RMS ‖τ̃‖: fixed a_min %.1f N, varying %.1f N; reduction RMS %.1f N, mean %.1f N, std %.1f N, "
      "min %.2f N, max %.1f N (seed: 48.3 ± 17.6 N); clamped steps fixed %zu, varying %zu of %zu\n",
      label, out.forces.rms_fixed, out.forces.rms_variable, out.forces.rms_reduction,
      out.forces.mean_reduction, out.forces.std_reduction, out.forces.min_reduction, out.forces.max_reduction,
      out.fixed.clamped_steps, out.variable.clamped_steps, out.variable.samples.size());
  return out;
}

void expect_limits_respected(const VariableDiameterRobot& robot, const CircleRun& run) {
  for (const CircleSample& s : run.samples) {
    ASSERT_GE(s.diameter_joint, robot.linkage().inner_radius_min() - 1e-12) << "t = " << s.time;
    ASSERT_LE(s.diameter_joint, s.diameter_upper + 1e-12) << "t = " << s.time;
    for (int i = 0; i < 6; ++i) {
      ASSERT_GT(s.joints[i], robot.parameters().backbone_lower) << "t = " << s.time;
      ASSERT_LT(s.joints[i], robot.parameters().backbone_upper) << "t = " << s.time;
    }
  }
}

TEST(VariableDiameterCircle, HookBranchGrowsShrinksNearInterferenceAndGrowsAgainS21) {
  const VariableDiameterRobotParameters params;  // E = 74 GPa
  const VariableDiameterRobot robot(params);
  const CircleOutcome out = run_circle(params, CircleBranch::kHook, "hook, E = 74 GPa");
  ASSERT_EQ(out.fixed.failed_steps + out.variable.failed_steps, 0u);
  ASSERT_EQ(out.fixed.samples.size(), out.variable.samples.size());
  const std::size_t n = out.variable.samples.size();

  // The tip follows the circle in both runs (after the first 0.1 s of closing the initial error).
  for (std::size_t i = 100; i < n; ++i) {
    ASSERT_LT(out.variable.samples[i].tracking_error, 0.01);
    ASSERT_LT(out.fixed.samples[i].tracking_error, 0.01);
  }

  // Forces: never higher with the diameter free, and lower overall, by the dissertation's order of magnitude.
  EXPECT_GE(out.forces.min_reduction, -1e-6);
  EXPECT_LT(out.forces.rms_variable, out.forces.rms_fixed);
  EXPECT_GT(out.forces.rms_reduction, 48.3 - 2 * 17.6);
  EXPECT_LT(out.forces.rms_reduction, 48.3 + 2 * 17.6);

  // Limits: a and the backbones stay inside theirs at every step. Where no diameter avoids disk
  // interference (the middle segment bends past ~3.13 rad at the bottom of the circle), both runs hold
  // a = a_min; those steps are the same in both, so the task causes them, not the redundancy resolution.
  expect_limits_respected(robot, out.fixed);
  expect_limits_respected(robot, out.variable);
  std::size_t unavoidable = 0, extra_clamps = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const bool fixed_hit = out.fixed.samples[i].status == VariableDiameterStatus::kInterferenceUnavoidable;
    const bool variable_hit =
        out.variable.samples[i].status == VariableDiameterStatus::kInterferenceUnavoidable;
    ASSERT_EQ(fixed_hit, variable_hit) << "t = " << out.variable.samples[i].time;
    unavoidable += variable_hit ? 1 : 0;
    extra_clamps += out.variable.samples[i].status == VariableDiameterStatus::kDiameterClamped ? 1 : 0;
  }
  std::printf(
      "[hook] steps with interference at any diameter: %zu; steps where a met its moving limit: %zu\n",
      unavoidable, extra_clamps);
  EXPECT_GT(unavoidable, 0u);
  EXPECT_LT(unavoidable, n / 4);
  EXPECT_LT(extra_clamps, n / 100) << "the limit term of H keeps a off its limit but for a few steps";

  // The diameter history: grows in the first part, falls with the interference limit to a_min in the
  // middle, grows again on the way back to the start (Fig. 2.12).
  const double a_min = robot.linkage().inner_radius_min();
  std::size_t peak = 0;
  for (std::size_t i = 0; i < n / 3; ++i) {
    if (out.variable.samples[i].diameter_joint > out.variable.samples[peak].diameter_joint) peak = i;
  }
  const CircleSample& first_peak = out.variable.samples[peak];
  const CircleSample& middle = out.variable.samples[n / 2];
  const CircleSample& end = out.variable.samples[n - 1];
  std::printf("[hook] a: start %.2f mm, peak %.2f mm at %.2f s, middle %.2f mm, end %.2f mm\n",
              out.variable.samples[0].diameter_joint, first_peak.diameter_joint, first_peak.time,
              middle.diameter_joint, end.diameter_joint);
  EXPECT_GT(first_peak.diameter_joint, a_min + 10.0);
  EXPECT_NEAR(middle.diameter_joint, a_min, 1e-9);
  EXPECT_GT(end.diameter_joint, a_min + 20.0);
  // Between the peak and the middle a falls, and it falls because the interference limit comes down:
  // the limit is the interference one and a stays within the H-term's margin of it.
  // (Compared 0.1 s apart: near its balance point the capped null-space step jitters by < 0.01 mm.)
  for (std::size_t i = peak + 100; i < n / 2; i += 100) {
    const CircleSample& s = out.variable.samples[i];
    ASSERT_LE(s.diameter_joint, out.variable.samples[i - 100].diameter_joint + 0.02) << "t = " << s.time;
    ASSERT_TRUE(std::isfinite(s.interference)) << "t = " << s.time;
    ASSERT_LT(s.diameter_upper - s.diameter_joint, 12.0) << "t = " << s.time;
  }

  // The data for the console's plot of diameter and forces (and for a person to look at).
  EXPECT_TRUE(write_circle_csv("variable_diameter_circle.csv", out.fixed, out.variable));
  EXPECT_TRUE(write_circle_svg("variable_diameter_circle.svg", out.fixed, out.variable));
}

TEST(VariableDiameterCircle, PrintedModulusGivesTheSameStoryS21) {
  VariableDiameterRobotParameters params;
  params.youngs_modulus = 74.0;  // the dissertation's "74 MPa" as printed
  const CircleOutcome out = run_circle(params, CircleBranch::kHook, "hook, E = 74 MPa");
  EXPECT_GE(out.forces.min_reduction, -1e-6);
  EXPECT_GT(out.forces.rms_reduction, 48.3 - 2 * 17.6);
  EXPECT_LT(out.forces.rms_reduction, 48.3 + 2 * 17.6);
}

// Why the objective is evaluated in SI: read in mm, the gradient term is too weak to move a at all
// while the segments curl, and the first growth of Fig. 2.12 is missing.
TEST(VariableDiameterCircle, ObjectiveInMillimetresMissesTheFirstGrowth) {
  VariableDiameterRobotParameters params;
  params.redundancy.objective_length_scale = 1.0;
  const VariableDiameterRobot robot(params);
  const CircleOutcome out = run_circle(params, CircleBranch::kHook, "hook, objective in mm");
  const std::size_t n = out.variable.samples.size();
  double first_third_max = 0.0;
  for (std::size_t i = 0; i < n / 3; ++i) {
    first_third_max = std::max(first_third_max, out.variable.samples[i].diameter_joint);
  }
  std::printf("[hook, objective in mm] a: largest in the first third %.2f mm, end %.2f mm\n", first_third_max,
              out.variable.samples[n - 1].diameter_joint);
  EXPECT_LT(first_third_max, robot.linkage().inner_radius_min() + 0.5);
  EXPECT_GE(out.forces.min_reduction, -1e-6);
}

TEST(VariableDiameterCircle, SShapeBranchNeverMeetsInterference) {
  const VariableDiameterRobotParameters params;
  const VariableDiameterRobot robot(params);
  const CircleOutcome out = run_circle(params, CircleBranch::kSShape, "S shape, E = 74 GPa");
  expect_limits_respected(robot, out.variable);
  EXPECT_EQ(out.variable.clamped_steps, 0u);
  for (const CircleSample& s : out.variable.samples) ASSERT_TRUE(std::isinf(s.interference));
  EXPECT_GE(out.forces.min_reduction, -1e-6);
  EXPECT_GT(out.forces.rms_reduction, 48.3) << "unhindered by interference, the diameter does more";
}

}  // namespace
}  // namespace tendril::teleop
