// Linux joysticks and gamepads through evdev (/dev/input/event*).
//
// EvdevDecoder turns the kernel's input_event stream into JoystickState reports (one per
// SYN_REPORT), so it can be tested with recorded events. EvdevJoystick owns a reader thread (never
// the control thread) that opens the device, decodes it, publishes the newest state in a lock-free
// slot, and survives hot-plug: when the device goes away the state turns "disconnected" (zero
// outputs, deadman released) at once, and the device is looked for again every rescan period.
#pragma once

#include <linux/input.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>
#include <thread>

#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/input/joystick.hpp"

namespace tendril::input {

class EvdevDecoder {
 public:
  explicit EvdevDecoder(JoystickMapping mapping);  // throws JoystickConfigError

  // The device's own range for an axis (EVIOCGABS), which replaces the configured one.
  void set_axis_range(int code, double minimum, double maximum) noexcept;
  // Applies one event. Returns true when it completed a report (SYN_REPORT); `state()` then holds it.
  // After SYN_DROPPED the events up to the next SYN_REPORT are incomplete and are ignored.
  bool apply(const input_event& event) noexcept;
  // Sets an axis/button directly (used to resynchronise from EVIOCGABS/EVIOCGKEY after SYN_DROPPED).
  void set_axis_raw(int code, double raw) noexcept;
  void set_key(int code, bool pressed) noexcept;
  // Starts a fresh report from the current raw values (after a resync).
  void publish(std::int64_t stamp_ns) noexcept;

  const JoystickState& state() const noexcept { return state_; }
  const JoystickMapping& mapping() const noexcept { return mapping_; }
  void set_connected(bool connected) noexcept;

 private:
  void recompute() noexcept;

  JoystickMapping mapping_;
  std::array<double, kMaxJoystickOutputs> raw_{};
  std::uint32_t keys_ = 0;  // bit i = buttons[i]
  bool deadman_held_ = false;
  bool dropping_ = false;
  JoystickState state_{};
};

struct EvdevJoystickOptions {
  // "/dev/input/event3", or "name:<substring>" to take the first device whose name contains it
  // (EVIOCGNAME), which survives re-enumeration after hot-plug.
  std::string device;
  JoystickMapping mapping;
  std::chrono::milliseconds rescan_period{500};
  std::string input_directory = "/dev/input";  // where "name:" looks for event* nodes
};

class EvdevJoystick {
 public:
  explicit EvdevJoystick(EvdevJoystickOptions options);  // throws JoystickConfigError
  ~EvdevJoystick();
  EvdevJoystick(const EvdevJoystick&) = delete;
  EvdevJoystick& operator=(const EvdevJoystick&) = delete;

  void start();
  void stop();

  // Newest report; wait-free, callable from the control thread.
  JoystickState state() const noexcept { return slot_.load(); }
  // How often the device appeared and went away (for metrics and tests).
  std::uint64_t connects() const noexcept { return connects_.load(); }
  std::uint64_t disconnects() const noexcept { return disconnects_.load(); }

 private:
  void run();
  int open_device(std::string& name_out) const;

  EvdevJoystickOptions options_;
  hardware::LatestValue<JoystickState> slot_;
  std::atomic<bool> running_{false};
  std::atomic<std::uint64_t> connects_{0};
  std::atomic<std::uint64_t> disconnects_{0};
  std::thread thread_;
};

}  // namespace tendril::input
