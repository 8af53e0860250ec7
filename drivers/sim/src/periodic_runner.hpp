// run_periodic: the loop of a simulated device's own real-time thread. Calls tick(now, dt) every
// period at absolute deadlines (clock_nanosleep TIMER_ABSTIME on CLOCK_MONOTONIC, which is
// steady_clock's epoch on Linux), with dt the real time elapsed since the last tick capped at
// max_dt (a stalled thread must not make the model jump), until `stop` is set. Records lateness and
// overruns (a cycle that starts a whole period late resynchronises instead of bursting to catch up).
#pragma once

#include <atomic>
#include <chrono>
#include <functional>

#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulation.hpp"

namespace tendril::sim::detail {

void run_periodic(std::chrono::nanoseconds period, double max_dt, int fifo_priority,
                  const std::atomic<bool>& stop, hardware::LatestValue<RealtimeStatistics>& statistics,
                  const std::function<void(Clock::time_point, double)>& tick) noexcept;

}  // namespace tendril::sim::detail
