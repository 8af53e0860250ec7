// LatestValue<T>: a single-writer, multi-reader seqlock slot for trivially copyable T.
// The writer never waits; readers retry while a write is in progress. Used to hand data between
// the real-time thread and the bus, simulation and server threads without locks or allocation.
#pragma once

#include <atomic>
#include <cstring>
#include <type_traits>

namespace tendril::hardware {

template <typename T>
class LatestValue {
  static_assert(std::is_trivially_copyable_v<T>, "LatestValue holds trivially copyable data only");

 public:
  LatestValue() = default;
  explicit LatestValue(const T& initial) { store(initial); }

  void store(const T& value) noexcept {
    const auto s = seq_.load(std::memory_order_relaxed);
    seq_.store(s + 1, std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_release);
    copy_in(value);
    std::atomic_thread_fence(std::memory_order_release);
    seq_.store(s + 2, std::memory_order_release);
  }

  T load() const noexcept {
    T out;
    for (;;) {
      const auto s1 = seq_.load(std::memory_order_acquire);
      if (s1 & 1U) continue;
      copy_out(out);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (seq_.load(std::memory_order_relaxed) == s1) return out;
    }
  }

  // Number of completed stores; lets a reader tell whether anything new arrived.
  std::uint64_t version() const noexcept { return seq_.load(std::memory_order_acquire) / 2; }

 private:
  // Byte-wise copies through atomic_ref keep the seqlock free of data races in the C++ model.
  void copy_in(const T& v) noexcept {
    const auto* src = reinterpret_cast<const unsigned char*>(&v);
    for (std::size_t i = 0; i < sizeof(T); ++i)
      // Padding bytes of T are copied as they are, as memcpy would.
      // NOLINTNEXTLINE(clang-analyzer-core.CallAndMessage)
      std::atomic_ref<unsigned char>(bytes_[i]).store(src[i], std::memory_order_relaxed);
  }
  void copy_out(T& v) const noexcept {
    auto* dst = reinterpret_cast<unsigned char*>(&v);
    for (std::size_t i = 0; i < sizeof(T); ++i)
      dst[i] = std::atomic_ref<unsigned char>(const_cast<unsigned char&>(bytes_[i]))
                   .load(std::memory_order_relaxed);
  }

  std::atomic<std::uint64_t> seq_{0};
  alignas(T) unsigned char bytes_[sizeof(T)]{};
};

}  // namespace tendril::hardware
