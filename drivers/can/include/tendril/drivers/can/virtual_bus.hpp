// VirtualBus: an in-process CAN bus. Every frame sent by one endpoint reaches every other endpoint
// (not the sender, like a real controller without loop-back), in send order, timestamped.
#pragma once

#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "tendril/drivers/can/bus.hpp"

namespace tendril::can {

class VirtualBus;

// An endpoint of a VirtualBus; behaves like one controller on the wire.
class VirtualBusEndpoint final : public Bus {
 public:
  ~VirtualBusEndpoint() override;
  SendResult send(const Frame& frame) noexcept override;
  std::optional<Frame> receive(std::chrono::nanoseconds timeout) noexcept override;
  void wake() noexcept override;
  BusState state() const noexcept override;
  BusStatistics statistics() const noexcept override;
  std::string name() const override;
  std::uint32_t bitrate() const noexcept override;
  // Frames waiting in this endpoint's receive queue.
  std::size_t pending() const noexcept;

 private:
  friend class VirtualBus;
  struct Impl;
  explicit VirtualBusEndpoint(std::shared_ptr<Impl> impl);
  std::shared_ptr<Impl> impl_;
};

class VirtualBus {
 public:
  // queue_capacity: frames each endpoint buffers before the oldest are dropped (counted as
  // receive overflow), like a controller's RX FIFO.
  explicit VirtualBus(std::string name, std::uint32_t bitrate = 1'000'000, std::size_t queue_capacity = 4096);
  ~VirtualBus();
  VirtualBus(const VirtualBus&) = delete;
  VirtualBus& operator=(const VirtualBus&) = delete;

  std::unique_ptr<VirtualBusEndpoint> attach(std::string endpoint_name);
  const std::string& name() const noexcept;
  std::uint32_t bitrate() const noexcept;
  // Test hook for failure injection: a bus-off controller. Frames sent by a bus-off endpoint fail.
  void set_bus_off(const std::string& endpoint_name, bool bus_off);

  struct Shared;

 private:
  std::shared_ptr<Shared> shared_;
};

}  // namespace tendril::can
