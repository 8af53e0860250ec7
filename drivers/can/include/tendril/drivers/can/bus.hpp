// The Bus interface: what the CANopen master and simulated nodes see of a CAN bus.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "tendril/drivers/can/frame.hpp"

namespace tendril::can {

// Counters every bus keeps; read from any thread.
struct BusStatistics {
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t send_failures = 0;
  std::uint64_t error_frames = 0;
  std::uint64_t bus_off_events = 0;
  std::uint64_t receive_overflows = 0;  // frames dropped because the receive queue was full
};

// One endpoint on a CAN bus. send() never blocks; receive() waits at most `timeout`
// (zero = poll). Error frames are delivered through receive() with Frame::error set.
// One thread sends and receives on an endpoint at a time; different endpoints are independent,
// except wake(), which any thread may call.
class Bus {
 public:
  virtual ~Bus() = default;
  virtual SendResult send(const Frame& frame) noexcept = 0;
  virtual std::optional<Frame> receive(std::chrono::nanoseconds timeout) noexcept = 0;
  // Makes a receive() waiting on this endpoint return at once (empty when no frame is queued); when
  // none is waiting, the next one does. Any thread; no lock, no allocation, never blocks: the
  // real-time thread rings it to hand the bus thread work that must not wait for its next wake-up
  // (a quick stop), so the bus thread can sleep until its next deadline instead of polling.
  virtual void wake() noexcept = 0;
  virtual BusState state() const noexcept = 0;
  virtual BusStatistics statistics() const noexcept = 0;
  virtual std::string name() const = 0;
  // Nominal bitrate in bit/s, used for bus-load accounting.
  virtual std::uint32_t bitrate() const noexcept = 0;
};

}  // namespace tendril::can
