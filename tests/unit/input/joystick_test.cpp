#include "tendril/drivers/input/joystick.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace tendril::input {
namespace {

AxisMapping axis(double deadband = 0.1) {
  return AxisMapping{"roll", 0, -100.0, 100.0, deadband, 1.0, false};
}

TEST(NormaliseAxis, CentreIsZeroAndEndsAreFullScale) {
  const auto a = axis();
  EXPECT_DOUBLE_EQ(normalise_axis(a, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(normalise_axis(a, 100.0), 1.0);
  EXPECT_DOUBLE_EQ(normalise_axis(a, -100.0), -1.0);
  EXPECT_DOUBLE_EQ(normalise_axis(a, 250.0), 1.0);  // beyond the range: clamped
}

TEST(NormaliseAxis, DeadbandReadsZeroAndOutputStartsContinuouslyAtItsEdge) {
  const auto a = axis(0.1);
  EXPECT_DOUBLE_EQ(normalise_axis(a, 9.9), 0.0);
  EXPECT_DOUBLE_EQ(normalise_axis(a, -10.0), 0.0);
  EXPECT_NEAR(normalise_axis(a, 10.0 + 1e-6), 0.0, 1e-6);  // no step at the edge
  EXPECT_NEAR(normalise_axis(a, 55.0), 0.5, 1e-12);        // (0.55 − 0.1) / 0.9
}

TEST(NormaliseAxis, ScaleAndInversion) {
  auto a = axis(0.0);
  a.scale = 0.5;
  EXPECT_DOUBLE_EQ(normalise_axis(a, 100.0), 0.5);
  a.invert = true;
  EXPECT_DOUBLE_EQ(normalise_axis(a, 100.0), -0.5);
  a.scale = 3.0;
  EXPECT_DOUBLE_EQ(normalise_axis(a, 100.0), -1.0);  // clamped after scaling
}

TEST(NormaliseAxis, NonFiniteReadsZero) {
  EXPECT_EQ(normalise_axis(axis(), std::numeric_limits<double>::quiet_NaN()), 0.0);
  EXPECT_EQ(normalise_axis(axis(), std::numeric_limits<double>::infinity()), 0.0);
}

TEST(JoystickMapping, RefusesMappingsThatCannotWork) {
  JoystickMapping m;
  m.axes = {axis(), axis()};
  EXPECT_THROW(m.validate(), JoystickConfigError);  // "roll" twice
  m.axes = {axis(1.0)};
  EXPECT_THROW(m.validate(), JoystickConfigError);  // deadband swallows everything
  m.axes = {AxisMapping{"roll", 0, 5.0, 5.0, 0.1, 1.0, false}};
  EXPECT_THROW(m.validate(), JoystickConfigError);  // empty range
  m.axes = {AxisMapping{"", 0, -1.0, 1.0, 0.1, 1.0, false}};
  EXPECT_THROW(m.validate(), JoystickConfigError);
  m.axes = {AxisMapping{"roll", 0, -1.0, 1.0, 0.1, -1.0, false}};
  EXPECT_THROW(m.validate(), JoystickConfigError);  // negative scale: use invert
  m.axes = {axis()};
  EXPECT_NO_THROW(m.validate());
  EXPECT_EQ(m.output_index("roll"), 0);
  EXPECT_EQ(m.output_index("distal"), -1);
}

}  // namespace
}  // namespace tendril::input
