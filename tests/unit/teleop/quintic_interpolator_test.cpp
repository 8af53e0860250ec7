#include "tendril/teleop/quintic_interpolator.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

namespace tendril::teleop {
namespace {

struct State {
  std::vector<double> q, qd, qdd;
  explicit State(std::size_t n) : q(n), qd(n), qdd(n) {}
};

State sample_at(const QuinticInterpolator& interp, double t) {
  State s(interp.joints());
  interp.sample(t, s.q, s.qd, s.qdd);
  return s;
}

TEST(QuinticInterpolator, RestToRestMatchesTheDissertationsFormula) {
  QuinticInterpolator interp(3);
  const std::vector<double> q0{0.5, -1.0, 2.0};
  const std::vector<double> qf{3.0, 1.5, 2.5};
  interp.reset(q0, 1.0);
  ASSERT_EQ(interp.retarget(1.0, qf, 2.0, 10.0), RetargetStatus::kOk);
  const double T = interp.duration();
  ASSERT_GT(T, 0.0);
  for (int i = 0; i <= 100; ++i) {
    const double tau = i / 100.0;
    const State s = sample_at(interp, 1.0 + tau * T);
    const double shape = 10 * std::pow(tau, 3) - 15 * std::pow(tau, 4) + 6 * std::pow(tau, 5);
    for (std::size_t j = 0; j < 3; ++j) EXPECT_NEAR(s.q[j], q0[j] + (qf[j] - q0[j]) * shape, 1e-12) << tau;
  }
  const State end = sample_at(interp, 1.0 + T + 5.0);
  for (std::size_t j = 0; j < 3; ++j) {
    EXPECT_EQ(end.q[j], qf[j]);
    EXPECT_EQ(end.qd[j], 0.0);
    EXPECT_EQ(end.qdd[j], 0.0);
  }
  EXPECT_TRUE(interp.done(1.0 + T));
  EXPECT_FALSE(interp.done(1.0 + 0.5 * T));
}

TEST(QuinticInterpolator, RestToRestDurationIsTheShortestWithinLimits) {
  // Rest-to-rest peaks: |v| = 15/8·h/T, |a| = (10/√3)·h/T². The slowest joint (largest h) sets T.
  QuinticInterpolator interp(2);
  interp.reset(std::vector<double>{0.0, 0.0});
  const double h = 2.0, vmax = 1.0, amax = 100.0;
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{0.5, -h}, vmax, amax), RetargetStatus::kOk);
  const double expected = std::max(15.0 / 8.0 * h / vmax, std::sqrt(10.0 / std::sqrt(3.0) * h / amax));
  EXPECT_NEAR(interp.duration(), expected, 1e-5 * expected);

  // Acceleration-bound case.
  interp.reset(std::vector<double>{0.0, 0.0});
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{h, 0.0}, 100.0, 0.5), RetargetStatus::kOk);
  const double expected_a = std::sqrt(10.0 / std::sqrt(3.0) * h / 0.5);
  EXPECT_NEAR(interp.duration(), expected_a, 1e-5 * expected_a);
}

void expect_limits_respected(const QuinticInterpolator& interp, const std::vector<double>& vmax,
                             const std::vector<double>& amax) {
  const double t0 = interp.start_time(), T = interp.duration();
  for (int i = 0; i <= 20000; ++i) {
    const State s = sample_at(interp, t0 + T * i / 20000.0);
    for (std::size_t j = 0; j < interp.joints(); ++j) {
      ASSERT_TRUE(std::isfinite(s.q[j]) && std::isfinite(s.qd[j]) && std::isfinite(s.qdd[j]));
      EXPECT_LE(std::abs(s.qd[j]), vmax[j] * (1 + 1e-6)) << "joint " << j << " sample " << i;
      EXPECT_LE(std::abs(s.qdd[j]), amax[j] * (1 + 1e-6)) << "joint " << j << " sample " << i;
    }
  }
}

TEST(QuinticInterpolator, PerJointLimitsRespectedWhenSampledDensely) {
  QuinticInterpolator interp(4);
  interp.reset(std::vector<double>{0, 0, 0, 0});
  const std::vector<double> vmax{5.0, 1.5, 0.5, 0.5}, amax{20.0, 4.0, 2.0, 0.3};
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{30.0, -3.0, 0.8, -0.9}, vmax, amax),
            RetargetStatus::kOk);
  expect_limits_respected(interp, vmax, amax);
  // Tight: at least one joint reaches one of its limits (within the search tolerance).
  double worst = 0;
  for (int i = 0; i <= 20000; ++i) {
    const State s = sample_at(interp, interp.duration() * i / 20000.0);
    for (std::size_t j = 0; j < 4; ++j)
      worst = std::max({worst, std::abs(s.qd[j]) / vmax[j], std::abs(s.qdd[j]) / amax[j]});
  }
  EXPECT_GT(worst, 0.999);
}

TEST(QuinticInterpolator, MidMotionRetargetIsContinuousAndWithinLimits) {
  QuinticInterpolator interp(2);
  interp.reset(std::vector<double>{0.0, 0.0});
  const std::vector<double> vmax{2.0, 2.0}, amax{8.0, 8.0};
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{5.0, 2.0}, vmax, amax), RetargetStatus::kOk);
  const double t_switch = 0.4 * interp.duration();
  const State before = sample_at(interp, t_switch);
  ASSERT_GT(std::abs(before.qd[0]), 0.1);  // really mid-motion
  ASSERT_GT(std::abs(before.qdd[0]), 0.1);

  // Reverse direction: the new segment must brake from the inherited motion.
  ASSERT_EQ(interp.retarget(t_switch, std::vector<double>{-1.0, 2.5}, vmax, amax), RetargetStatus::kOk);
  const State after = sample_at(interp, t_switch);
  for (std::size_t j = 0; j < 2; ++j) {
    EXPECT_NEAR(after.q[j], before.q[j], 1e-12);
    EXPECT_NEAR(after.qd[j], before.qd[j], 1e-9);
    EXPECT_NEAR(after.qdd[j], before.qdd[j], 1e-9);
  }
  // Continuity one tick either side of the switch (1 ms): changes bounded by the limits.
  const State tick_after = sample_at(interp, t_switch + 1e-3);
  for (std::size_t j = 0; j < 2; ++j)
    EXPECT_LE(std::abs(tick_after.qd[j] - before.qd[j]), amax[j] * 1e-3 * 1.01);
  expect_limits_respected(interp, vmax, amax);
  // Shortest: some joint reaches a limit (the duration search stops within 1e-5 of the boundary).
  double worst = 0;
  for (int i = 0; i <= 20000; ++i) {
    const State s = sample_at(interp, t_switch + interp.duration() * i / 20000.0);
    for (std::size_t j = 0; j < 2; ++j)
      worst = std::max({worst, std::abs(s.qd[j]) / vmax[j], std::abs(s.qdd[j]) / amax[j]});
  }
  EXPECT_GT(worst, 0.999);
  const State end = sample_at(interp, t_switch + interp.duration());
  EXPECT_NEAR(end.q[0], -1.0, 1e-12);
  EXPECT_NEAR(end.q[1], 2.5, 1e-12);
}

TEST(QuinticInterpolator, DelayResumesTheMotionWhereItStood) {
  QuinticInterpolator interp(1);
  interp.reset(std::vector<double>{0.0}, 0.0);
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{10.0}, 5.0, 20.0), RetargetStatus::kOk);
  const double T = interp.duration();
  const State before = sample_at(interp, 0.4 * T);
  // The control loop lost 25 ms after sampling at 0.4 T: the next sample, one 1 ms period later in
  // wall time, continues from there rather than 25 ms further on.
  interp.delay(0.025);
  const State after = sample_at(interp, 0.4 * T + 0.025 + 0.001);
  EXPECT_NEAR(after.q[0], before.q[0] + before.qd[0] * 0.001, 1e-4);
  EXPECT_FALSE(interp.done(T + 0.001));
  EXPECT_TRUE(interp.done(T + 0.025));
  EXPECT_EQ(sample_at(interp, T + 0.025).q[0], 10.0);
  // Nonsense delays change nothing.
  interp.delay(-1.0);
  interp.delay(std::numeric_limits<double>::quiet_NaN());
  interp.delay(std::numeric_limits<double>::infinity());
  EXPECT_DOUBLE_EQ(interp.start_time(), 0.025);
}

TEST(QuinticInterpolator, ZeroDistanceGoalHoldsWithMinimumDuration) {
  QuinticInterpolator interp(2, 0.05);
  interp.reset(std::vector<double>{1.0, -2.0});
  ASSERT_EQ(interp.retarget(3.0, std::vector<double>{1.0, -2.0}, 1.0, 1.0), RetargetStatus::kOk);
  EXPECT_DOUBLE_EQ(interp.duration(), 0.05);
  for (double t : {3.0, 3.01, 3.05, 4.0}) {
    const State s = sample_at(interp, t);
    EXPECT_EQ(s.q[0], 1.0);
    EXPECT_EQ(s.q[1], -2.0);
    EXPECT_EQ(s.qd[0], 0.0);
    EXPECT_EQ(s.qdd[1], 0.0);
  }
}

TEST(QuinticInterpolator, RejectsBadInputAndKeepsTheSegment) {
  QuinticInterpolator interp(2);
  interp.reset(std::vector<double>{0.0, 0.0});
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{1.0, 1.0}, 1.0, 1.0), RetargetStatus::kOk);
  const double T = interp.duration();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(interp.retarget(0.1, std::vector<double>{nan, 1.0}, 1.0, 1.0), RetargetStatus::kInvalidArgument);
  EXPECT_EQ(interp.retarget(0.1, std::vector<double>{1.0}, 1.0, 1.0), RetargetStatus::kInvalidArgument);
  EXPECT_EQ(interp.retarget(0.1, std::vector<double>{2.0, 2.0}, 0.0, 1.0), RetargetStatus::kInvalidArgument);
  EXPECT_EQ(interp.retarget(0.1, std::vector<double>{2.0, 2.0}, 1.0, -1.0), RetargetStatus::kInvalidArgument);
  EXPECT_EQ(interp.retarget(nan, std::vector<double>{2.0, 2.0}, 1.0, 1.0), RetargetStatus::kInvalidArgument);
  EXPECT_EQ(interp.duration(), T);
  EXPECT_EQ(interp.goal()[0], 1.0);
  EXPECT_THROW(QuinticInterpolator(0), std::invalid_argument);
  EXPECT_THROW(QuinticInterpolator(kMaxInterpolatedJoints + 1), std::invalid_argument);
  EXPECT_THROW(QuinticInterpolator(2, 0.0), std::invalid_argument);
}

TEST(QuinticInterpolator, InheritedVelocityAboveNewLimitIsReportedAndStaysFinite) {
  QuinticInterpolator interp(1);
  interp.reset(std::vector<double>{0.0});
  ASSERT_EQ(interp.retarget(0.0, std::vector<double>{10.0}, 5.0, 50.0), RetargetStatus::kOk);
  const double t = 0.5 * interp.duration();
  // New, much lower velocity limit: the current speed cannot be undone instantly.
  EXPECT_EQ(interp.retarget(t, std::vector<double>{10.0}, 0.1, 50.0), RetargetStatus::kLimitsUnreachable);
  for (int i = 0; i <= 1000; ++i) {
    const State s = sample_at(interp, t + interp.duration() * i / 1000.0);
    ASSERT_TRUE(std::isfinite(s.q[0]) && std::isfinite(s.qd[0]) && std::isfinite(s.qdd[0]));
  }
  EXPECT_NEAR(sample_at(interp, t + interp.duration()).q[0], 10.0, 1e-12);
}

TEST(QuinticInterpolator, ManyRandomRetargetsStayFiniteAndContinuous) {
  QuinticInterpolator interp(3);
  interp.reset(std::vector<double>{0, 0, 0});
  const std::vector<double> vmax{1, 2, 3}, amax{4, 5, 6};
  unsigned seed = 12345;
  auto rnd = [&] {
    seed = seed * 1103515245u + 12345u;
    return ((seed >> 8) & 0xFFFF) / 65535.0 * 2.0 - 1.0;
  };
  double t = 0.0;
  State prev = sample_at(interp, t);
  for (int k = 0; k < 200; ++k) {
    const std::vector<double> goal{5 * rnd(), 5 * rnd(), 5 * rnd()};
    ASSERT_NE(interp.retarget(t, goal, vmax, amax), RetargetStatus::kInvalidArgument);
    const State now = sample_at(interp, t);
    for (std::size_t j = 0; j < 3; ++j) {
      EXPECT_NEAR(now.q[j], prev.q[j], 1e-9);
      EXPECT_NEAR(now.qd[j], prev.qd[j], 1e-9);
    }
    t += 0.001 + 0.3 * std::abs(rnd());
    prev = sample_at(interp, t);
    for (std::size_t j = 0; j < 3; ++j) ASSERT_TRUE(std::isfinite(prev.q[j]) && std::isfinite(prev.qdd[j]));
  }
}

}  // namespace
}  // namespace tendril::teleop
