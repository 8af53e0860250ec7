#include "tendril/drivers/can/virtual_bus.hpp"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <stdexcept>

namespace tendril::can {

// One mutex per bus guards the endpoint list and every receive ring: the virtual bus is a
// simulation aid, so simplicity wins over contention here. Rings are preallocated at attach()
// so send() does not allocate.
struct VirtualBus::Shared {
  std::string name;
  std::uint32_t bitrate;
  std::size_t queue_capacity;
  std::mutex mutex;
  std::vector<VirtualBusEndpoint::Impl*> endpoints;  // guarded by mutex
};

struct VirtualBusEndpoint::Impl {
  std::shared_ptr<VirtualBus::Shared> bus;
  std::string name;
  std::condition_variable frame_arrived;
  // Ring buffer, guarded by bus->mutex.
  std::vector<Frame> ring;
  std::size_t head = 0;
  std::size_t count = 0;
  bool bus_off = false;  // guarded by bus->mutex
  std::atomic<BusState> state{BusState::error_active};
  std::atomic<std::uint64_t> sent{0}, received{0}, send_failures{0}, error_frames{0}, bus_off_events{0},
      overflows{0};

  // Caller holds bus->mutex.
  void push_locked(const Frame& f) noexcept {
    if (ring.empty()) return;
    if (count == ring.size()) {
      // Full: drop the oldest, like a controller FIFO overwriting on overrun.
      head = (head + 1) % ring.size();
      --count;
      overflows.fetch_add(1, std::memory_order_relaxed);
    }
    ring[(head + count) % ring.size()] = f;
    ++count;
  }
  Frame pop_locked() noexcept {
    Frame f = ring[head];
    head = (head + 1) % ring.size();
    --count;
    return f;
  }
};

VirtualBusEndpoint::VirtualBusEndpoint(std::shared_ptr<Impl> impl) : impl_(std::move(impl)) {}

VirtualBusEndpoint::~VirtualBusEndpoint() {
  std::lock_guard lock(impl_->bus->mutex);
  auto& eps = impl_->bus->endpoints;
  eps.erase(std::remove(eps.begin(), eps.end(), impl_.get()), eps.end());
}

SendResult VirtualBusEndpoint::send(const Frame& frame) noexcept {
  if (frame.len > 8) {
    impl_->send_failures.fetch_add(1, std::memory_order_relaxed);
    return SendResult::too_long;
  }
  Frame copy = frame;
  copy.error = false;  // only controllers produce error frames
  copy.timestamp = Clock::now();
  {
    std::lock_guard lock(impl_->bus->mutex);
    if (impl_->bus_off) {
      impl_->send_failures.fetch_add(1, std::memory_order_relaxed);
      return SendResult::bus_off;
    }
    for (auto* ep : impl_->bus->endpoints) {
      if (ep == impl_.get() || ep->bus_off) continue;  // no loop-back; a bus-off node hears nothing
      ep->push_locked(copy);
      ep->frame_arrived.notify_one();
    }
  }
  impl_->sent.fetch_add(1, std::memory_order_relaxed);
  return SendResult::ok;
}

std::optional<Frame> VirtualBusEndpoint::receive(std::chrono::nanoseconds timeout) noexcept {
  std::unique_lock lock(impl_->bus->mutex);
  if (impl_->count == 0 && timeout > std::chrono::nanoseconds::zero()) {
    impl_->frame_arrived.wait_for(lock, std::min(timeout, std::chrono::nanoseconds(std::chrono::hours(24))),
                                  [&] { return impl_->count > 0; });
  }
  if (impl_->count == 0) return std::nullopt;
  Frame f = impl_->pop_locked();
  lock.unlock();
  if (f.error) {
    impl_->error_frames.fetch_add(1, std::memory_order_relaxed);
  } else {
    impl_->received.fetch_add(1, std::memory_order_relaxed);
  }
  return f;
}

BusState VirtualBusEndpoint::state() const noexcept { return impl_->state.load(std::memory_order_relaxed); }

BusStatistics VirtualBusEndpoint::statistics() const noexcept {
  BusStatistics s;
  s.frames_sent = impl_->sent.load(std::memory_order_relaxed);
  s.frames_received = impl_->received.load(std::memory_order_relaxed);
  s.send_failures = impl_->send_failures.load(std::memory_order_relaxed);
  s.error_frames = impl_->error_frames.load(std::memory_order_relaxed);
  s.bus_off_events = impl_->bus_off_events.load(std::memory_order_relaxed);
  s.receive_overflows = impl_->overflows.load(std::memory_order_relaxed);
  return s;
}

std::string VirtualBusEndpoint::name() const { return impl_->bus->name + "/" + impl_->name; }

std::uint32_t VirtualBusEndpoint::bitrate() const noexcept { return impl_->bus->bitrate; }

std::size_t VirtualBusEndpoint::pending() const noexcept {
  std::lock_guard lock(impl_->bus->mutex);
  return impl_->count;
}

VirtualBus::VirtualBus(std::string name, std::uint32_t bitrate, std::size_t queue_capacity)
    : shared_(std::make_shared<Shared>()) {
  if (queue_capacity == 0)
    throw std::invalid_argument("VirtualBus '" + name + "': queue_capacity must be > 0");
  if (bitrate == 0) throw std::invalid_argument("VirtualBus '" + name + "': bitrate must be > 0");
  shared_->name = std::move(name);
  shared_->bitrate = bitrate;
  shared_->queue_capacity = queue_capacity;
}

VirtualBus::~VirtualBus() = default;

std::unique_ptr<VirtualBusEndpoint> VirtualBus::attach(std::string endpoint_name) {
  auto impl = std::make_shared<VirtualBusEndpoint::Impl>();
  impl->bus = shared_;
  impl->name = std::move(endpoint_name);
  impl->ring.resize(shared_->queue_capacity);
  std::lock_guard lock(shared_->mutex);
  for (auto* ep : shared_->endpoints) {
    if (ep->name == impl->name)
      throw std::invalid_argument("VirtualBus '" + shared_->name + "': an endpoint named '" + impl->name +
                                  "' is already attached");
  }
  shared_->endpoints.push_back(impl.get());
  return std::unique_ptr<VirtualBusEndpoint>(new VirtualBusEndpoint(std::move(impl)));
}

const std::string& VirtualBus::name() const noexcept { return shared_->name; }

std::uint32_t VirtualBus::bitrate() const noexcept { return shared_->bitrate; }

void VirtualBus::set_bus_off(const std::string& endpoint_name, bool bus_off) {
  std::lock_guard lock(shared_->mutex);
  for (auto* ep : shared_->endpoints) {
    if (ep->name != endpoint_name) continue;
    if (ep->bus_off == bus_off) return;
    ep->bus_off = bus_off;
    // The controller reports the change through an error frame, as SocketCAN does.
    Frame err;
    err.error = true;
    err.id = bus_off ? error_class::bus_off : error_class::restarted;
    err.len = 8;
    err.timestamp = Clock::now();
    if (bus_off) {
      // Entering bus-off discards what the controller had buffered.
      ep->head = 0;
      ep->count = 0;
      ep->bus_off_events.fetch_add(1, std::memory_order_relaxed);
      ep->state.store(BusState::bus_off, std::memory_order_relaxed);
    } else {
      ep->state.store(BusState::error_active, std::memory_order_relaxed);
    }
    ep->push_locked(err);
    ep->frame_arrived.notify_one();
    return;
  }
  throw std::invalid_argument("VirtualBus '" + shared_->name + "': no endpoint named '" + endpoint_name +
                              "'");
}

}  // namespace tendril::can
