#include "tendril/drivers/input/evdev_joystick.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <vector>

namespace tendril::input {
namespace {

std::int64_t monotonic_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

bool test_bit(const std::vector<unsigned long>& bits, int bit) {
  constexpr int kBitsPerLong = static_cast<int>(sizeof(unsigned long) * 8);
  return ((bits[static_cast<std::size_t>(bit / kBitsPerLong)] >> (bit % kBitsPerLong)) & 1UL) != 0;
}

}  // namespace

EvdevDecoder::EvdevDecoder(JoystickMapping mapping) : mapping_(std::move(mapping)) {
  mapping_.validate();
  for (std::size_t i = 0; i < mapping_.axes.size(); ++i) {
    const auto& axis = mapping_.axes[i];
    raw_[i] = 0.5 * (axis.minimum + axis.maximum);
  }
}

void EvdevDecoder::set_axis_range(int code, double minimum, double maximum) noexcept {
  if (!(maximum > minimum)) return;  // a device reporting an empty range keeps the configured one
  for (auto& axis : mapping_.axes) {
    if (axis.code == code) {
      axis.minimum = minimum;
      axis.maximum = maximum;
    }
  }
}

void EvdevDecoder::set_axis_raw(int code, double raw) noexcept {
  for (std::size_t i = 0; i < mapping_.axes.size(); ++i) {
    if (mapping_.axes[i].code == code) raw_[i] = raw;
  }
}

void EvdevDecoder::set_key(int code, bool pressed) noexcept {
  if (code == mapping_.deadman_code) deadman_held_ = pressed;
  for (std::size_t i = 0; i < mapping_.buttons.size(); ++i) {
    if (mapping_.buttons[i].code != code) continue;
    const std::uint32_t bit = 1U << i;
    keys_ = pressed ? (keys_ | bit) : (keys_ & ~bit);
  }
}

void EvdevDecoder::set_connected(bool connected) noexcept {
  state_.connected = connected;
  if (!connected) {
    // A vanished device must not leave the robot moving: everything reads as released.
    for (std::size_t i = 0; i < mapping_.axes.size(); ++i) {
      raw_[i] = 0.5 * (mapping_.axes[i].minimum + mapping_.axes[i].maximum);
    }
    keys_ = 0;
    deadman_held_ = false;
    dropping_ = false;
  }
  recompute();
}

void EvdevDecoder::recompute() noexcept {
  state_.outputs.fill(0.0);
  if (state_.connected) {
    for (std::size_t i = 0; i < mapping_.axes.size(); ++i)
      state_.outputs[i] = normalise_axis(mapping_.axes[i], raw_[i]);
  }
  state_.buttons = state_.connected ? keys_ : 0U;
  // With no deadman configured, presence is implied by a connected device.
  state_.deadman = state_.connected && (mapping_.deadman_code < 0 || deadman_held_);
}

void EvdevDecoder::publish(std::int64_t stamp_ns) noexcept {
  recompute();
  state_.stamp_ns = stamp_ns;
  ++state_.reports;
}

bool EvdevDecoder::apply(const input_event& event) noexcept {
  if (event.type == EV_SYN) {
    if (event.code == SYN_DROPPED) {
      dropping_ = true;
      return false;
    }
    if (event.code != SYN_REPORT) return false;
    if (dropping_) {
      // The kernel's buffer overflowed: this report is incomplete. The owner resynchronises.
      dropping_ = false;
      return false;
    }
    publish(static_cast<std::int64_t>(event.input_event_sec) * 1'000'000'000 +
            static_cast<std::int64_t>(event.input_event_usec) * 1000);
    return true;
  }
  if (dropping_) return false;
  if (event.type == EV_ABS) set_axis_raw(event.code, event.value);
  if (event.type == EV_KEY) set_key(event.code, event.value != 0);  // 1 press, 2 autorepeat, 0 release
  return false;
}

EvdevJoystick::EvdevJoystick(EvdevJoystickOptions options) : options_(std::move(options)) {
  options_.mapping.validate();
  if (options_.device.empty()) {
    throw JoystickConfigError(
        "evdev joystick: device is empty; give /dev/input/eventN or name:<part of its name>");
  }
  if (options_.rescan_period.count() <= 0)
    throw JoystickConfigError("evdev joystick: rescan_period must be positive");
  slot_.store(JoystickState{});
}

EvdevJoystick::~EvdevJoystick() { stop(); }

void EvdevJoystick::start() {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this] { run(); });
}

void EvdevJoystick::stop() {
  running_ = false;
  if (thread_.joinable()) thread_.join();
}

int EvdevJoystick::open_device(std::string& name_out) const {
  const std::string prefix = "name:";
  std::vector<std::string> candidates;
  std::string wanted_name;
  if (options_.device.rfind(prefix, 0) == 0) {
    wanted_name = options_.device.substr(prefix.size());
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(options_.input_directory, ec)) {
      const auto file = entry.path().filename().string();
      if (file.rfind("event", 0) == 0) candidates.push_back(entry.path().string());
    }
    std::sort(candidates.begin(), candidates.end());
  } else {
    candidates.push_back(options_.device);
  }
  for (const auto& path : candidates) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) continue;
    char name[256] = {};
    if (::ioctl(fd, EVIOCGNAME(sizeof(name) - 1), name) < 0) name[0] = '\0';
    if (!wanted_name.empty() && std::string(name).find(wanted_name) == std::string::npos) {
      ::close(fd);
      continue;
    }
    name_out = name;
    return fd;
  }
  return -1;
}

void EvdevJoystick::run() {
  EvdevDecoder decoder(options_.mapping);
  int fd = -1;
  auto next_scan = std::chrono::steady_clock::now();
  std::array<input_event, 64> events{};

  // Reads the device's current axes and keys (after opening and after SYN_DROPPED).
  auto resync = [&] {
    for (const auto& axis : options_.mapping.axes) {
      input_absinfo info{};
      if (::ioctl(fd, EVIOCGABS(axis.code), &info) == 0) {
        decoder.set_axis_range(axis.code, info.minimum, info.maximum);
        decoder.set_axis_raw(axis.code, info.value);
      }
    }
    std::vector<unsigned long> keys((KEY_MAX + 1 + sizeof(unsigned long) * 8 - 1) /
                                    (sizeof(unsigned long) * 8));
    if (::ioctl(fd, EVIOCGKEY(keys.size() * sizeof(unsigned long)), keys.data()) >= 0) {
      for (const auto& button : options_.mapping.buttons) {
        if (button.code >= 0 && button.code <= KEY_MAX)
          decoder.set_key(button.code, test_bit(keys, button.code));
      }
      const int deadman = options_.mapping.deadman_code;
      if (deadman >= 0 && deadman <= KEY_MAX) decoder.set_key(deadman, test_bit(keys, deadman));
    }
    decoder.publish(monotonic_ns());
    slot_.store(decoder.state());
  };
  auto disconnect = [&] {
    if (fd >= 0) ::close(fd);
    fd = -1;
    decoder.set_connected(false);
    decoder.publish(monotonic_ns());
    slot_.store(decoder.state());
    ++disconnects_;
  };

  while (running_.load()) {
    if (fd < 0) {
      const auto now = std::chrono::steady_clock::now();
      if (now < next_scan) {
        std::this_thread::sleep_for(
            std::min<std::chrono::steady_clock::duration>(next_scan - now, std::chrono::milliseconds(50)));
        continue;
      }
      next_scan = now + options_.rescan_period;
      std::string name;
      fd = open_device(name);
      if (fd < 0) continue;
      decoder.set_connected(true);
      ++connects_;
      resync();
      continue;
    }
    pollfd pfd{fd, POLLIN, 0};
    const int ready = ::poll(&pfd, 1, 50);
    if (ready < 0 && errno != EINTR) {
      disconnect();
      continue;
    }
    if (ready <= 0) continue;
    if ((pfd.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
      disconnect();
      continue;
    }
    const ssize_t n = ::read(fd, events.data(), sizeof(events));
    if (n < 0) {
      if (errno == EAGAIN || errno == EINTR) continue;
      disconnect();  // ENODEV: unplugged
      continue;
    }
    if (n == 0) {
      disconnect();
      continue;
    }
    const auto count = static_cast<std::size_t>(n) / sizeof(input_event);
    for (std::size_t i = 0; i < count; ++i) {
      const bool dropped = events[i].type == EV_SYN && events[i].code == SYN_DROPPED;
      if (decoder.apply(events[i])) slot_.store(decoder.state());
      if (dropped) resync();
    }
  }
  if (fd >= 0) ::close(fd);
  decoder.set_connected(false);
  slot_.store(decoder.state());
}

}  // namespace tendril::input
