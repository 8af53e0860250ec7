#include "periodic_runner.hpp"

#include <pthread.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <cerrno>

namespace tendril::sim::detail {

namespace {
timespec to_timespec(Clock::time_point t) noexcept {
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  return ts;
}
}  // namespace

void run_periodic(std::chrono::nanoseconds period, double max_dt, int fifo_priority,
                  const std::atomic<bool>& stop, hardware::LatestValue<RealtimeStatistics>& statistics,
                  const std::function<void(Clock::time_point, double)>& tick) noexcept {
  RealtimeStatistics stats;
  if (fifo_priority > 0) {
    sched_param sp{};
    sp.sched_priority = fifo_priority;
    stats.sched_fifo = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
  }
  auto deadline = Clock::now();
  auto last = deadline;
  while (!stop.load(std::memory_order_relaxed)) {
    const auto now = Clock::now();
    const auto lateness = std::chrono::duration_cast<std::chrono::nanoseconds>(now - deadline).count();
    stats.last_lateness_ns = lateness;
    stats.max_lateness_ns = std::max(stats.max_lateness_ns, lateness);
    const double dt = std::min(std::chrono::duration<double>(now - last).count(), max_dt);
    last = now;
    if (dt > 0.0) tick(now, dt);
    ++stats.cycles;
    deadline += period;
    if (Clock::now() > deadline + period) {
      ++stats.overruns;
      deadline = Clock::now();
    }
    statistics.store(stats);
    const timespec ts = to_timespec(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
}

}  // namespace tendril::sim::detail
