// EvdevJoystick against a real kernel input device created through uinput, including hot-plug
// (destroying and re-creating the device). Needs /dev/uinput and evdev: runs inside the qemu VM
// (tests/can-vm), where TENDRIL_CAN_VM_REQUIRED=1 turns a missing device into a failure.
#include <fcntl.h>
#include <linux/uinput.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <thread>

#include "tendril/drivers/input/evdev_joystick.hpp"

namespace tendril::input {
namespace {

constexpr const char* kName = "tendril test gamepad";

class UinputPad {
 public:
  UinputPad() {
    fd_ = ::open("/dev/uinput", O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd_ < 0) return;
    bool ok = ::ioctl(fd_, UI_SET_EVBIT, EV_ABS) == 0 && ::ioctl(fd_, UI_SET_EVBIT, EV_KEY) == 0 &&
              ::ioctl(fd_, UI_SET_KEYBIT, BTN_TR) == 0 && ::ioctl(fd_, UI_SET_KEYBIT, BTN_SOUTH) == 0;
    for (int code : {ABS_X, ABS_Y}) {
      uinput_abs_setup abs{};
      abs.code = static_cast<std::uint16_t>(code);
      abs.absinfo.minimum = 0;
      abs.absinfo.maximum = 1023;  // differs from the configured range: the device's own must win
      abs.absinfo.value = 512;
      ok = ok && ::ioctl(fd_, UI_SET_ABSBIT, code) == 0 && ::ioctl(fd_, UI_ABS_SETUP, &abs) == 0;
    }
    uinput_setup setup{};
    setup.id.bustype = BUS_USB;
    setup.id.vendor = 0x1209;
    setup.id.product = 0x0001;
    std::strncpy(setup.name, kName, UINPUT_MAX_NAME_SIZE - 1);
    ok = ok && ::ioctl(fd_, UI_DEV_SETUP, &setup) == 0 && ::ioctl(fd_, UI_DEV_CREATE) == 0;
    if (!ok) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~UinputPad() {
    if (fd_ >= 0) {
      ::ioctl(fd_, UI_DEV_DESTROY);
      ::close(fd_);
    }
  }
  bool ok() const { return fd_ >= 0; }
  void emit(std::uint16_t type, std::uint16_t code, std::int32_t value) {
    input_event e{};
    e.type = type;
    e.code = code;
    e.value = value;
    ASSERT_EQ(::write(fd_, &e, sizeof(e)), static_cast<ssize_t>(sizeof(e)));
  }

 private:
  int fd_ = -1;
};

template <typename Predicate>
bool wait_for(Predicate p) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (std::chrono::steady_clock::now() < end) {
    if (p()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return p();
}

TEST(EvdevUinput, RealDeviceByNameWithDeviceRangeDeadmanAndHotPlug) {
  if (::access("/dev/uinput", W_OK) != 0) {
    if (std::getenv("TENDRIL_CAN_VM_REQUIRED") != nullptr) FAIL() << "/dev/uinput is missing in the test VM";
    GTEST_SKIP() << "no /dev/uinput on this kernel (runs inside tests/can-vm)";
  }
  EvdevJoystickOptions options;
  options.device = std::string("name:") + kName;
  options.mapping.axes = {{"roll", ABS_X, -1, 1, 0.05, 1.0, false},
                          {"proximal", ABS_Y, -1, 1, 0.05, 1.0, false}};
  options.mapping.deadman_code = BTN_TR;
  options.rescan_period = std::chrono::milliseconds(50);
  EvdevJoystick joystick(options);
  joystick.start();

  auto pad = std::make_unique<UinputPad>();
  ASSERT_TRUE(pad->ok()) << "could not create the uinput device: " << std::strerror(errno);
  ASSERT_TRUE(wait_for([&] { return joystick.state().connected; }));
  EXPECT_FALSE(joystick.state().deadman);
  EXPECT_NEAR(joystick.state().outputs[0], 0.0, 1e-9);  // 512 of 0..1023 is inside the deadband

  pad->emit(EV_ABS, ABS_X, 1023);
  pad->emit(EV_KEY, BTN_TR, 1);
  pad->emit(EV_SYN, SYN_REPORT, 0);
  ASSERT_TRUE(wait_for([&] { return joystick.state().deadman; }));
  EXPECT_NEAR(joystick.state().outputs[0], 1.0, 1e-9);

  pad.reset();  // unplugged while the deadman is held: everything must release
  ASSERT_TRUE(wait_for([&] { return !joystick.state().connected; }));
  EXPECT_FALSE(joystick.state().deadman);
  EXPECT_EQ(joystick.state().outputs[0], 0.0);

  pad = std::make_unique<UinputPad>();  // plugged in again, probably under another event node
  ASSERT_TRUE(pad->ok());
  ASSERT_TRUE(wait_for([&] { return joystick.state().connected && joystick.connects() == 2; }));
  pad->emit(EV_ABS, ABS_Y, 0);
  pad->emit(EV_SYN, SYN_REPORT, 0);
  ASSERT_TRUE(wait_for([&] { return joystick.state().outputs[1] < -0.99; }));
  EXPECT_FALSE(joystick.state().deadman);
  joystick.stop();
}

}  // namespace
}  // namespace tendril::input
