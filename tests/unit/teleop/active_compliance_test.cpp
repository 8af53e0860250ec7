#include "tendril/teleop/active_compliance.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace tendril::teleop {
namespace {

constexpr double dt = 0.001;

TEST(ActiveCompliance, IncrementFollowsEq425AtBothEndsOfTheRange) {
  // T4.7: t = 0 gives K_a·v_min·dt, t = 1 gives K_a·v_max·dt.
  ActiveComplianceParameters p;
  p.gain = 1.5;
  p.deadband = 0.0;
  EXPECT_NEAR(std::abs(active_compliance_increment(p, 1e-12, dt)), 1.5 * p.min_speed * dt, 1e-14);
  EXPECT_NEAR(std::abs(active_compliance_increment(p, p.max_deflection, dt)), 1.5 * p.max_speed * dt, 1e-12);
  // Halfway: the mean of both speeds.
  EXPECT_NEAR(std::abs(active_compliance_increment(p, 0.5 * p.max_deflection, dt)),
              1.5 * 0.5 * (p.min_speed + p.max_speed) * dt, 1e-12);
}

TEST(ActiveCompliance, MovesAgainstTheDeflectionSoTheSpringRelaxes) {
  const ActiveComplianceParameters p;
  // deflection = drive − carriage < 0: the carriage was pushed up, the drive follows it up.
  EXPECT_GT(active_compliance_increment(p, -0.5, dt), 0.0);
  EXPECT_LT(active_compliance_increment(p, 0.5, dt), 0.0);
}

TEST(ActiveCompliance, SaturatesBeyondTheMaximumDeflection) {
  const ActiveComplianceParameters p;
  EXPECT_DOUBLE_EQ(active_compliance_increment(p, 5.0 * p.max_deflection, dt),
                   active_compliance_increment(p, p.max_deflection, dt));
}

TEST(ActiveCompliance, DeadbandAndBadInputGiveNoMotion) {
  const ActiveComplianceParameters p;
  EXPECT_EQ(active_compliance_increment(p, 0.5 * p.deadband, dt), 0.0);
  EXPECT_EQ(active_compliance_increment(p, std::numeric_limits<double>::quiet_NaN(), dt), 0.0);
  EXPECT_EQ(active_compliance_increment(p, 0.5, 0.0), 0.0);
  EXPECT_EQ(active_compliance_increment(p, 0.5, -dt), 0.0);
  // Just outside the deadband it moves at about v_min.
  EXPECT_GT(std::abs(active_compliance_increment(p, 1.01 * p.deadband, dt)), 0.9 * p.min_speed * dt);
}

TEST(ActiveCompliance, Eq424OnlyTouchesTheBendDrives) {
  const ActiveComplianceParameters p;
  const std::array<double, 4> measured{30.0, 0.2, 1.0, -1.0};
  std::array<double, 4> q_des{31.0, 0.3, 0.0, 0.0};
  apply_active_compliance(p, measured, {-0.5, 0.0}, dt, q_des);
  EXPECT_EQ(q_des[0], 31.0);
  EXPECT_EQ(q_des[1], 0.3);
  EXPECT_GT(q_des[2], measured[2]);
  EXPECT_EQ(q_des[3], measured[3]);  // no deflection: holds where it is
}

TEST(ActiveCompliance, RejectsParametersThatCannotWork) {
  ActiveComplianceParameters p;
  EXPECT_NO_THROW(validate(p));
  p.max_speed = 0.1;  // below v_min
  EXPECT_THROW(validate(p), std::invalid_argument);
  p = {};
  p.deadband = 2.0;  // ≥ max deflection: would never move
  EXPECT_THROW(validate(p), std::invalid_argument);
  p = {};
  p.gain = std::numeric_limits<double>::infinity();
  EXPECT_THROW(validate(p), std::invalid_argument);
}

}  // namespace
}  // namespace tendril::teleop
