#include "tendril/drivers/can/virtual_bus.hpp"

#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <climits>
#include <cstdint>
#include <ctime>
#include <stdexcept>

namespace tendril::can {
namespace {

// Waits while *word == expected, at most until `deadline` on CLOCK_MONOTONIC (the steady clock).
void futex_wait_until(std::atomic<std::uint32_t>& word, std::uint32_t expected,
                      Clock::time_point deadline) noexcept {
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(deadline.time_since_epoch()).count();
  timespec ts{static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)};
  // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC deadline.
  syscall(SYS_futex, reinterpret_cast<std::uint32_t*>(&word), FUTEX_WAIT_BITSET_PRIVATE, expected, &ts,
          nullptr, FUTEX_BITSET_MATCH_ANY);
}

void futex_wake_all(std::atomic<std::uint32_t>& word) noexcept {
  syscall(SYS_futex, reinterpret_cast<std::uint32_t*>(&word), FUTEX_WAKE_PRIVATE, INT_MAX, nullptr, nullptr,
          0);
}

static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t) &&
                  std::atomic<std::uint32_t>::is_always_lock_free,
              "the futex word must be a plain 32-bit integer");

}  // namespace

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
  // An eventcount instead of a condition variable, so that wake() needs no lock: every frame pushed
  // here and every wake() bumps `signal`; a receive() that found nothing sleeps on it with a futex
  // and is woken only when someone is waiting (`waiters`).
  std::atomic<std::uint32_t> signal{0};
  std::atomic<int> waiters{0};
  std::atomic<bool> woken{false};
  void signal_waiters() noexcept {
    signal.fetch_add(1, std::memory_order_seq_cst);
    if (waiters.load(std::memory_order_seq_cst) > 0) futex_wake_all(signal);
  }
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
      ep->signal_waiters();
    }
  }
  impl_->sent.fetch_add(1, std::memory_order_relaxed);
  return SendResult::ok;
}

std::optional<Frame> VirtualBusEndpoint::receive(std::chrono::nanoseconds timeout) noexcept {
  auto& im = *impl_;
  const auto deadline = Clock::now() + std::clamp(timeout, std::chrono::nanoseconds::zero(),
                                                  std::chrono::nanoseconds(std::chrono::hours(24)));
  for (;;) {
    const std::uint32_t seen = im.signal.load(std::memory_order_seq_cst);
    {
      std::unique_lock lock(im.bus->mutex);
      if (im.count > 0) {
        Frame f = im.pop_locked();
        lock.unlock();
        if (f.error) {
          im.error_frames.fetch_add(1, std::memory_order_relaxed);
        } else {
          im.received.fetch_add(1, std::memory_order_relaxed);
        }
        return f;
      }
    }
    if (im.woken.exchange(false, std::memory_order_acq_rel)) return std::nullopt;
    if (Clock::now() >= deadline) return std::nullopt;
    im.waiters.fetch_add(1, std::memory_order_seq_cst);
    futex_wait_until(im.signal, seen, deadline);  // returns at once if a frame or wake() came since `seen`
    im.waiters.fetch_sub(1, std::memory_order_seq_cst);
  }
}

void VirtualBusEndpoint::wake() noexcept {
  impl_->woken.store(true, std::memory_order_release);
  impl_->signal_waiters();
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
    ep->signal_waiters();
    return;
  }
  throw std::invalid_argument("VirtualBus '" + shared_->name + "': no endpoint named '" + endpoint_name +
                              "'");
}

}  // namespace tendril::can
