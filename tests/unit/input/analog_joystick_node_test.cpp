// The SIMULATED P3America 822 ADC node and AnalogJoystickReceiver over the virtual CAN bus: frames,
// timing, NMT, the dissertation's voltage mapping through a 12-bit ADC with noise, and the failure cases.
#include <gtest/gtest.h>

#include <cmath>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"

namespace tendril {
namespace {

struct Rig {
  can::VirtualBus bus{"vcan-test"};
  std::unique_ptr<can::VirtualBusEndpoint> node_end = bus.attach("adc-node");
  std::unique_ptr<can::VirtualBusEndpoint> master_end = bus.attach("master");
  sim::SimulatedAnalogJoystick node{*node_end, sim::AnalogJoystickNodeParameters{}};
  input::AnalogJoystickReceiver receiver{input::AnalogJoystickCalibration{}};
  std::int64_t now_ns = 0;
  int heartbeats = 0;
  int bootups = 0;

  // Steps the node at 1 kHz for `seconds`, the receiver draining the bus every step.
  void run(double seconds) {
    const int steps = static_cast<int>(std::lround(seconds * 1000.0));
    for (int i = 0; i < steps; ++i) {
      node.step(0.001);
      now_ns += 1'000'000;
      while (auto frame = master_end->receive(std::chrono::nanoseconds(0))) {
        if (frame->id == 0x730) {
          (frame->data[0] == 0x00 ? bootups : heartbeats)++;
        }
        receiver.handle(*frame, now_ns);
      }
    }
  }
};

TEST(SimulatedAnalogJoystick, BootsSendsHeartbeatsAndTpdosAtTheirRates) {
  Rig rig;
  rig.run(1.0);
  EXPECT_EQ(rig.bootups, 1);
  EXPECT_NEAR(rig.heartbeats, 10, 1);                                   // 100 ms heartbeat
  EXPECT_NEAR(static_cast<double>(rig.receiver.frames()), 100.0, 1.0);  // 10 ms TPDO
  const auto state = rig.receiver.state(true, rig.now_ns);
  ASSERT_TRUE(state.connected);
  for (double o : state.outputs) EXPECT_EQ(o, 0.0);  // centred stick: noise stays inside the deadband
}

TEST(SimulatedAnalogJoystick, DeflectionReachesTheReceiverAsTheDissertationsVoltage) {
  Rig rig;
  rig.node.set_deflection({1.0, -1.0, 0.5});
  rig.run(0.1);  // 25 filter time constants
  const auto volts = rig.node.last_sample();
  EXPECT_NEAR(volts[0], 5.0, 0.02);  // +max → 5 V
  EXPECT_NEAR(volts[1], 0.0, 0.02);  // −max → 0 V
  EXPECT_NEAR(volts[2], 3.75, 0.02);
  const auto state = rig.receiver.state(true, rig.now_ns);
  ASSERT_TRUE(state.connected);
  EXPECT_NEAR(state.outputs[0], 1.0, 0.01);
  EXPECT_NEAR(state.outputs[1], -1.0, 0.01);
  EXPECT_NEAR(state.outputs[2], 0.46 / 0.96, 0.01);  // half deflection minus the 4 % deadband
}

TEST(SimulatedAnalogJoystick, NmtStopSilenceAndWiringFaultsStopMotion) {
  Rig rig;
  rig.node.set_deflection({1.0, 0.0, 0.0});
  rig.run(0.1);
  ASSERT_TRUE(rig.receiver.state(true, rig.now_ns).connected);

  ASSERT_EQ(rig.master_end->send(can::Frame::make(0x000, {0x02, 0x30})), can::SendResult::ok);  // NMT stop
  rig.run(0.2);
  EXPECT_FALSE(rig.receiver.state(true, rig.now_ns).connected);  // stale after 100 ms
  rig.master_end->send(can::Frame::make(0x000, {0x01, 0x00}));   // NMT start all
  rig.run(0.05);
  EXPECT_TRUE(rig.receiver.state(true, rig.now_ns).connected);

  rig.node.inject_channel_voltage(2, 5.9);  // open wiper pulled up past the supply
  rig.run(0.1);
  const auto faulted = rig.receiver.state(true, rig.now_ns);
  EXPECT_FALSE(faulted.connected);
  EXPECT_EQ(faulted.outputs[0], 0.0);
  rig.node.inject_channel_voltage(2, std::nan(""));
  rig.run(0.1);
  EXPECT_TRUE(rig.receiver.state(true, rig.now_ns).connected);

  rig.node.set_silent(true);  // cable pulled
  rig.run(0.2);
  EXPECT_FALSE(rig.receiver.state(true, rig.now_ns).connected);
}

TEST(SimulatedAnalogJoystick, TheFootPedalOnDigitalInput0IsTheDeadman) {
  Rig rig;
  rig.node.set_deflection({0.0, 1.0, 0.0});
  rig.run(0.2);
  auto state = rig.receiver.state(rig.now_ns);
  EXPECT_TRUE(state.connected);
  EXPECT_FALSE(state.deadman);
  EXPECT_GT(state.outputs[1], 0.9);  // the stick reads; without the pedal nothing may move
  rig.node.set_pedal(true);
  rig.run(0.05);
  EXPECT_TRUE(rig.receiver.state(rig.now_ns).deadman);
  rig.node.set_pedal(false);
  rig.run(0.05);
  EXPECT_FALSE(rig.receiver.state(rig.now_ns).deadman);
  // A calibration without a pedal never reports the deadman from the node.
  input::AnalogJoystickCalibration none;
  none.deadman_digital_input = -1;
  input::AnalogJoystickReceiver no_pedal(none);
  rig.node.set_pedal(true);
  rig.run(0.05);
  const auto frame = input::encode_analog_joystick_pdo(0x30, {2.5, 2.5, 2.5});
  no_pedal.handle(frame, rig.now_ns);
  EXPECT_FALSE(no_pedal.state(rig.now_ns).deadman);
  none.deadman_digital_input = 9;
  EXPECT_THROW(input::AnalogJoystickReceiver{none}, input::JoystickConfigError);
}

}  // namespace
}  // namespace tendril
