#include "tendril/drivers/sim/simulation.hpp"

#include <pthread.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <cerrno>

namespace tendril::sim {

Simulation::Simulation(can::VirtualBus& bus, Clock::time_point start) : bus_(bus), now_(start) {}

Simulation::~Simulation() { stop(); }

SimulatedCia402Drive& Simulation::add_drive(std::uint8_t node_id, DriveParameters params) {
  if (running_) throw SimulationSetupError("simulation: add_drive() while the real-time thread runs");
  for (const auto& s : drives_) {
    if (s->drive->node_id() == node_id) {
      throw SimulationSetupError("simulation: node id " + std::to_string(node_id) +
                                 " is already taken by drive '" + s->drive->parameters().name + "'");
    }
  }
  auto slot = std::make_unique<Slot>();
  slot->endpoint = bus_.attach("sim-node-" + std::to_string(node_id) + "-" + params.name);
  slot->drive = std::make_unique<SimulatedCia402Drive>(node_id, *slot->endpoint, std::move(params));
  slot->truth.store(slot->drive->truth());
  drives_.push_back(std::move(slot));
  return *drives_.back()->drive;
}

void Simulation::add_plant(Plant& plant) {
  if (running_) throw SimulationSetupError("simulation: add_plant() while the real-time thread runs");
  plants_.push_back(&plant);
}

SimulatedCia402Drive& Simulation::drive(std::size_t i) {
  if (i >= drives_.size()) throw std::out_of_range("simulation: no drive " + std::to_string(i));
  return *drives_[i]->drive;
}

const SimulatedCia402Drive& Simulation::drive(std::size_t i) const {
  if (i >= drives_.size()) throw std::out_of_range("simulation: no drive " + std::to_string(i));
  return *drives_[i]->drive;
}

void Simulation::step(double dt) noexcept {
  now_ += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(dt));
  step(now_, dt);
}

void Simulation::step(Clock::time_point now, double dt) noexcept {
  now_ = now;
  for (auto& s : drives_) {
    if (s->power_cycle_requested.exchange(false)) s->drive->power_cycle();
    if (const auto f = s->fault_requested.exchange(0))
      s->drive->inject_fault(static_cast<std::uint16_t>(f & 0xFFFF));
    s->drive->pump(now, dt);
  }
  for (auto* p : plants_) p->step(dt);
  for (auto& s : drives_) s->truth.store(s->drive->truth());
}

DriveTruth Simulation::truth(std::size_t i) const noexcept {
  if (i >= drives_.size()) return {};
  return drives_[i]->truth.load();
}

void Simulation::request_power_cycle(std::size_t i) noexcept {
  if (i < drives_.size()) drives_[i]->power_cycle_requested = true;
}

void Simulation::request_fault(std::size_t i, std::uint16_t emcy_code) noexcept {
  if (i < drives_.size()) drives_[i]->fault_requested = 0x10000u | emcy_code;
}

void Simulation::set_silent(std::size_t i, bool silent) noexcept {
  if (i < drives_.size()) drives_[i]->drive->set_silent(silent);
}

void Simulation::start_realtime(std::chrono::nanoseconds period, int fifo_priority) {
  if (period.count() <= 0) throw SimulationSetupError("simulation: real-time period must be positive");
  if (running_.exchange(true)) throw SimulationSetupError("simulation: real-time thread already running");
  stop_requested_ = false;
  thread_ = std::thread([this, period, fifo_priority] { run(period, fifo_priority); });
}

void Simulation::stop() noexcept {
  stop_requested_ = true;
  if (thread_.joinable()) thread_.join();
  running_ = false;
}

namespace {
timespec to_timespec(Clock::time_point t) {
  // steady_clock is CLOCK_MONOTONIC on Linux (libstdc++), so its epoch matches clock_nanosleep's.
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
  timespec ts;
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  return ts;
}
}  // namespace

void Simulation::run(std::chrono::nanoseconds period, int fifo_priority) noexcept {
  RealtimeStatistics stats;
  if (fifo_priority > 0) {
    sched_param sp{};
    sp.sched_priority = fifo_priority;
    stats.sched_fifo = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
  }
  auto deadline = Clock::now();
  auto last = deadline;
  while (!stop_requested_.load(std::memory_order_relaxed)) {
    const auto now = Clock::now();
    const auto lateness = std::chrono::duration_cast<std::chrono::nanoseconds>(now - deadline).count();
    stats.last_lateness_ns = lateness;
    stats.max_lateness_ns = std::max(stats.max_lateness_ns, lateness);
    // Physics advances by the real elapsed time, capped so a long stall cannot explode the model.
    const double dt = std::min(std::chrono::duration<double>(now - last).count(), 0.05);
    last = now;
    step(now, dt);
    ++stats.cycles;
    deadline += period;
    if (Clock::now() > deadline + period) {
      ++stats.overruns;
      deadline = Clock::now();  // resynchronise instead of bursting to catch up
    }
    stats_.store(stats);
    const timespec ts = to_timespec(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
}

}  // namespace tendril::sim
