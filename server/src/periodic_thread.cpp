#include "tendril/server/periodic_thread.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <time.h>

#include <cerrno>
#include <cmath>

namespace tendril::server {

std::size_t MicrosecondHistogram::bin(double us) noexcept {
  if (!(us >= 0)) us = 0;
  if (us < kFine) return static_cast<std::size_t>(us);
  auto coarse = static_cast<std::size_t>((us - kFine) / 100.0);
  return coarse < kCoarse ? kFine + coarse : kBins - 1;
}

double MicrosecondHistogram::upper_edge(std::size_t b) noexcept {
  if (b < kFine) return static_cast<double>(b + 1);
  if (b < kFine + kCoarse) return kFine + 100.0 * static_cast<double>(b - kFine + 1);
  return INFINITY;
}

void MicrosecondHistogram::record(double us) noexcept {
  bins_[bin(us)].fetch_add(1, std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
  auto ns = static_cast<std::int64_t>(us * 1000.0);
  auto prev = max_ns_.load(std::memory_order_relaxed);
  while (ns > prev && !max_ns_.compare_exchange_weak(prev, ns, std::memory_order_relaxed)) {
  }
}

double MicrosecondHistogram::quantile(double q) const noexcept {
  const auto n = count();
  if (n == 0) return 0.0;
  const auto target = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(n)));
  std::uint64_t seen = 0;
  for (std::size_t b = 0; b < kBins; ++b) {
    seen += bins_[b].load(std::memory_order_relaxed);
    if (seen >= target && seen > 0) return std::min(upper_edge(b), max());
  }
  return max();
}

void MicrosecondHistogram::reset() noexcept {
  for (auto& b : bins_) b.store(0, std::memory_order_relaxed);
  count_.store(0);
  max_ns_.store(0);
}

PeriodicThread::~PeriodicThread() { stop(); }

void PeriodicThread::start(std::string name, std::chrono::nanoseconds period, Cycle cycle,
                           bool request_realtime, int priority) {
  stop();
  name_ = std::move(name);
  period_ = period;
  cycle_ = std::move(cycle);
  request_realtime_ = request_realtime;
  priority_ = priority;
  stop_.store(false);
  running_.store(true);
  realtime_decided_.store(false);
  thread_ = std::thread([this] { run(); });
  realtime_decided_.wait(false);
}

void PeriodicThread::stop() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
  running_.store(false);
}

void PeriodicThread::run() {
  pthread_setname_np(pthread_self(), name_.substr(0, 15).c_str());
  if (request_realtime_) {
    sched_param sp{};
    sp.sched_priority = priority_;
    const int refused = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    realtime_error_.store(refused);
    realtime_.store(refused == 0);
    // MCL_ONFAULT: pages are locked as they are first touched, not all at once. Locking every mapped
    // page (each thread's 8 MB stack, every allocator arena) made an idle server resident at
    // ~285 MB; what the real-time threads touch is locked just the same, and prefault_stack() below
    // touches their stacks before the first cycle.
    bool locked = mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0;
    if (!locked && errno == EINVAL) locked = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;  // kernel < 4.4
    locked_.store(locked);
    prefault_stack();
  }
  realtime_decided_.store(true);
  realtime_decided_.notify_all();
  using clock = std::chrono::steady_clock;
  // steady_clock is CLOCK_MONOTONIC on Linux, so its epoch matches clock_nanosleep's.
  auto deadline = clock::now() + period_;
  bool overrun = false;
  auto previous_wake = clock::time_point{};
  while (!stop_.load(std::memory_order_relaxed)) {
    const auto ns = deadline.time_since_epoch().count();
    timespec ts{static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const auto woke = clock::now();
    CycleTiming timing{deadline, woke, std::chrono::nanoseconds(0), overrun};
    if (previous_wake != clock::time_point{}) {
      const auto gap = woke - previous_wake;
      const double period_us = std::chrono::duration<double, std::micro>(gap).count();
      period_error_.record(std::abs(period_us - std::chrono::duration<double, std::micro>(period_).count()));
      if (gap > period_) {
        timing.lost = std::chrono::duration_cast<std::chrono::nanoseconds>(gap - period_);
        if (gap >= 2 * period_) late_cycles_.fetch_add(1, std::memory_order_relaxed);
        constexpr std::array<std::chrono::milliseconds, 4> kLostOver{
            std::chrono::milliseconds(1), std::chrono::milliseconds(5), std::chrono::milliseconds(20),
            std::chrono::milliseconds(50)};
        for (std::size_t k = 0; k < kLostOver.size(); ++k)
          if (timing.lost > kLostOver[k]) lost_over_[k].fetch_add(1, std::memory_order_relaxed);
        auto prev = lost_max_ns_.load(std::memory_order_relaxed);
        while (timing.lost.count() > prev &&
               !lost_max_ns_.compare_exchange_weak(prev, timing.lost.count(), std::memory_order_relaxed)) {
        }
      }
    }
    previous_wake = woke;
    cycle_(timing);
    const auto done = clock::now();
    work_.record(std::chrono::duration<double, std::micro>(done - woke).count());
    cycles_.fetch_add(1, std::memory_order_relaxed);
    deadline += period_;
    overrun = done > deadline;
    if (overrun) {
      overruns_.fetch_add(1, std::memory_order_relaxed);
      // Skip the missed cycles instead of bursting to catch up: a late controller must not run
      // several ticks back to back.
      while (deadline < done) deadline += period_;
    }
  }
}

void PeriodicThread::prefault_stack() noexcept {
  // Touch the stack a cycle may use, so that its pages are resident and locked before the first
  // deadline rather than faulted in on a cycle's time.
  constexpr std::size_t kStackPrefault = std::size_t{256} * 1024;
  volatile unsigned char stack[kStackPrefault];
  for (std::size_t i = 0; i < kStackPrefault; i += 4096) stack[i] = 0;
}

LoopStatistics PeriodicThread::statistics() const noexcept {
  LoopStatistics s;
  s.cycles = cycles_.load();
  s.overruns = overruns_.load();
  s.late_cycles = late_cycles_.load();
  s.lost_max_us = static_cast<double>(lost_max_ns_.load()) / 1000.0;
  s.lost_over_1ms = lost_over_[0].load();
  s.lost_over_5ms = lost_over_[1].load();
  s.lost_over_20ms = lost_over_[2].load();
  s.lost_over_50ms = lost_over_[3].load();
  s.period_error_p50_us = period_error_.quantile(0.5);
  s.period_error_p99_us = period_error_.quantile(0.99);
  s.period_error_max_us = period_error_.max();
  s.work_p50_us = work_.quantile(0.5);
  s.work_p99_us = work_.quantile(0.99);
  s.work_max_us = work_.max();
  s.realtime_scheduling = realtime_.load();
  s.memory_locked = locked_.load();
  s.realtime_requested = request_realtime_;
  s.realtime_priority = priority_;
  s.realtime_error = realtime_error_.load();
  return s;
}

}  // namespace tendril::server
