// A CAN bus with its CANopen master (for every robot's drives on it), simulated nodes when it is
// virtual, and its bus thread.
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <sstream>

#include "runtime_impl.hpp"

namespace tendril::server {

void CanBusComponent::check_load(const std::string& where) {
  const double total = load + extra_bits_per_second / config.bitrate;
  if (total <= config.max_load) return;
  std::ostringstream msg;
  msg.precision(3);
  msg << where << ": buses: bus '" << config.name << "' would run at " << total * 100.0 << " % load ("
      << (load * config.bitrate + extra_bits_per_second) / 1000.0 << " kbit/s worst case of "
      << config.bitrate / 1000.0 << " kbit/s: " << load_breakdown << extra_breakdown
      << "), over its ceiling of " << config.max_load * 100.0
      << " %. Lengthen sync_period_us, raise the bitrate, or move drives to another bus.";
  throw ConfigError(msg.str());
}

void CanBusComponent::configure(const std::function<void()>& idle) {
  master->start(idle);
  for (auto& hook : on_start) hook();
}

void CanBusComponent::start_simulation(bool realtime_priority) {
  // The simulated nodes run before the master configures them, so that they answer.
  if (stepped || (sim_drives.empty() && plants.empty())) return;
  sim_thread.start(
      "sim:" + config.name, std::chrono::milliseconds(1),
      [this](const CycleTiming& c) {
        // The SIMULATED hardware keeps real time as real hardware would: a late cycle steps the
        // time that really passed (heartbeats, PDO rates, physics), not a nominal 1 ms. Otherwise a
        // loaded machine slows simulated time, and the ADC nodes' 100 Hz PDOs thin out until their
        // sensors look stale. Capped at 1 s of physics per cycle.
        const double dt = std::min(0.001 + std::chrono::duration<double>(c.lost).count(), 1.0);
        for (auto& d : sim_drives) d->pump(c.woke, dt);
        for (auto* p : plants) p->step(dt);
      },
      realtime_priority, 70);
}

void CanBusComponent::activate(bool realtime_priority) {
  stopping.store(false);
  bus_thread = std::thread([this, realtime_priority] { run_bus(realtime_priority); });
}

void CanBusComponent::deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) {
  stopping.store(true);
  master_endpoint->wake();  // the bus thread may sleep up to kMaxSleep on receive()
  if (bus_thread.joinable()) bus_thread.join();
  try {
    master->shutdown(timeout, idle);
  } catch (const std::exception&) {
    // Shutdown is best effort: the drives quick-stop by themselves when the master heartbeat ends.
  }
  sim_thread.stop();
}

std::function<void()> CanBusComponent::stepped_idle() {
  if (!stepped) return {};
  // Stepped: the simulated nodes only move when someone steps them, so step them while the master
  // waits in its blocking start-up and shutdown exchanges.
  return [this] {
    const auto now = std::chrono::steady_clock::now();
    for (auto& d : sim_drives) d->pump(now, 0.001);
  };
}

void CanBusComponent::step(Clock::time_point now, double period, bool after_control) {
  if (after_control) {
    // Urgent requests from this cycle leave now, as the bus thread would when woken.
    master->poll(now);
    return;
  }
  for (auto& d : sim_drives) d->pump(now, period);
  for (auto* p : plants) p->step(period);
  while (auto f = master_endpoint->receive(std::chrono::nanoseconds(0))) {
    master->handle(*f, now);
    for (auto& listen : frame_listeners) listen(*f, now);
  }
  master->poll(now);
}

void CanBusComponent::run_bus(bool realtime_priority) {
  pthread_setname_np(pthread_self(), "canbus");
  if (realtime_priority) {
    // Just below the control thread: SYNC and heartbeats must not starve behind the network threads.
    sched_param sp{};
    sp.sched_priority = 75;
    pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  }
  // Sleeps until the master's next deadline (SYNC, heartbeat, a consumer timeout) or a frame. Urgent
  // commands (quick stop, disable) do not wait for that: CanopenMaster::set_command() rings
  // Bus::wake(), and the poll below sends them. The cap only bounds how long stop() may wait.
  constexpr auto kMaxSleep = std::chrono::milliseconds(100);
  auto handle = [this](const can::Frame& f) {
    const auto at = std::chrono::steady_clock::now();
    master->handle(f, at);
    for (auto& listen : frame_listeners) listen(f, at);
  };
  while (!stopping.load(std::memory_order_relaxed)) {
    auto now = std::chrono::steady_clock::now();
    auto wait = std::min<std::chrono::nanoseconds>(master->next_deadline() - now, kMaxSleep);
    if (wait < std::chrono::nanoseconds(0)) wait = std::chrono::nanoseconds(0);
    if (auto frame = master_endpoint->receive(wait)) {
      // The watchdogs run at the time taken before the queue is drained: frames that arrived while
      // this thread was stalled count as heard (they are stamped as handled), so a stall of this
      // thread never looks like a silent drive.
      now = std::chrono::steady_clock::now();
      handle(*frame);
      while (auto more = master_endpoint->receive(std::chrono::nanoseconds(0))) handle(*more);
      master->poll(now);
    } else {
      master->poll(std::chrono::steady_clock::now());
    }
  }
}

}  // namespace tendril::server
