// SafetyEventLog: a fixed-size, lock-free ring of safety events. One producer (the control thread)
// pushes without allocating or waiting; when full, the oldest events are overwritten. One consumer
// drains new events in order; any thread may copy the newest events (newest first) for display.
// Each slot is a small seqlock, so a reader never sees a half-written event.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>

#include "tendril/safety/safety_types.hpp"

namespace tendril::safety {

struct SafetyEvent {
  std::uint64_t sequence = 0;  // 0, 1, 2, … in push order
  double time = 0.0;           // monotonic seconds, as given by the caller
  EventKind kind = EventKind::kTransition;
  FaultCode code = FaultCode::kNone;
  OperatingState from = OperatingState::kDisabled;
  OperatingState to = OperatingState::kDisabled;
  std::int32_t joint = -1;          // -1: not about one joint
  char text[kSafetyTextSize] = {};  // short message for a person, NUL-terminated
};

class SafetyEventLog {
 public:
  static constexpr std::size_t kCapacity = 256;

  // Producer only. Fills in the sequence number and returns it.
  std::uint64_t push(const SafetyEvent& event) noexcept;

  // Consumer only: hands every event pushed since the last drain to callback, oldest first, and
  // returns how many were delivered. Events overwritten before they could be read are counted in lost().
  template <typename Callback>
  std::size_t drain(Callback&& callback) {
    const std::uint64_t head = head_.load(std::memory_order_acquire);
    if (head - drain_cursor_ > kCapacity) {
      lost_.fetch_add(head - kCapacity - drain_cursor_, std::memory_order_relaxed);
      drain_cursor_ = head - kCapacity;
    }
    std::size_t delivered = 0;
    SafetyEvent event;
    for (; drain_cursor_ < head; ++drain_cursor_) {
      if (read(drain_cursor_, event)) {
        callback(static_cast<const SafetyEvent&>(event));
        ++delivered;
      } else {
        lost_.fetch_add(1, std::memory_order_relaxed);
      }
    }
    return delivered;
  }

  // Any thread: copies up to out.size() of the newest events, newest first; returns the count.
  std::size_t copy_newest_first(std::span<SafetyEvent> out) const noexcept;

  std::uint64_t pushed() const noexcept { return head_.load(std::memory_order_acquire); }
  std::uint64_t lost() const noexcept { return lost_.load(std::memory_order_relaxed); }

 private:
  static constexpr std::size_t kWords = (sizeof(SafetyEvent) + 7) / 8;
  struct Slot {
    std::atomic<std::uint64_t> seq{0};  // 2·index + 1 while writing, 2·index + 2 when complete
    std::array<std::atomic<std::uint64_t>, kWords> words{};
  };

  // Reads event `index` if it is still in its slot and complete.
  bool read(std::uint64_t index, SafetyEvent& out) const noexcept;

  std::array<Slot, kCapacity> slots_{};
  std::atomic<std::uint64_t> head_{0};  // number of events pushed
  std::atomic<std::uint64_t> lost_{0};
  std::uint64_t drain_cursor_ = 0;
};

}  // namespace tendril::safety
