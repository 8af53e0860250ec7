#include "tendril/safety/safety_event_log.hpp"

#include <cstring>
#include <type_traits>

namespace tendril::safety {

static_assert(std::is_trivially_copyable_v<SafetyEvent>, "events are copied word by word");

std::uint64_t SafetyEventLog::push(const SafetyEvent& event) noexcept {
  const std::uint64_t index = head_.load(std::memory_order_relaxed);
  Slot& slot = slots_[index % kCapacity];
  std::array<std::uint64_t, kWords> words{};
  SafetyEvent stamped = event;
  stamped.sequence = index;
  stamped.text[sizeof(stamped.text) - 1] = '\0';
  std::memcpy(words.data(), &stamped, sizeof(SafetyEvent));

  slot.seq.store(2 * index + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  for (std::size_t w = 0; w < kWords; ++w) slot.words[w].store(words[w], std::memory_order_relaxed);
  slot.seq.store(2 * index + 2, std::memory_order_release);
  head_.store(index + 1, std::memory_order_release);
  return index;
}

bool SafetyEventLog::read(std::uint64_t index, SafetyEvent& out) const noexcept {
  const Slot& slot = slots_[index % kCapacity];
  const std::uint64_t before = slot.seq.load(std::memory_order_acquire);
  if (before != 2 * index + 2) return false;  // overwritten or being written
  std::array<std::uint64_t, kWords> words{};
  for (std::size_t w = 0; w < kWords; ++w) words[w] = slot.words[w].load(std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_acquire);
  if (slot.seq.load(std::memory_order_relaxed) != before) return false;
  std::memcpy(static_cast<void*>(&out), words.data(), sizeof(SafetyEvent));
  return true;
}

std::size_t SafetyEventLog::copy_newest_first(std::span<SafetyEvent> out) const noexcept {
  const std::uint64_t head = head_.load(std::memory_order_acquire);
  std::size_t n = 0;
  for (std::uint64_t k = 0; k < head && k < kCapacity && n < out.size(); ++k)
    if (read(head - 1 - k, out[n])) ++n;
  return n;
}

}  // namespace tendril::safety
