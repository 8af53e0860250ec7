// Configuration-space map and controller of the SRMC (Abah 2022, §4.7.2, eqs. 4.13–4.15, 4.21–4.23).
#include "tendril/teleop/catheter_configuration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <stdexcept>

#include "allocation_counter.hpp"

namespace tendril::teleop {
namespace {

using Vector4 = CatheterConfigurationMap::Vector4;

constexpr double kGain = 1.4;                    // placeholder curvature gain k (rad/mm), Abah 2022, §4.5.2
const double kCoupling = 0.6 * std::cos(-0.44);  // c = r1·cos δ2 with r1 = 0.6 mm

ModalCatheterParameters linear_model() { return constant_curvature_modal_parameters(CatheterParameters{}); }

// m = 3: bend θ̃*(q) = k·q + κ·q² at the tip, so J_ψq depends on q and the inverse is a real root
// find. Monotonic for q > −k/(2κ).
ModalCatheterParameters quadratic_model() {
  ModalCatheterParameters p = linear_model();
  auto add_square = [](ModalSegmentShape& shape, double kappa) {
    Eigen::MatrixXd a = Eigen::MatrixXd::Zero(4, 3);
    a.leftCols(2) = shape.shape_matrix;
    a(1, 2) = -kappa / shape.length;
    shape.shape_matrix = a;
  };
  add_square(p.proximal, 0.2);
  add_square(p.distal, 0.3);
  return p;
}

// Distal bend κ·q² only: no slope at q4 = 0, so (4.21) is singular there.
ModalCatheterParameters singular_distal_model() {
  ModalCatheterParameters p = linear_model();
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(4, 3);
  a(0, 0) = std::numbers::pi / 2.0;
  a(1, 2) = -0.5 / p.distal.length;
  p.distal.shape_matrix = a;
  return p;
}

ConfigurationRateParameters rates(bool coupling) {
  // Defaults are the dissertation's values: a1 0.063, b1 −0.049, a2 0.17, b2 0.019, r1 0.6, δ2 −0.44.
  ConfigurationRateParameters r;
  r.coupling_enabled = coupling;
  return r;
}

// ∂ψ/∂q by central differences of configuration().
Eigen::Matrix4d numeric_jacobian(const CatheterConfigurationMap& map, const Vector4& q) {
  Eigen::Matrix4d j;
  constexpr double h = 1e-6;
  for (int k = 0; k < 4; ++k) {
    Vector4 dq = Vector4::Zero();
    dq[k] = h;
    j.col(k) = (map.configuration(q + dq) - map.configuration(q - dq)) / (2.0 * h);
  }
  return j;
}

// ---------------------------------------------------------------------------------------------
// CatheterConfigurationMap

TEST(CatheterConfigurationMap, LossLinesGiveTheDissertationsAssembledAngles) {
  // θ*_L1 = 1 rad → θ_L1 = 0.014; θ*_L2 = 1 rad → θ_L2 = 0.189. With k = 1.4 rad/mm the nominal
  // bend is 1 rad at q = 1/1.4 mm.
  const CatheterConfigurationMap uncoupled(linear_model(), rates(false));
  const double q_one_rad = 1.0 / kGain;
  const Vector4 psi = uncoupled.configuration(Vector4(12.0, 0.3, q_one_rad, q_one_rad));
  EXPECT_DOUBLE_EQ(psi[0], 12.0);
  EXPECT_DOUBLE_EQ(psi[1], 0.3);
  EXPECT_NEAR(psi[2], 0.014, 1e-12);
  EXPECT_NEAR(psi[3], 0.189, 1e-12);

  // With coupling the distal carriage must sit c·θ_L1 lower for the tube to see the same actuation.
  const CatheterConfigurationMap coupled(linear_model(), rates(true));
  EXPECT_NEAR(coupled.coupling(), kCoupling, 1e-15);
  const Vector4 psi_c = coupled.configuration(Vector4(0.0, 0.0, q_one_rad, q_one_rad - kCoupling * 0.014));
  EXPECT_NEAR(psi_c[2], 0.014, 1e-12);
  EXPECT_NEAR(psi_c[3], 0.189, 1e-12);

  // And the inverse recovers those actuations from the dissertation's assembled angles.
  Vector4 q;
  ASSERT_TRUE(uncoupled.joints(Vector4(12.0, 0.3, 0.014, 0.189), q));
  EXPECT_NEAR(q[2], q_one_rad, 1e-12);
  EXPECT_NEAR(q[3], q_one_rad, 1e-12);
  ASSERT_TRUE(coupled.joints(Vector4(12.0, 0.3, 0.014, 0.189), q));
  EXPECT_NEAR(q[2], q_one_rad, 1e-12);
  EXPECT_NEAR(q[3], q_one_rad - kCoupling * 0.014, 1e-12);
}

TEST(CatheterConfigurationMap, BendGrowsWithPositiveActuationAndIsZeroStraightBeforeLoss) {
  // θ_Li is a bend (0 = straight nominal): q = 0 gives just the loss offsets, more q bends more.
  const CatheterConfigurationMap map(linear_model(), rates(false));
  const Vector4 straight = map.configuration(Vector4::Zero());
  EXPECT_NEAR(straight[2], -0.049, 1e-15);
  EXPECT_NEAR(straight[3], 0.019, 1e-15);
  const Vector4 bent = map.configuration(Vector4(0.0, 0.0, 0.5, 0.5));
  EXPECT_NEAR(bent[2] - straight[2], 0.063 * kGain * 0.5, 1e-12);
  EXPECT_NEAR(bent[3] - straight[3], 0.17 * kGain * 0.5, 1e-12);
}

TEST(CatheterConfigurationMap, ProximalBendShiftsDistalBendOnlyWithCoupling) {
  const CatheterConfigurationMap coupled(linear_model(), rates(true));
  const CatheterConfigurationMap uncoupled(linear_model(), rates(false));
  const Vector4 q0(5.0, 0.1, 0.2, 0.3);
  const Vector4 q1(5.0, 0.1, 0.9, 0.3);  // only the proximal carriage moves
  const Vector4 a = coupled.configuration(q0), b = coupled.configuration(q1);
  const double d_theta1 = b[2] - a[2];
  EXPECT_NEAR(d_theta1, 0.063 * kGain * 0.7, 1e-12);
  // (4.15): the distal tube sees Δq4_eff = c·Δθ_L1.
  EXPECT_NEAR(b[3] - a[3], 0.17 * kGain * kCoupling * d_theta1, 1e-12);
  EXPECT_GT(b[3] - a[3], 0.0);
  EXPECT_DOUBLE_EQ(uncoupled.configuration(q1)[3], uncoupled.configuration(q0)[3]);
}

TEST(CatheterConfigurationMap, InverseRoundTripsLinearAndQuadraticModels) {
  for (const bool coupling : {true, false}) {
    for (const auto& model : {linear_model(), quadratic_model()}) {
      const CatheterConfigurationMap map(model, rates(coupling));
      for (const Vector4& q_true : {Vector4(0.0, 0.0, 0.0, 0.0), Vector4(30.0, -1.2, 1.7, -0.8),
                                    Vector4(4.0, 3.0, -0.6, 2.5), Vector4(-2.0, 0.5, 6.0, -1.1)}) {
        const Vector4 psi = map.configuration(q_true);
        Vector4 q;
        ASSERT_TRUE(map.joints(psi, q)) << psi.transpose();
        EXPECT_LT((q - q_true).cwiseAbs().maxCoeff(), 1e-10) << q.transpose() << " vs " << q_true.transpose();
        EXPECT_LT((map.configuration(q) - psi).cwiseAbs().maxCoeff(), 1e-12);
      }
      // ψ → q → ψ for a configuration picked directly.
      const Vector4 psi(10.0, 0.4, 0.05, 0.3);
      Vector4 q;
      ASSERT_TRUE(map.joints(psi, q));
      EXPECT_LT((map.configuration(q) - psi).cwiseAbs().maxCoeff(), 1e-12);
    }
  }
}

TEST(CatheterConfigurationMap, InverseRejectsNonFiniteAndUnreachableBends) {
  const CatheterConfigurationMap map(linear_model(), rates(true));
  const Vector4 untouched(1.0, 2.0, 3.0, 4.0);
  Vector4 q = untouched;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(map.joints(Vector4(0.0, nan, 0.1, 0.1), q));
  EXPECT_FALSE(map.joints(Vector4(0.0, 0.0, std::numeric_limits<double>::infinity(), 0.1), q));
  // θ_L1 = 10 rad needs θ̃* = 159 rad, q3 ≈ 114 mm: beyond any stroke.
  EXPECT_FALSE(map.joints(Vector4(0.0, 0.0, 10.0, 0.1), q));
  EXPECT_EQ(q, untouched);

  // θ̃* = 1.4q + 0.3q² never goes below −1.63 rad: a distal bend below b2 + 0.17·(−1.63) has no root.
  const CatheterConfigurationMap quadratic(quadratic_model(), rates(false));
  EXPECT_FALSE(quadratic.joints(Vector4(0.0, 0.0, 0.0, 0.019 + 0.17 * -1.7), q));
  EXPECT_TRUE(quadratic.joints(Vector4(0.0, 0.0, 0.0, 0.019 + 0.17 * -1.6), q));
  // Two roots there; the one nearer the straight pose (q > −k/2κ = −2.33 mm) is taken.
  EXPECT_GT(q[3], -14.0 / 6.0);
}

TEST(CatheterConfigurationMap, JointRatesHaveTheDissertationsSignsAndCouplingTerm) {
  const CatheterConfigurationMap coupled(linear_model(), rates(true));
  const Vector4 q(10.0, 0.2, 0.4, -0.3);
  Vector4 qd;
  // Bending the proximal segment more needs more q3 (∂θ̃*/∂q = −∂θ/∂q = +k > 0) and the distal
  // carriage backs off by c·θ̇_L1 to cancel the coupling: q̇4 = −c·θ̇_L1.
  ASSERT_TRUE(coupled.joint_rates(q, Vector4(0.0, 0.0, 1.0, 0.0), qd));
  EXPECT_NEAR(qd[2], 1.0 / (0.063 * kGain), 1e-12);
  EXPECT_NEAR(qd[3], -kCoupling, 1e-12);
  EXPECT_DOUBLE_EQ(qd[0], 0.0);
  EXPECT_DOUBLE_EQ(qd[1], 0.0);
  ASSERT_TRUE(coupled.joint_rates(q, Vector4(2.0, -0.5, 0.0, 1.0), qd));
  EXPECT_DOUBLE_EQ(qd[0], 2.0);
  EXPECT_DOUBLE_EQ(qd[1], -0.5);
  EXPECT_DOUBLE_EQ(qd[2], 0.0);
  EXPECT_NEAR(qd[3], 1.0 / (0.17 * kGain), 1e-12);
  // Both at once superpose: q̇4 = θ̇_L2/(a2·k) − c·θ̇_L1.
  ASSERT_TRUE(coupled.joint_rates(q, Vector4(0.0, 0.0, 0.3, 0.2), qd));
  EXPECT_NEAR(qd[3], 0.2 / (0.17 * kGain) - kCoupling * 0.3, 1e-12);

  const CatheterConfigurationMap uncoupled(linear_model(), rates(false));
  ASSERT_TRUE(uncoupled.joint_rates(q, Vector4(0.0, 0.0, 1.0, 0.0), qd));
  EXPECT_NEAR(qd[2], 1.0 / (0.063 * kGain), 1e-12);
  EXPECT_DOUBLE_EQ(qd[3], 0.0);
}

TEST(CatheterConfigurationMap, JointRatesMatchFiniteDifferencesOfForwardAndInverse) {
  for (const bool coupling : {true, false}) {
    const CatheterConfigurationMap map(quadratic_model(), rates(coupling));
    for (const Vector4& q : {Vector4(3.0, 0.1, 0.5, 1.2), Vector4(20.0, -0.7, -0.9, 0.4)}) {
      const Vector4 psi_rate(0.7, -0.2, 0.05, -0.08);
      Vector4 qd;
      ASSERT_TRUE(map.joint_rates(q, psi_rate, qd));
      // Forward: J·q̇ must reproduce ψ̇.
      const Vector4 reproduced = numeric_jacobian(map, q) * qd;
      EXPECT_LT((reproduced - psi_rate).cwiseAbs().maxCoeff(), 1e-7) << reproduced.transpose();
      // Inverse: q̇ ≈ (joints(ψ + h·ψ̇) − joints(ψ − h·ψ̇)) / 2h.
      const Vector4 psi = map.configuration(q);
      constexpr double h = 1e-5;
      Vector4 q_plus, q_minus;
      ASSERT_TRUE(map.joints(psi + h * psi_rate, q_plus));
      ASSERT_TRUE(map.joints(psi - h * psi_rate, q_minus));
      const Vector4 numeric = (q_plus - q_minus) / (2.0 * h);
      EXPECT_LT((numeric - qd).cwiseAbs().maxCoeff(), 1e-6)
          << numeric.transpose() << " vs " << qd.transpose();
    }
  }
}

TEST(CatheterConfigurationMap, IntegratedJointRatesFollowAConfigurationPath) {
  // q̇ = joint_rates(q, ψ̇(t)) integrated (RK4) must keep configuration(q(t)) on ψ(t), coupling on.
  const CatheterConfigurationMap map(quadratic_model(), rates(true));
  const Vector4 q0(2.0, 0.0, 0.3, -0.2);
  const Vector4 psi0 = map.configuration(q0);
  const Vector4 amplitude(5.0, 0.8, 0.06, 0.25);
  auto psi_at = [&](double t) -> Vector4 {
    return psi0 + Vector4(amplitude[0] * t, amplitude[1] * std::sin(t), amplitude[2] * std::sin(2.0 * t),
                          amplitude[3] * (1.0 - std::cos(1.5 * t)));
  };
  auto psi_rate_at = [&](double t) -> Vector4 {
    return Vector4(amplitude[0], amplitude[1] * std::cos(t), 2.0 * amplitude[2] * std::cos(2.0 * t),
                   1.5 * amplitude[3] * std::sin(1.5 * t));
  };
  auto f = [&](double t, const Vector4& q) {
    Vector4 qd;
    EXPECT_TRUE(map.joint_rates(q, psi_rate_at(t), qd));
    return qd;
  };
  Vector4 q = q0;
  constexpr double dt = 1e-3;
  double worst = 0.0;
  for (int i = 0; i < 3000; ++i) {
    const double t = i * dt;
    const Vector4 k1 = f(t, q), k2 = f(t + dt / 2, q + dt / 2 * k1), k3 = f(t + dt / 2, q + dt / 2 * k2),
                  k4 = f(t + dt, q + dt * k3);
    q += dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    worst = std::max(worst, (map.configuration(q) - psi_at(t + dt)).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst, 1e-9);
  // The proximal bend really moved, so the coupling term was exercised.
  EXPECT_GT(std::abs(q[2] - q0[2]), 0.1);
}

TEST(CatheterConfigurationMap, SingularOrNonFiniteRatesHold) {
  const CatheterConfigurationMap map(singular_distal_model(), rates(false));
  Vector4 qd(9.0, 9.0, 9.0, 9.0);
  EXPECT_FALSE(map.joint_rates(Vector4(0.0, 0.0, 0.2, 0.0), Vector4(0.0, 0.0, 0.0, 0.1), qd));
  EXPECT_EQ(qd, Vector4::Zero());
  qd.setConstant(9.0);
  EXPECT_TRUE(map.joint_rates(Vector4(0.0, 0.0, 0.2, 0.5), Vector4(0.0, 0.0, 0.0, 0.1), qd));
  EXPECT_NEAR(qd[3], 0.1 / (0.17 * 2.0 * 0.5 * 0.5), 1e-12);

  const CatheterConfigurationMap linear(linear_model(), rates(true));
  qd.setConstant(9.0);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(linear.joint_rates(Vector4(0.0, nan, 0.0, 0.0), Vector4(0.0, 0.0, 0.1, 0.0), qd));
  EXPECT_EQ(qd, Vector4::Zero());
  EXPECT_FALSE(linear.joint_rates(Vector4::Zero(), Vector4(0.0, 0.0, nan, 0.0), qd));
}

TEST(CatheterConfigurationMap, RejectsBadParameters) {
  ConfigurationRateParameters bad = rates(true);
  bad.proximal_loss.slope = 0.0;
  EXPECT_THROW(CatheterConfigurationMap(linear_model(), bad), std::invalid_argument);
  ModalCatheterParameters bad_model = linear_model();
  bad_model.distal.length = 0.0;
  EXPECT_THROW(CatheterConfigurationMap(bad_model, rates(true)), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------
// ConfigurationSpaceController

const Vector4 kMaxVelocity(2.0, 0.5, 0.1, 0.2);      // mm/s, rad/s, rad/s, rad/s
const Vector4 kMaxAcceleration(5.0, 2.0, 0.5, 1.0);  // per s

// Runs the controller at 1 kHz from t0 for `seconds`; returns the largest per-tick change of q_des.
struct RunStats {
  Vector4 max_rate_change = Vector4::Zero();  // max |q̇_k − q̇_{k−1}| (the tick before included)
  double max_tracking_error = 0.0;            // max |ψ(q_des(t)) − ψ_des(t)| over the bends
};

RunStats run(ConfigurationSpaceController& c, double& t, double seconds, Vector4& q, Vector4& qd) {
  constexpr double dt = 1e-3;
  RunStats stats;
  const int ticks = static_cast<int>(std::lround(seconds / dt));
  for (int i = 0; i < ticks; ++i) {
    t += dt;
    const Vector4 previous = qd;
    EXPECT_TRUE(c.step(t, dt, q, qd)) << "t = " << t;
    stats.max_rate_change = stats.max_rate_change.cwiseMax((qd - previous).cwiseAbs());
    const Vector4 error = c.map().configuration(q) - c.desired_configuration(t);
    stats.max_tracking_error = std::max(stats.max_tracking_error, error.cwiseAbs().maxCoeff());
  }
  return stats;
}

TEST(ConfigurationSpaceController, ReachesABendGoalSmoothly) {
  for (const auto& model : {linear_model(), quadratic_model()}) {
    const CatheterConfigurationMap map(model, rates(true));
    ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
    Vector4 q(5.0, 0.2, 0.3, -0.4), qd = Vector4::Zero();
    const Vector4 q_start = q;
    double t = 2.0;
    c.reset(t, q);
    EXPECT_LT((c.goal() - map.configuration(q)).cwiseAbs().maxCoeff(), 1e-15);

    // Holding after reset: no motion at all.
    run(c, t, 0.05, q, qd);
    EXPECT_LT((q - q_start).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT(qd.cwiseAbs().maxCoeff(), 1e-9);

    const Vector4 goal(8.0, -0.1, 0.05, 0.25);
    ASSERT_TRUE(c.retarget(t, goal));
    EXPECT_EQ(c.goal(), goal);
    EXPECT_FALSE(c.done(t));
    const double duration = c.duration();
    EXPECT_GT(duration, 0.5);
    const RunStats stats = run(c, t, duration + 0.2, q, qd);
    EXPECT_TRUE(c.done(t));

    const Vector4 reached = map.configuration(q);
    EXPECT_NEAR(reached[2], goal[2], 1e-3);
    EXPECT_NEAR(reached[3], goal[3], 1e-3);
    EXPECT_LT((reached - goal).cwiseAbs().maxCoeff(), 1e-6);  // and in fact much closer
    Vector4 q_goal;
    ASSERT_TRUE(map.joints(goal, q_goal));
    EXPECT_LT((q - q_goal).cwiseAbs().maxCoeff(), 1e-5);
    EXPECT_LT(qd.cwiseAbs().maxCoeff(), 1e-6);  // only the decaying drift-correction residue
    // ψ(q_des) tracks the quintic all along, and q̇ changes by at most an acceleration-sized step
    // per tick (no jump when the motion starts).
    EXPECT_LT(stats.max_tracking_error, 1e-6);
    EXPECT_LT(stats.max_rate_change[0], 2.0 * kMaxAcceleration[0] * 1e-3);
    EXPECT_LT(stats.max_rate_change[2], 2.0 * kMaxAcceleration[2] * 1e-3 / (0.063 * kGain));
  }
}

TEST(ConfigurationSpaceController, RetargetMidMotionKeepsJointsAndRatesContinuous) {
  const CatheterConfigurationMap map(linear_model(), rates(true));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(0.0, 0.0, 0.0, 0.0), qd = Vector4::Zero();
  double t = 0.0;
  c.reset(t, q);
  ASSERT_TRUE(c.retarget(t, Vector4(10.0, 0.5, 0.06, 0.3)));
  run(c, t, 0.4 * c.duration(), q, qd);
  EXPECT_GT(qd.cwiseAbs().maxCoeff(), 0.1);  // really moving at the switch

  const Vector4 q_before = q, qd_before = qd;
  ASSERT_TRUE(c.retarget(t, Vector4(-3.0, -0.4, -0.02, -0.1)));
  const double dt = 1e-3;
  t += dt;
  ASSERT_TRUE(c.step(t, dt, q, qd));
  // Per-tick change bounded by the joint speed (no jump) and the rate by one acceleration step.
  const Eigen::Array4d joint_accel_bound(
      kMaxAcceleration[0], kMaxAcceleration[1], kMaxAcceleration[2] / (0.063 * kGain),
      kMaxAcceleration[3] / (0.17 * kGain) + kCoupling * kMaxAcceleration[2]);
  EXPECT_TRUE(((qd - qd_before).array().abs() <= 1.5 * joint_accel_bound * dt).all())
      << (qd - qd_before).transpose();
  EXPECT_LT((q - q_before - qd_before * dt).cwiseAbs().maxCoeff(), 1e-4);

  const RunStats stats = run(c, t, c.duration() + 0.2, q, qd);
  EXPECT_TRUE(((stats.max_rate_change.array()) <= 1.5 * joint_accel_bound * dt).all())
      << stats.max_rate_change.transpose();
  EXPECT_LT((map.configuration(q) - Vector4(-3.0, -0.4, -0.02, -0.1)).cwiseAbs().maxCoeff(), 1e-6);

  // A reset while moving holds where q_des is: the next step does not move it.
  Vector4 q_held = q + Vector4(0.0, 0.0, 0.3, 0.0);  // e.g. after the caller clamped a joint
  c.reset(t, q_held);
  const Vector4 q_reset = q_held;
  t += dt;
  ASSERT_TRUE(c.step(t, dt, q_held, qd));
  EXPECT_LT((q_held - q_reset).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(ConfigurationSpaceController, CompensatesCouplingSoOnlyTheProximalBendMoves) {
  const CatheterConfigurationMap map(linear_model(), rates(true));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(0.0, 0.0, 0.2, 0.1), qd = Vector4::Zero();
  double t = 0.0;
  c.reset(t, q);
  const Vector4 psi0 = map.configuration(q);
  const Vector4 goal = psi0 + Vector4(0.0, 0.0, 0.05, 0.0);
  ASSERT_TRUE(c.retarget(t, goal));
  constexpr double dt = 1e-3;
  double worst_distal = 0.0;
  for (int i = 0; i < static_cast<int>((c.duration() + 0.1) / dt); ++i) {
    t += dt;
    ASSERT_TRUE(c.step(t, dt, q, qd));
    worst_distal = std::max(worst_distal, std::abs(map.configuration(q)[3] - psi0[3]));
    // q̇4 = −c·θ̇_L1 while θ_L2 is held.
    EXPECT_NEAR(qd[3], -kCoupling * qd[2] * 0.063 * kGain, 1e-9);
  }
  EXPECT_LT(worst_distal, 1e-9);
  EXPECT_NEAR(q[2] - 0.2, 0.05 / (0.063 * kGain), 1e-6);
  EXPECT_NEAR(q[3] - 0.1, -kCoupling * 0.05, 1e-6);

  // Without coupling the distal carriage stays put.
  const CatheterConfigurationMap uncoupled_map(linear_model(), rates(false));
  ConfigurationSpaceController u(uncoupled_map, kMaxVelocity, kMaxAcceleration);
  q = Vector4(0.0, 0.0, 0.2, 0.1);
  t = 0.0;
  u.reset(t, q);
  ASSERT_TRUE(u.retarget(t, uncoupled_map.configuration(q) + Vector4(0.0, 0.0, 0.05, 0.0)));
  run(u, t, u.duration() + 0.1, q, qd);
  EXPECT_NEAR(q[2] - 0.2, 0.05 / (0.063 * kGain), 1e-6);
  EXPECT_NEAR(q[3], 0.1, 1e-12);
}

TEST(ConfigurationSpaceController, DriftCorrectionPullsBackADisturbedCommandSmoothly) {
  const CatheterConfigurationMap map(linear_model(), rates(true));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(0.0, 0.0, 0.2, 0.1), qd = Vector4::Zero();
  double t = 0.0;
  c.reset(t, q);
  const Vector4 held = q;
  q[2] += 0.01;  // the caller clamped or nudged q_des
  constexpr double dt = 1e-3;
  t += dt;
  ASSERT_TRUE(c.step(t, dt, q, qd));
  // One tick removes kDriftCorrectionRate·dt = 2 % of the error, not all of it.
  EXPECT_NEAR(q[2] - held[2], 0.01 * (1.0 - ConfigurationSpaceController::kDriftCorrectionRate * dt), 1e-12);
  run(c, t, 0.5, q, qd);  // 10 time constants
  EXPECT_LT((q - held).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(ConfigurationSpaceController, RejectsBadInputsAndHolds) {
  EXPECT_THROW(ConfigurationSpaceController(CatheterConfigurationMap(linear_model(), rates(true)),
                                            Vector4(1.0, 1.0, 0.0, 1.0), kMaxAcceleration),
               std::invalid_argument);
  EXPECT_THROW(
      ConfigurationSpaceController(CatheterConfigurationMap(linear_model(), rates(true)), kMaxVelocity,
                                   Vector4(1.0, std::numeric_limits<double>::infinity(), 1.0, 1.0)),
      std::invalid_argument);

  const CatheterConfigurationMap map(linear_model(), rates(true));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(1.0, 0.0, 0.1, 0.1), qd(5.0, 5.0, 5.0, 5.0);
  // Not armed before reset.
  EXPECT_FALSE(c.step(0.001, 0.001, q, qd));
  EXPECT_EQ(qd, Vector4::Zero());
  EXPECT_FALSE(c.retarget(0.0, Vector4(0.0, 0.0, 0.0, 0.0)));
  EXPECT_FALSE(c.done(10.0));

  c.reset(0.0, q);
  const Vector4 goal_before = c.goal();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(c.retarget(0.0, Vector4(nan, 0.0, 0.0, 0.0)));
  EXPECT_FALSE(c.retarget(nan, Vector4(0.0, 0.0, 0.0, 0.0)));
  EXPECT_FALSE(c.retarget(0.0, Vector4(0.0, 0.0, 10.0, 0.0)));  // no q3 reaches a 10 rad bend
  EXPECT_EQ(c.goal(), goal_before);

  const Vector4 q_before = q;
  qd.setConstant(5.0);
  EXPECT_FALSE(c.step(0.001, 0.0, q, qd));
  EXPECT_FALSE(c.step(0.001, -1e-3, q, qd));
  EXPECT_FALSE(c.step(0.001, nan, q, qd));
  EXPECT_EQ(q, q_before);
  EXPECT_EQ(qd, Vector4::Zero());
  Vector4 bad_q(nan, 0.0, 0.0, 0.0);
  EXPECT_FALSE(c.step(0.001, 0.001, bad_q, qd));

  // A non-finite reset disarms.
  c.reset(0.0, Vector4(0.0, nan, 0.0, 0.0));
  EXPECT_FALSE(c.step(0.001, 0.001, q, qd));
}

TEST(ConfigurationSpaceController, SingularMapHoldsWithZeroRate) {
  const CatheterConfigurationMap map(singular_distal_model(), rates(false));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(0.0, 0.0, 0.2, 0.0), qd(1.0, 1.0, 1.0, 1.0);  // distal at its zero-slope point
  c.reset(0.0, q);
  ASSERT_TRUE(c.retarget(0.0, map.configuration(q) + Vector4(1.0, 0.0, 0.0, 0.05)));
  const Vector4 q_before = q;
  EXPECT_FALSE(c.step(0.01, 0.001, q, qd));
  EXPECT_EQ(q, q_before);
  EXPECT_EQ(qd, Vector4::Zero());
}

TEST(ConfigurationSpaceController, TickPathDoesNotAllocate) {
  const CatheterConfigurationMap map(quadratic_model(), rates(true));
  ConfigurationSpaceController c(map, kMaxVelocity, kMaxAcceleration);
  Vector4 q(5.0, 0.0, 0.3, 0.2), qd = Vector4::Zero(), q_goal;
  double sink = 0.0;

  const long before = tendril::testing::allocation_count.load();
  c.reset(0.0, q);
  EXPECT_TRUE(c.retarget(0.0, Vector4(9.0, 0.4, 0.05, 0.3)));
  for (int i = 1; i <= 2000; ++i) {
    const double t = i * 1e-3;
    if (i == 700) c.retarget(t, Vector4(2.0, -0.3, 0.0, 0.1));
    c.step(t, 1e-3, q, qd);
    sink += c.done(t) ? 1.0 : 0.0;
    sink += c.goal()[2] + c.desired_configuration(t)[3];
    sink += map.joints(map.configuration(q), q_goal) ? q_goal[3] : 0.0;
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  // The counter really sees allocations, so the check above can fail.
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
