// LatestValue<T>: a single-writer, multi-reader slot for trivially copyable T that hands data between
// the real-time thread and the bus, simulation and server threads without locks or allocation.
//
// Two seqlock buffers written in turn, readers pointed at the last complete one. A store fills the
// buffer readers are not pointed at, then points them at it; a reader that finds its buffer being
// rewritten (the writer has moved on twice) looks again where the pointer now is. So a reader never
// waits for a writer that was preempted mid-store: with one buffer it spun until that writer ran again,
// and a real-time reader that had preempted a normal-priority writer on its own CPU spun for tens of
// ms on a loaded machine (the control thread over the SIMULATED limb's surface motion: the loop lost
// 72–117 ms, the arm's watchdog fired). The writer never waits; a reader retries only while stores
// complete under it.
#pragma once

#include <atomic>
#include <cstdint>
#include <type_traits>

namespace tendril::hardware {

template <typename T>
struct LatestValueTestAccess;  // defined by the tests only: a store stopped half way

template <typename T>
class LatestValue {
  static_assert(std::is_trivially_copyable_v<T>, "LatestValue holds trivially copyable data only");

 public:
  LatestValue() = default;
  explicit LatestValue(const T& initial) { store(initial); }

  void store(const T& value) noexcept { end_store(begin_store(value)); }

  T load() const noexcept {
    T out;
    for (;;) {
      if (buffers_[latest_.load(std::memory_order_acquire)].try_read(out)) return out;
    }
  }

  // Number of completed stores; lets a reader tell whether anything new arrived.
  std::uint64_t version() const noexcept { return stores_.load(std::memory_order_acquire); }

 private:
  friend struct LatestValueTestAccess<T>;

  // A store in two halves (the tests stop between them, as a preemption would): fill the buffer
  // readers are not pointed at, then point them at it.
  int begin_store(const T& value) noexcept {
    const int next = 1 - latest_.load(std::memory_order_relaxed);  // this thread is the only writer
    buffers_[next].begin_write(value);
    return next;
  }
  void end_store(int next) noexcept {
    buffers_[next].end_write();
    latest_.store(next, std::memory_order_release);
    stores_.fetch_add(1, std::memory_order_release);
  }

  class Buffer {
   public:
    void begin_write(const T& v) noexcept {
      seq_.store(seq_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_release);
      // Byte-wise copies through atomic_ref keep the seqlock free of data races in the C++ model.
      const auto* src = reinterpret_cast<const unsigned char*>(&v);
      for (std::size_t i = 0; i < sizeof(T); ++i)
        // Padding bytes of T are copied as they are, as memcpy would.
        // NOLINTNEXTLINE(clang-analyzer-core.CallAndMessage)
        std::atomic_ref<unsigned char>(bytes_[i]).store(src[i], std::memory_order_relaxed);
    }
    void end_write() noexcept {
      std::atomic_thread_fence(std::memory_order_release);
      seq_.store(seq_.load(std::memory_order_relaxed) + 1, std::memory_order_release);
    }
    // False when a write was under way or came during the copy.
    bool try_read(T& out) const noexcept {
      const auto s1 = seq_.load(std::memory_order_acquire);
      if (s1 & 1U) return false;
      auto* dst = reinterpret_cast<unsigned char*>(&out);
      for (std::size_t i = 0; i < sizeof(T); ++i)
        dst[i] = std::atomic_ref<unsigned char>(const_cast<unsigned char&>(bytes_[i]))
                     .load(std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_acquire);
      return seq_.load(std::memory_order_relaxed) == s1;
    }

   private:
    std::atomic<std::uint64_t> seq_{0};
    alignas(T) unsigned char bytes_[sizeof(T)]{};
  };

  Buffer buffers_[2];
  std::atomic<int> latest_{0};
  std::atomic<std::uint64_t> stores_{0};
};

}  // namespace tendril::hardware
