#include "tendril/teleop/pid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace tendril::teleop {
namespace {

// First-order plant τ·ẏ = −y + gain·u, integrated with explicit Euler at the controller rate.
struct FirstOrderPlant {
  double tau = 0.2, gain = 1.0, y = 0.0;
  void step(double u, double dt) { y += dt / tau * (-y + gain * u); }
};

struct StepRun {
  double final_value = 0, overshoot = 0, max_abs_output = 0;
};

StepRun simulate(Pid& pid, FirstOrderPlant plant, double setpoint, double seconds, double dt = 1e-3) {
  StepRun r;
  for (int i = 0; i < static_cast<int>(seconds / dt); ++i) {
    const double u = pid.update(setpoint, plant.y, dt);
    r.max_abs_output = std::max(r.max_abs_output, std::abs(u));
    plant.step(u, dt);
    r.overshoot = std::max(r.overshoot, plant.y - setpoint);
  }
  r.final_value = plant.y;
  return r;
}

TEST(Pid, StepResponseConvergesOnFirstOrderPlant) {
  Pid pid({.kp = 2.0, .ki = 5.0, .kd = 0.01, .derivative_filter_time = 0.005});
  const StepRun r = simulate(pid, FirstOrderPlant{}, 1.0, 5.0);
  EXPECT_NEAR(r.final_value, 1.0, 1e-3);  // integral action removes the steady-state error
  // Proportional-only control leaves the classic error 1/(1 + kp·gain).
  Pid p_only({.kp = 2.0});
  EXPECT_NEAR(simulate(p_only, FirstOrderPlant{}, 1.0, 5.0).final_value, 2.0 / 3.0, 1e-3);
}

TEST(Pid, OutputIsClampedToTheLimit) {
  Pid pid({.kp = 100.0, .ki = 10.0, .output_limit = 0.7});
  EXPECT_DOUBLE_EQ(pid.update(10.0, 0.0, 1e-3), 0.7);
  EXPECT_TRUE(pid.saturated());
  EXPECT_DOUBLE_EQ(pid.update(-10.0, 0.0, 1e-3), -0.7);
  const StepRun r = simulate(pid, FirstOrderPlant{}, 5.0, 2.0);
  EXPECT_LE(r.max_abs_output, 0.7);
}

TEST(Pid, AntiWindupLimitsOvershootAfterSaturation) {
  // The plant needs u = 1 in steady state; the limit of 1.2 keeps the output saturated for a while.
  PidGains gains{.kp = 1.0, .ki = 4.0, .output_limit = 1.2};
  gains.anti_windup = AntiWindup::kNone;
  Pid plain(gains);
  const StepRun wound = simulate(plain, FirstOrderPlant{.tau = 1.0}, 1.0, 20.0);
  gains.anti_windup = AntiWindup::kConditional;
  Pid conditional(gains);
  const StepRun cond = simulate(conditional, FirstOrderPlant{.tau = 1.0}, 1.0, 20.0);
  gains.anti_windup = AntiWindup::kBackCalculation;
  Pid back(gains);
  const StepRun bc = simulate(back, FirstOrderPlant{.tau = 1.0}, 1.0, 20.0);

  EXPECT_GT(wound.overshoot, 0.05);
  EXPECT_LT(cond.overshoot, 0.5 * wound.overshoot);
  EXPECT_LT(bc.overshoot, 0.5 * wound.overshoot);
  EXPECT_NEAR(cond.final_value, 1.0, 1e-3);
  EXPECT_NEAR(bc.final_value, 1.0, 1e-3);
}

TEST(Pid, IntegratorDoesNotGrowWhileSaturated) {
  Pid pid({.kp = 1.0, .ki = 10.0, .output_limit = 0.5, .anti_windup = AntiWindup::kConditional});
  for (int i = 0; i < 5000; ++i) pid.update(100.0, 0.0, 1e-3);  // stuck plant, huge error
  EXPECT_LE(pid.integral(), 1e-9);                              // kp·e alone saturates: no integration
  Pid limited({.kp = 0.0, .ki = 1.0, .integral_limit = 0.3, .anti_windup = AntiWindup::kNone});
  for (int i = 0; i < 5000; ++i) limited.update(1.0, 0.0, 1e-3);
  EXPECT_DOUBLE_EQ(limited.integral(), 0.3);
}

TEST(Pid, DerivativeActsOnMeasurementOnly) {
  Pid pid({.kp = 0.0, .kd = 1.0});
  pid.update(0.0, 0.0, 1e-3);
  EXPECT_DOUBLE_EQ(pid.update(5.0, 0.0, 1e-3), 0.0);       // setpoint step: no derivative kick
  EXPECT_NEAR(pid.update(5.0, 0.001, 1e-3), -1.0, 1e-12);  // measurement moving at +1/s → −kd·1
}

TEST(Pid, DerivativeFilterSmoothsAStep) {
  Pid pid({.kd = 1.0, .derivative_filter_time = 0.01});
  pid.update(0.0, 0.0, 1e-3);
  const double first = pid.update(0.0, 0.01, 1e-3);  // raw derivative −10/s
  EXPECT_NEAR(first, -10.0 * (1e-3 / (0.01 + 1e-3)), 1e-9);
}

TEST(Pid, BadSampleGivesZeroAndResetClears) {
  Pid pid({.kp = 1.0, .ki = 1.0});
  pid.update(1.0, 0.0, 1e-3);
  const double integral = pid.integral();
  EXPECT_EQ(pid.update(std::numeric_limits<double>::quiet_NaN(), 0.0, 1e-3), 0.0);
  EXPECT_EQ(pid.update(1.0, 0.0, 0.0), 0.0);
  EXPECT_EQ(pid.integral(), integral);
  pid.reset();
  EXPECT_EQ(pid.integral(), 0.0);
  EXPECT_THROW(Pid({.kp = -1.0}), std::invalid_argument);
  EXPECT_THROW(Pid({.kp = 1.0, .output_limit = 0.0}), std::invalid_argument);
}

}  // namespace
}  // namespace tendril::teleop
