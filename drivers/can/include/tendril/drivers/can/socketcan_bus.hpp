// SocketCanBus: a Linux SocketCAN CAN_RAW endpoint (can0, vcan0, ...).
#pragma once

#include <array>
#include <atomic>
#include <stdexcept>
#include <string>

#include "tendril/drivers/can/bus.hpp"

namespace tendril::can {

// Thrown at set-up when the interface cannot be opened (no AF_CAN, no such interface, ...).
class CanSetupError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The controller state after an error frame with class bits `error_class` (Frame::id of an error
// frame) and detail bytes `data` (data[1]: controller warning/passive/active bits), starting from
// `current`. Bus-off wins; a restart returns to error-active. Pure, so it is testable without CAN.
BusState bus_state_after_error_frame(std::uint32_t error_class, const std::array<std::uint8_t, 8>& data,
                                     BusState current) noexcept;

class SocketCanBus final : public Bus {
 public:
  // Opens CAN_RAW on `interface`, enables error frames (bus-off, controller, protocol), sets the
  // socket non-blocking. `bitrate` is only used for bus-load accounting (the kernel owns the link).
  explicit SocketCanBus(const std::string& interface, std::uint32_t bitrate = 1'000'000);
  ~SocketCanBus() override;
  SocketCanBus(const SocketCanBus&) = delete;
  SocketCanBus& operator=(const SocketCanBus&) = delete;

  SendResult send(const Frame& frame) noexcept override;
  std::optional<Frame> receive(std::chrono::nanoseconds timeout) noexcept override;
  void wake() noexcept override;  // through an eventfd polled next to the socket
  BusState state() const noexcept override;
  BusStatistics statistics() const noexcept override;
  std::string name() const override;
  std::uint32_t bitrate() const noexcept override;
  int native_handle() const noexcept { return fd_; }

 private:
  int fd_ = -1;
  int wake_fd_ = -1;  // eventfd: readable after wake()
  std::string interface_;
  std::uint32_t bitrate_;
  std::atomic<BusState> state_{BusState::error_active};
  std::atomic<std::uint64_t> sent_{0}, received_{0}, send_failures_{0}, error_frames_{0}, bus_off_{0};
};

}  // namespace tendril::can
