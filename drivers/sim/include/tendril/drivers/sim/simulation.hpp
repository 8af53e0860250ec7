// Simulation: hosts SIMULATED drives (each on its own endpoint of one VirtualBus) and plants, and
// runs them either stepped from a test (step(dt): simulated time, as fast as possible) or in a
// real-time thread with absolute deadlines (clock_nanosleep TIMER_ABSTIME on CLOCK_MONOTONIC).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <thread>
#include <vector>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"

namespace tendril::sim {

// A physical model stepped after the drives on the simulation thread (e.g. SrmcPlant).
class Plant {
 public:
  virtual ~Plant() = default;
  virtual void step(double dt) noexcept = 0;
};

struct RealtimeStatistics {
  std::uint64_t cycles = 0;
  std::uint64_t overruns = 0;        // cycles that started a full period late (then resynchronised)
  std::int64_t max_lateness_ns = 0;  // worst wake-up delay after the absolute deadline
  std::int64_t last_lateness_ns = 0;
  bool sched_fifo = false;  // true if the thread got SCHED_FIFO (needs CAP_SYS_NICE)
};

class Simulation {
 public:
  // Stepped time starts at `start`; the real-time thread uses the real steady clock.
  explicit Simulation(can::VirtualBus& bus,
                      Clock::time_point start = Clock::time_point{} + std::chrono::hours(1));
  ~Simulation();  // stops the real-time thread
  Simulation(const Simulation&) = delete;
  Simulation& operator=(const Simulation&) = delete;

  // Set-up, not while the real-time thread runs (throws SimulationSetupError then).
  SimulatedCia402Drive& add_drive(std::uint8_t node_id, DriveParameters params);
  void add_plant(Plant& plant);  // not owned; must outlive the simulation

  std::size_t drive_count() const noexcept { return drives_.size(); }
  SimulatedCia402Drive& drive(std::size_t i);
  const SimulatedCia402Drive& drive(std::size_t i) const;

  // Stepped mode: advance simulated time by dt (seconds), pump every drive, step every plant.
  void step(double dt) noexcept;
  // One cycle at an explicit time (used by the real-time thread and by callers with their own clock).
  void step(Clock::time_point now, double dt) noexcept;
  Clock::time_point now() const noexcept { return now_; }

  // Real-time mode. Throws SimulationSetupError if already running or period is not positive.
  // fifo_priority > 0 asks for SCHED_FIFO at that priority; without permission it runs normally.
  void start_realtime(std::chrono::nanoseconds period, int fifo_priority = 0);
  void stop() noexcept;
  bool running() const noexcept { return running_.load(); }
  RealtimeStatistics realtime_statistics() const noexcept { return stats_.load(); }

  // Thread-safe views and requests (any thread; requests act at the next cycle).
  DriveTruth truth(std::size_t i) const noexcept;
  void request_power_cycle(std::size_t i) noexcept;
  void request_fault(std::size_t i, std::uint16_t emcy_code) noexcept;
  void set_silent(std::size_t i, bool silent) noexcept;

 private:
  struct Slot {
    std::unique_ptr<can::VirtualBusEndpoint> endpoint;
    std::unique_ptr<SimulatedCia402Drive> drive;
    hardware::LatestValue<DriveTruth> truth;
    std::atomic<bool> power_cycle_requested{false};
    std::atomic<std::uint32_t> fault_requested{0};  // 0x10000 | code
  };
  void run(std::chrono::nanoseconds period, int fifo_priority) noexcept;

  can::VirtualBus& bus_;
  std::vector<std::unique_ptr<Slot>> drives_;
  std::vector<Plant*> plants_;
  Clock::time_point now_;
  std::atomic<bool> running_{false};
  std::atomic<bool> stop_requested_{false};
  std::thread thread_;
  hardware::LatestValue<RealtimeStatistics> stats_;
};

}  // namespace tendril::sim
