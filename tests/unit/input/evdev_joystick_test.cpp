// EvdevDecoder with recorded event sequences, and EvdevJoystick's reader thread fed through a FIFO
// (a recorded-event source with the same read()/poll() behaviour as a device node, minus ioctls),
// including unplug (writer closes) and re-plug.
#include "tendril/drivers/input/evdev_joystick.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <thread>
#include <vector>

namespace tendril::input {
namespace {

JoystickMapping gamepad() {
  JoystickMapping m;
  m.axes = {{"roll", ABS_X, -32768, 32767, 0.05, 1.0, false},
            {"proximal", ABS_Y, -32768, 32767, 0.05, 1.0, true},  // stick up reads negative on most pads
            {"distal", ABS_RZ, 0, 255, 0.05, 1.0, false}};
  m.buttons = {{BTN_SOUTH, "hold"}};
  m.deadman_code = BTN_TR;
  return m;
}

input_event ev(std::uint16_t type, std::uint16_t code, std::int32_t value, long usec = 0) {
  input_event e{};
  e.input_event_sec = 1;
  e.input_event_usec = usec;
  e.type = type;
  e.code = code;
  e.value = value;
  return e;
}

TEST(EvdevDecoder, ReportsOnlyAtSynReportWithMappedOutputs) {
  EvdevDecoder d(gamepad());
  d.set_connected(true);
  EXPECT_FALSE(d.apply(ev(EV_ABS, ABS_X, 32767)));
  EXPECT_FALSE(d.apply(ev(EV_ABS, ABS_Y, -32768)));
  EXPECT_FALSE(d.apply(ev(EV_ABS, ABS_RZ, 0)));
  EXPECT_FALSE(d.apply(ev(EV_ABS, ABS_HAT0X, 1)));  // unmapped: ignored
  ASSERT_TRUE(d.apply(ev(EV_SYN, SYN_REPORT, 0, 250)));
  const auto s = d.state();
  EXPECT_NEAR(s.outputs[0], 1.0, 1e-4);
  EXPECT_NEAR(s.outputs[1], 1.0, 1e-4);  // inverted
  EXPECT_NEAR(s.outputs[2], -1.0, 1e-4);
  EXPECT_EQ(s.reports, 1U);
  EXPECT_EQ(s.stamp_ns, 1'000'250'000);
  EXPECT_FALSE(s.deadman);
}

TEST(EvdevDecoder, DeadmanAndButtons) {
  EvdevDecoder d(gamepad());
  d.set_connected(true);
  d.apply(ev(EV_KEY, BTN_TR, 1));
  d.apply(ev(EV_KEY, BTN_SOUTH, 1));
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  EXPECT_TRUE(d.state().deadman);
  EXPECT_EQ(d.state().buttons, 1U);
  d.apply(ev(EV_KEY, BTN_TR, 2));  // autorepeat still held
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  EXPECT_TRUE(d.state().deadman);
  d.apply(ev(EV_KEY, BTN_TR, 0));
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  EXPECT_FALSE(d.state().deadman);
}

TEST(EvdevDecoder, IgnoresTheIncompleteReportAfterSynDropped) {
  EvdevDecoder d(gamepad());
  d.set_connected(true);
  d.apply(ev(EV_ABS, ABS_X, 16000));
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  const double before = d.state().outputs[0];
  d.apply(ev(EV_SYN, SYN_DROPPED, 0));
  d.apply(ev(EV_ABS, ABS_X, -32768));
  EXPECT_FALSE(d.apply(ev(EV_SYN, SYN_REPORT, 0)));
  EXPECT_EQ(d.state().outputs[0], before);
  d.apply(ev(EV_ABS, ABS_X, -32768));
  EXPECT_TRUE(d.apply(ev(EV_SYN, SYN_REPORT, 0)));
  EXPECT_NEAR(d.state().outputs[0], -1.0, 1e-9);
}

TEST(EvdevDecoder, DisconnectReleasesEverything) {
  EvdevDecoder d(gamepad());
  d.set_connected(true);
  d.apply(ev(EV_ABS, ABS_X, 32767));
  d.apply(ev(EV_KEY, BTN_TR, 1));
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  d.set_connected(false);
  EXPECT_FALSE(d.state().connected);
  EXPECT_FALSE(d.state().deadman);
  for (double o : d.state().outputs) EXPECT_EQ(o, 0.0);
  d.set_connected(true);  // re-plugged: centred until the device says otherwise
  d.publish(0);
  EXPECT_EQ(d.state().outputs[0], 0.0);
  EXPECT_FALSE(d.state().deadman);
}

TEST(EvdevDecoder, DeviceRangeReplacesConfiguredRange) {
  EvdevDecoder d(gamepad());
  d.set_connected(true);
  d.set_axis_range(ABS_X, 0, 1023);
  d.apply(ev(EV_ABS, ABS_X, 1023));
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  EXPECT_NEAR(d.state().outputs[0], 1.0, 1e-9);
  d.set_axis_range(ABS_X, 5, 5);  // nonsense from a device: ignored
  d.apply(ev(EV_SYN, SYN_REPORT, 0));
  EXPECT_NEAR(d.state().outputs[0], 1.0, 1e-9);
}

template <typename Predicate>
bool wait_for(Predicate p, std::chrono::milliseconds timeout = std::chrono::milliseconds(3000)) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (p()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return p();
}

class FifoDevice {
 public:
  FifoDevice() {
    path_ = std::filesystem::temp_directory_path() / ("tendril-evdev-" + std::to_string(::getpid()));
    ::unlink(path_.c_str());
    if (::mkfifo(path_.c_str(), 0600) != 0) throw std::runtime_error("mkfifo failed");
  }
  ~FifoDevice() {
    unplug();
    ::unlink(path_.c_str());
  }
  const std::filesystem::path& path() const { return path_; }
  // Opening the write end blocks until the reader has the FIFO open, like a device node appearing.
  void plug() { fd_ = ::open(path_.c_str(), O_WRONLY); }
  void unplug() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }
  void send(const std::vector<input_event>& events) {
    const auto bytes = events.size() * sizeof(input_event);
    ASSERT_EQ(::write(fd_, events.data(), bytes), static_cast<ssize_t>(bytes));
  }

 private:
  std::filesystem::path path_;
  int fd_ = -1;
};

TEST(EvdevJoystick, ReadsRecordedEventsAndSurvivesUnplugAndReplug) {
  FifoDevice device;
  EvdevJoystickOptions options;
  options.device = device.path().string();
  options.mapping = gamepad();
  options.rescan_period = std::chrono::milliseconds(20);
  EvdevJoystick joystick(options);
  EXPECT_FALSE(joystick.state().connected);
  joystick.start();

  device.plug();
  ASSERT_TRUE(wait_for([&] { return joystick.state().connected; }));
  device.send({ev(EV_ABS, ABS_X, 32767), ev(EV_KEY, BTN_TR, 1), ev(EV_SYN, SYN_REPORT, 0)});
  ASSERT_TRUE(wait_for([&] { return joystick.state().deadman; }));
  EXPECT_NEAR(joystick.state().outputs[0], 1.0, 1e-4);

  // The reader sees hang-up and releases everything at once. (A FIFO can be reopened without a
  // writer, so it may count as connected again right after the rescan; the counters tell.)
  device.unplug();
  ASSERT_TRUE(wait_for([&] { return joystick.disconnects() >= 1; }));
  EXPECT_FALSE(joystick.state().deadman);
  EXPECT_EQ(joystick.state().outputs[0], 0.0);

  device.plug();  // found again on the next rescan
  ASSERT_TRUE(wait_for([&] { return joystick.connects() >= 2 && joystick.state().connected; }));
  device.send({ev(EV_ABS, ABS_Y, -32768), ev(EV_SYN, SYN_REPORT, 0)});
  ASSERT_TRUE(wait_for([&] { return joystick.state().outputs[1] > 0.99; }));
  EXPECT_FALSE(joystick.state().deadman);  // the old press did not survive the unplug
  joystick.stop();
  EXPECT_FALSE(joystick.state().connected);
}

TEST(EvdevJoystick, RefusesAnEmptyDevice) {
  EvdevJoystickOptions options;
  options.mapping = gamepad();
  EXPECT_THROW(EvdevJoystick{options}, JoystickConfigError);
}

}  // namespace
}  // namespace tendril::input
