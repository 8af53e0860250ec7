#include "tendril/drivers/canopen/analog_input_node.hpp"

#include <gtest/gtest.h>

namespace tendril::canopen {
namespace {

TEST(AnalogInputNode, EncodesAndDecodesMillivoltsAndDigitalInputs) {
  const auto f = encode_analog_input_pdo(0x31, {2.5, 0.0, 5.0}, std::uint8_t{0x05});
  EXPECT_EQ(f.id, 0x1B1U);
  EXPECT_EQ(f.len, 7);
  EXPECT_EQ(f.data[0], 0xC4);  // 2500 mV = 0x09C4, little-endian
  EXPECT_EQ(f.data[1], 0x09);
  const auto pdo = decode_analog_input_pdo(f, 0x31);
  ASSERT_TRUE(pdo);
  EXPECT_DOUBLE_EQ(pdo->volts[0], 2.5);
  EXPECT_DOUBLE_EQ(pdo->volts[2], 5.0);
  EXPECT_TRUE(pdo->has_digital_inputs);
  EXPECT_EQ(pdo->digital_inputs, 0x05);
  // Without the 7th byte: no digital inputs.
  const auto six = decode_analog_input_pdo(encode_analog_input_pdo(0x31, {1.0, 1.0, 1.0}), 0x31);
  ASSERT_TRUE(six);
  EXPECT_FALSE(six->has_digital_inputs);
}

TEST(AnalogInputNode, IgnoresOtherNodesShortRtrAndErrorFrames) {
  auto f = encode_analog_input_pdo(0x31, {2.5, 2.5, 2.5});
  EXPECT_FALSE(decode_analog_input_pdo(f, 0x30));
  auto shorter = f;
  shorter.len = 5;
  EXPECT_FALSE(decode_analog_input_pdo(shorter, 0x31));
  auto rtr = f;
  rtr.rtr = true;
  EXPECT_FALSE(decode_analog_input_pdo(rtr, 0x31));
  auto error = f;
  error.error = true;
  EXPECT_FALSE(decode_analog_input_pdo(error, 0x31));
}

TEST(AnalogInputReceiver, GoesStaleAndFlagsWiringFaults) {
  AnalogInputReceiver rx({0x31, 5.0, 0.25, 100'000'000});
  EXPECT_FALSE(rx.reading(0).fresh);  // nothing yet
  ASSERT_TRUE(rx.handle(encode_analog_input_pdo(0x31, {2.5, 5.6, -0.0}), 1'000'000));
  auto r = rx.reading(50'000'000);
  EXPECT_TRUE(r.fresh);
  EXPECT_FALSE(r.wiring_fault[0]);
  EXPECT_TRUE(r.wiring_fault[1]);  // 5.6 V: beyond 5 V + 0.25 V
  EXPECT_FALSE(r.wiring_fault[2]);
  EXPECT_FALSE(rx.reading(102'000'000).fresh);
  EXPECT_THROW(AnalogInputReceiver({0, 5.0, 0.25, 1}), std::invalid_argument);
  EXPECT_THROW(AnalogInputReceiver({1, 5.0, 0.25, 0}), std::invalid_argument);
}

}  // namespace
}  // namespace tendril::canopen
