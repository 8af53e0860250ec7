#include "tendril/drivers/can/socketcan_bus.hpp"

#include <fcntl.h>
#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>

namespace tendril::can {
namespace {

std::string errno_text(int err) {
  return std::string(std::strerror(err)) + " (errno " + std::to_string(err) + ")";
}

}  // namespace

BusState bus_state_after_error_frame(std::uint32_t error_class, const std::array<std::uint8_t, 8>& data,
                                     BusState current) noexcept {
  if (error_class & CAN_ERR_BUSOFF) return BusState::bus_off;
  BusState next = current;
  if (error_class & CAN_ERR_RESTARTED) next = BusState::error_active;
  if (error_class & CAN_ERR_CRTL) {
    const std::uint8_t bits = data[1];
    if (bits & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) {
      next = BusState::error_passive;
    } else if (bits & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING)) {
      next = BusState::error_warning;
    } else if (bits & CAN_ERR_CRTL_ACTIVE) {
      next = BusState::error_active;
    }
  }
  return next;
}

SocketCanBus::SocketCanBus(const std::string& interface, std::uint32_t bitrate)
    : interface_(interface), bitrate_(bitrate) {
  if (interface.empty() || interface.size() >= IFNAMSIZ)
    throw CanSetupError("SocketCAN: interface name '" + interface + "' is invalid (1.." +
                        std::to_string(IFNAMSIZ - 1) + " characters)");
  if (bitrate == 0) throw CanSetupError("SocketCAN " + interface + ": bitrate must be > 0");

  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) {
    const int err = errno;
    if (err == EAFNOSUPPORT || err == EPROTONOSUPPORT)
      throw CanSetupError("SocketCAN " + interface +
                          ": this kernel has no CAN support (AF_CAN socket failed: " + errno_text(err) +
                          "); load the can and can-raw modules (modprobe can can-raw) or use a virtual bus");
    throw CanSetupError("SocketCAN " + interface + ": cannot create a CAN_RAW socket: " + errno_text(err));
  }
  auto fail = [&](const std::string& what) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    throw CanSetupError("SocketCAN " + interface + ": " + what + ": " + errno_text(err));
  };

  const unsigned index = ::if_nametoindex(interface.c_str());
  if (index == 0)
    fail("no such network interface (is it created and up? e.g. 'ip link add dev vcan0 type vcan')");

  // Error frames we want to see: bus-off, controller state changes, protocol violations, restarts
  // and TX timeouts. Bus-error flooding (CAN_ERR_BUSERROR) is left out on purpose.
  can_err_mask_t err_mask =
      CAN_ERR_BUSOFF | CAN_ERR_CRTL | CAN_ERR_PROT | CAN_ERR_RESTARTED | CAN_ERR_TX_TIMEOUT;
  if (::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask) != 0)
    fail("cannot set the error filter");

  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(index);
  if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0)
    fail("cannot bind the CAN_RAW socket");

  const int flags = ::fcntl(fd_, F_GETFL, 0);
  if (flags < 0 || ::fcntl(fd_, F_SETFL, flags | O_NONBLOCK) != 0)
    fail("cannot make the socket non-blocking");
  wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (wake_fd_ < 0) fail("cannot create the eventfd that wakes a waiting receive");
}

SocketCanBus::~SocketCanBus() {
  if (fd_ >= 0) ::close(fd_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void SocketCanBus::wake() noexcept {
  const std::uint64_t one = 1;
  // Non-blocking; fails only when the counter is about to overflow, which still leaves it readable.
  [[maybe_unused]] const ssize_t n = ::write(wake_fd_, &one, sizeof one);
}

SendResult SocketCanBus::send(const Frame& frame) noexcept {
  if (frame.len > 8) {
    send_failures_.fetch_add(1, std::memory_order_relaxed);
    return SendResult::too_long;
  }
  if (fd_ < 0) return SendResult::closed;
  can_frame cf{};
  cf.can_id = frame.extended ? ((frame.id & CAN_EFF_MASK) | CAN_EFF_FLAG) : (frame.id & CAN_SFF_MASK);
  if (frame.rtr) cf.can_id |= CAN_RTR_FLAG;
  cf.can_dlc = frame.len;
  std::memcpy(cf.data, frame.data.data(), frame.len);
  for (;;) {
    const ssize_t n = ::write(fd_, &cf, sizeof cf);
    if (n == static_cast<ssize_t>(sizeof cf)) {
      sent_.fetch_add(1, std::memory_order_relaxed);
      return SendResult::ok;
    }
    const int err = errno;
    if (n < 0 && err == EINTR) continue;
    send_failures_.fetch_add(1, std::memory_order_relaxed);
    if (n < 0 && (err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS)) return SendResult::would_block;
    if (n < 0 && (err == ENETDOWN || err == ENETUNREACH))
      // The interface goes down when the controller is bus-off and no auto-restart is set.
      return state_.load(std::memory_order_relaxed) == BusState::bus_off ? SendResult::bus_off
                                                                         : SendResult::io_error;
    if (n < 0 && err == EBADF) return SendResult::closed;
    return SendResult::io_error;
  }
}

std::optional<Frame> SocketCanBus::receive(std::chrono::nanoseconds timeout) noexcept {
  if (fd_ < 0) return std::nullopt;
  // Cap so that a caller's nanoseconds::max() cannot overflow the deadline.
  const auto deadline = Clock::now() + std::min(timeout, std::chrono::nanoseconds(std::chrono::hours(24)));
  for (;;) {
    can_frame cf{};
    const ssize_t n = ::read(fd_, &cf, sizeof cf);
    if (n == static_cast<ssize_t>(sizeof cf)) {
      Frame f;
      f.timestamp = Clock::now();
      f.len = cf.can_dlc > 8 ? 8 : cf.can_dlc;
      std::memcpy(f.data.data(), cf.data, f.len);
      if (cf.can_id & CAN_ERR_FLAG) {
        f.error = true;
        f.id = cf.can_id & CAN_ERR_MASK;
        error_frames_.fetch_add(1, std::memory_order_relaxed);
        const BusState before = state_.load(std::memory_order_relaxed);
        const BusState after = bus_state_after_error_frame(f.id, f.data, before);
        state_.store(after, std::memory_order_relaxed);
        if (after == BusState::bus_off && before != BusState::bus_off)
          bus_off_.fetch_add(1, std::memory_order_relaxed);
        return f;
      }
      f.extended = (cf.can_id & CAN_EFF_FLAG) != 0;
      f.rtr = (cf.can_id & CAN_RTR_FLAG) != 0;
      f.id = f.extended ? (cf.can_id & CAN_EFF_MASK) : (cf.can_id & CAN_SFF_MASK);
      received_.fetch_add(1, std::memory_order_relaxed);
      return f;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK)) return std::nullopt;  // short read / error

    // No frame: a pending wake() ends the call (and is consumed), else wait for either.
    std::uint64_t wakes = 0;
    if (::read(wake_fd_, &wakes, sizeof wakes) == static_cast<ssize_t>(sizeof wakes)) return std::nullopt;
    const auto remaining = deadline - Clock::now();
    if (remaining <= std::chrono::nanoseconds::zero()) return std::nullopt;
    const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(remaining).count();
    timespec ts{static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)};
    std::array<pollfd, 2> pfd{pollfd{fd_, POLLIN, 0}, pollfd{wake_fd_, POLLIN, 0}};
    const int r = ::ppoll(pfd.data(), pfd.size(), &ts, nullptr);
    if (r < 0 && errno != EINTR) return std::nullopt;
    if (r == 0) return std::nullopt;
  }
}

BusState SocketCanBus::state() const noexcept { return state_.load(std::memory_order_relaxed); }

BusStatistics SocketCanBus::statistics() const noexcept {
  BusStatistics s;
  s.frames_sent = sent_.load(std::memory_order_relaxed);
  s.frames_received = received_.load(std::memory_order_relaxed);
  s.send_failures = send_failures_.load(std::memory_order_relaxed);
  s.error_frames = error_frames_.load(std::memory_order_relaxed);
  s.bus_off_events = bus_off_.load(std::memory_order_relaxed);
  return s;
}

std::string SocketCanBus::name() const { return interface_; }

std::uint32_t SocketCanBus::bitrate() const noexcept { return bitrate_; }

}  // namespace tendril::can
