// PeriodicThread: runs a function at a fixed rate on its own thread with absolute deadlines
// (clock_nanosleep TIMER_ABSTIME on CLOCK_MONOTONIC), asking for SCHED_FIFO and mlockall and running
// without them when refused. Period jitter, overruns and lost time (how long the loop went without a
// cycle beyond one period) are measured every cycle, lock-free.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <string>
#include <thread>

namespace tendril::server {

// Lock-free histogram of microsecond values: 1 µs bins to 200 µs, then 100 µs bins to 20 ms.
class MicrosecondHistogram {
 public:
  void record(double us) noexcept;
  // q in [0, 1]; returns the upper edge of the bin holding that quantile (µs).
  double quantile(double q) const noexcept;
  double max() const noexcept {
    return static_cast<double>(max_ns_.load(std::memory_order_relaxed)) / 1000.0;
  }
  std::uint64_t count() const noexcept { return count_.load(std::memory_order_relaxed); }
  void reset() noexcept;

 private:
  static constexpr std::size_t kFine = 200, kCoarse = 199, kBins = kFine + kCoarse + 1;
  static std::size_t bin(double us) noexcept;
  static double upper_edge(std::size_t b) noexcept;
  std::array<std::atomic<std::uint64_t>, kBins> bins_{};
  std::atomic<std::uint64_t> count_{0};
  std::atomic<std::int64_t> max_ns_{0};
};

struct LoopStatistics {
  std::uint64_t cycles = 0;
  std::uint64_t overruns = 0;     // cycles whose work ran past the next deadline
  std::uint64_t late_cycles = 0;  // cycles that started a full period or more after the previous one
  double period_error_p50_us = 0, period_error_p99_us = 0, period_error_max_us = 0;
  double lost_max_us = 0;  // longest time without a cycle beyond one period
  // Cycles whose lost time (see CycleTiming::lost) was over 1, 5, 20 and 50 ms.
  std::uint64_t lost_over_1ms = 0, lost_over_5ms = 0, lost_over_20ms = 0, lost_over_50ms = 0;
  double work_p50_us = 0, work_p99_us = 0, work_max_us = 0;
  bool realtime_scheduling = false;  // SCHED_FIFO granted
  bool memory_locked = false;        // mlockall granted
  bool realtime_requested = false;   // SCHED_FIFO and mlockall were asked for
  int realtime_priority = 0;         // the SCHED_FIFO priority asked for
  // pthread_setschedparam's error when SCHED_FIFO was refused (EPERM: no CAP_SYS_NICE, or a cgroup
  // with no real-time budget, as a container's is by default); 0 when granted or not asked for.
  int realtime_error = 0;
};

// What a cycle learns about its own timing.
struct CycleTiming {
  std::chrono::steady_clock::time_point deadline;  // the absolute deadline this cycle was due at
  std::chrono::steady_clock::time_point woke;      // when it actually started
  // Time since the previous cycle started, beyond one period (0 for the first cycle): how long the
  // loop went without running. A stall of 25 ms at 1 kHz shows as 25 ms on the cycle after it.
  std::chrono::nanoseconds lost{0};
  bool previous_overrun = false;  // the previous cycle's work ran past this cycle's deadline
};

class PeriodicThread {
 public:
  // The cycle function must be real-time safe: no allocation, no locks, no blocking.
  using Cycle = std::function<void(const CycleTiming& timing)>;

  PeriodicThread() = default;
  ~PeriodicThread();
  PeriodicThread(const PeriodicThread&) = delete;
  PeriodicThread& operator=(const PeriodicThread&) = delete;

  // Returns once the thread has asked for (or not) real-time scheduling, so statistics() tells at
  // once whether it was granted.
  void start(std::string name, std::chrono::nanoseconds period, Cycle cycle, bool request_realtime,
             int priority = 80);
  void stop();
  bool running() const noexcept { return running_.load(); }
  LoopStatistics statistics() const noexcept;
  std::chrono::nanoseconds period() const noexcept { return period_; }

 private:
  void run();
  static void prefault_stack() noexcept;

  std::string name_;
  std::chrono::nanoseconds period_{1'000'000};
  Cycle cycle_;
  bool request_realtime_ = false;
  int priority_ = 80;
  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> cycles_{0}, overruns_{0}, late_cycles_{0};
  std::atomic<std::int64_t> lost_max_ns_{0};
  std::array<std::atomic<std::uint64_t>, 4> lost_over_{};  // over 1, 5, 20, 50 ms
  std::atomic<bool> realtime_{false}, locked_{false};
  std::atomic<int> realtime_error_{0};
  std::atomic<bool> realtime_decided_{false};  // the thread has asked for real-time scheduling, or not
  MicrosecondHistogram period_error_;
  MicrosecondHistogram work_;
};

}  // namespace tendril::server
