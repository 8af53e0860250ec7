#include <gtest/gtest.h>

#include <sys/socket.h>
#include <unistd.h>

#include "tendril/drivers/can/socketcan_bus.hpp"

namespace tendril::can {
namespace {

// On a kernel without AF_CAN (this CI's) the constructor must explain that; on one with CAN but
// without the interface it must name the interface. Either way it throws CanSetupError.
TEST(SocketCanBus, MissingInterfaceOrKernelSupportThrowsAClearError) {
  const int probe = ::socket(PF_CAN, SOCK_RAW, 1 /* CAN_RAW */);
  const bool kernel_has_can = probe >= 0;
  if (probe >= 0) ::close(probe);
  try {
    SocketCanBus bus("tendrilnone0");
    FAIL() << "opening a non-existent interface succeeded";
  } catch (const CanSetupError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("tendrilnone0"), std::string::npos) << msg;
    if (!kernel_has_can) {
      EXPECT_NE(msg.find("no CAN support"), std::string::npos) << msg;
    } else {
      EXPECT_NE(msg.find("no such network interface"), std::string::npos) << msg;
    }
  }
}

TEST(SocketCanBus, InvalidInterfaceNameIsRejected) {
  EXPECT_THROW(SocketCanBus(""), CanSetupError);
  EXPECT_THROW(SocketCanBus("an-interface-name-that-is-far-too-long"), CanSetupError);
}

TEST(SocketCanBus, ErrorFramesMapToControllerStates) {
  std::array<std::uint8_t, 8> data{};
  EXPECT_EQ(bus_state_after_error_frame(error_class::bus_off, data, BusState::error_active),
            BusState::bus_off);
  data[1] = 0x04;  // RX warning
  EXPECT_EQ(bus_state_after_error_frame(error_class::controller, data, BusState::error_active),
            BusState::error_warning);
  data[1] = 0x20;  // TX passive
  EXPECT_EQ(bus_state_after_error_frame(error_class::controller, data, BusState::error_warning),
            BusState::error_passive);
  data[1] = 0x40;  // back to error active
  EXPECT_EQ(bus_state_after_error_frame(error_class::controller, data, BusState::error_passive),
            BusState::error_active);
  data[1] = 0;
  EXPECT_EQ(bus_state_after_error_frame(error_class::restarted, data, BusState::bus_off),
            BusState::error_active);
  EXPECT_EQ(bus_state_after_error_frame(error_class::protocol, data, BusState::error_warning),
            BusState::error_warning);  // a protocol error alone does not change the state
  EXPECT_EQ(bus_state_after_error_frame(error_class::bus_off | error_class::restarted, data,
                                        BusState::error_active),
            BusState::bus_off);
}

}  // namespace
}  // namespace tendril::can
