// The dissertation's P3America 822 joystick through its ADC node (Abah 2022, §4.7.4).
#include "tendril/drivers/input/analog_joystick.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace tendril::input {
namespace {

TEST(AnalogJoystick, DissertationMappingHalfSupplyIsZeroEndsAreFullRate) {
  AnalogJoystickCalibration c;  // 5 V supply, 0.1 V deadband
  const auto s = analog_joystick_state({2.5, 5.0, 0.0}, c, true, 0);
  ASSERT_TRUE(s.connected);
  EXPECT_DOUBLE_EQ(s.outputs[0], 0.0);   // 2.5 V → 0
  EXPECT_DOUBLE_EQ(s.outputs[1], 1.0);   // 5 V → +q̇_max
  EXPECT_DOUBLE_EQ(s.outputs[2], -1.0);  // 0 V → −q̇_max
  EXPECT_TRUE(s.deadman);
}

TEST(AnalogJoystick, DeadbandAroundHalfSupplyAndLinearBeyond) {
  AnalogJoystickCalibration c;
  EXPECT_EQ(analog_joystick_state({2.58, 2.42, 2.5}, c, true, 0).outputs[0], 0.0);
  EXPECT_EQ(analog_joystick_state({2.58, 2.42, 2.5}, c, true, 0).outputs[1], 0.0);
  // 3.75 V is half deflection: (0.5 − 0.04) / 0.96 after cutting the 0.1 V (4 %) deadband.
  EXPECT_NEAR(analog_joystick_state({3.75, 2.5, 2.5}, c, true, 0).outputs[0], 0.46 / 0.96, 1e-12);
  c.deadband_volts = 0.0;
  EXPECT_NEAR(analog_joystick_state({3.75, 2.5, 2.5}, c, true, 0).outputs[0], 0.5,
              1e-12);  // the linear map exactly
}

TEST(AnalogJoystick, OutOfRangeVoltageIsAWiringFaultThatStopsMotion) {
  AnalogJoystickCalibration c;
  for (double bad : {-0.5, 5.4, std::nan("")}) {
    const auto s = analog_joystick_state({2.5, bad, 5.0}, c, true, 0);
    EXPECT_FALSE(s.connected) << bad;
    EXPECT_FALSE(s.deadman);
    for (double o : s.outputs) EXPECT_EQ(o, 0.0);
  }
  EXPECT_TRUE(analog_joystick_state({-0.2, 5.2, 2.5}, c, true, 0).connected);  // within the margin
}

TEST(AnalogJoystick, PdoRoundTripInMillivolts) {
  const auto frame = encode_analog_joystick_pdo(0x30, {1.234, 5.0, 0.0});
  EXPECT_EQ(frame.id, 0x1B0U);
  EXPECT_EQ(frame.len, 6);
  EXPECT_EQ(frame.data[0], 0xD2);  // 1234 mV = 0x04D2, little-endian
  EXPECT_EQ(frame.data[1], 0x04);
  const auto volts = decode_analog_joystick_pdo(frame, 0x30);
  ASSERT_TRUE(volts);
  EXPECT_DOUBLE_EQ((*volts)[0], 1.234);
  EXPECT_DOUBLE_EQ((*volts)[1], 5.0);
  EXPECT_FALSE(decode_analog_joystick_pdo(frame, 0x31));  // another node's TPDO
  auto short_frame = frame;
  short_frame.len = 4;
  EXPECT_FALSE(decode_analog_joystick_pdo(short_frame, 0x30));
}

TEST(AnalogJoystickReceiver, StaleReadingsStopMotion) {
  AnalogJoystickCalibration c;
  c.stale_after_ns = 100'000'000;
  AnalogJoystickReceiver receiver(c);
  EXPECT_FALSE(receiver.state(true, 0).connected);                    // nothing heard yet
  EXPECT_FALSE(receiver.handle(can::Frame::make(0x701, {0x05}), 0));  // its heartbeat is not a reading
  ASSERT_TRUE(receiver.handle(encode_analog_joystick_pdo(0x30, {5.0, 2.5, 2.5}), 1'000'000'000));
  EXPECT_DOUBLE_EQ(receiver.state(true, 1'050'000'000).outputs[0], 1.0);
  EXPECT_FALSE(receiver.state(false, 1'050'000'000).deadman);
  const auto stale = receiver.state(true, 1'200'000'000);
  EXPECT_FALSE(stale.connected);
  EXPECT_EQ(stale.outputs[0], 0.0);
}

TEST(AnalogJoystickReceiver, RefusesImpossibleCalibration) {
  AnalogJoystickCalibration c;
  c.node_id = 0;
  EXPECT_THROW(AnalogJoystickReceiver{c}, JoystickConfigError);
  c = {};
  c.deadband_volts = 2.5;
  EXPECT_THROW(AnalogJoystickReceiver{c}, JoystickConfigError);
}

}  // namespace
}  // namespace tendril::input
