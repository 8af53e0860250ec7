#include "tendril/server/robot_runtime.hpp"

#include <pthread.h>
#include <sched.h>

#include <cmath>
#include <sstream>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"
#include "tendril/drivers/can/socketcan_bus.hpp"
#include "tendril/drivers/canopen/bus_load.hpp"

namespace tendril::server {

namespace {

using safety::OperatingState;
using Cia = canopen::Cia402State;

sim::DriveParameters simulation_parameters(const JointConfig& j, const std::string& file, std::size_t index) {
  sim::DriveParameters p;
  if (j.simulation_preset == "srmc_insertion") {
    p = sim::DriveParameters::srmc_insertion(j.name);
  } else if (j.simulation_preset == "srmc_roll") {
    p = sim::DriveParameters::srmc_roll(j.name);
  } else if (j.simulation_preset == "srmc_bend") {
    p = sim::DriveParameters::srmc_bend(j.name);
  } else {
    p.name = j.name;
    // A generic lead-screw axis whose encoder matches the configured resolution.
    p.units_per_output_rev =
        static_cast<double>(p.encoder_counts_per_motor_rev) * p.gear_ratio / j.drive.counts_per_unit;
    p.max_velocity = 5.0 * j.max_velocity;
  }
  p.initial_position = j.initial_position;
  const double sim_counts = p.counts_per_unit();
  if (std::abs(sim_counts - j.drive.counts_per_unit) > 1e-6 * sim_counts) {
    std::ostringstream msg;
    msg << file << ": joints[" << index << "].drive.counts_per_unit: expected " << sim_counts
        << " to match the simulated drive '" << j.simulation_preset
        << "' (encoder counts per joint unit), got " << j.drive.counts_per_unit;
    throw ConfigError(msg.str());
  }
  p.validate();
  return p;
}

double seconds_since(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace

RobotRuntime::RobotRuntime(std::vector<RobotConfig> robots, RuntimeOptions options)
    : impl_(std::make_unique<Impl>()) {
  auto& im = *impl_;
  im.options = options;
  if (!(options.control_rate_hz > 0 && options.control_rate_hz <= 10'000))
    throw ConfigError("control_rate_hz: expected a rate in (0, 10000] Hz, got " +
                      std::to_string(options.control_rate_hz));
  im.period = 1.0 / options.control_rate_hz;
  if (robots.empty())
    throw ConfigError("no robot configured: the server file must list at least one robot file");

  for (auto& rc : robots) {
    auto unit = std::make_unique<RobotUnit>();
    unit->n = rc.joints.size();
    const std::string file = rc.file.string();
    unit->kinematics = make_kinematics(rc.kinematics, unit->n, file);

    std::vector<safety::JointLimit> limits;
    for (std::size_t i = 0; i < unit->n; ++i) {
      const auto& j = rc.joints[i];
      limits.push_back({j.name, j.unit, j.lower, j.upper, j.soft_margin, j.max_velocity, j.max_acceleration,
                        j.max_tracking_error});
      unit->max_velocity[i] = j.max_velocity;
      unit->max_acceleration[i] = j.max_acceleration;
    }
    safety::SupervisorOptions so;
    so.command_timeout = rc.command_timeout_ms / 1000.0;
    // Loop-timing bound (safety::lost_control_bound): half the shorter of the command timeout and the
    // drives' heartbeat consumer time (how long a drive tolerates a silent master), unless the robot
    // file sets a tighter one.
    int consumer_ms = 0;
    for (const auto& bc : rc.buses)
      consumer_ms = consumer_ms == 0 ? bc.master_heartbeat_timeout_ms
                                     : std::min(consumer_ms, bc.master_heartbeat_timeout_ms);
    so.max_lost_control_time = safety::lost_control_bound(so.command_timeout, consumer_ms / 1000.0);
    if (rc.max_lost_control_ms > 0) {
      if (rc.max_lost_control_ms / 1000.0 > so.max_lost_control_time)
        throw ConfigError(file + ": max_lost_control_ms: expected at most " +
                          std::to_string(static_cast<int>(so.max_lost_control_time * 1000.0)) +
                          " ms (half the shorter of command_timeout_ms and the buses' "
                          "master_heartbeat_timeout_ms), got " +
                          std::to_string(rc.max_lost_control_ms));
      so.max_lost_control_time = rc.max_lost_control_ms / 1000.0;
    }
    unit->supervisor = std::make_unique<safety::SafetySupervisor>(safety::LimitSet(std::move(limits)), so);
    OperatingLimits operating;
    for (std::size_t i = 0; i < unit->n; ++i) {
      operating.lower[i] = rc.joints[i].lower;
      operating.upper[i] = rc.joints[i].upper;
      operating.max_velocity[i] = rc.joints[i].max_velocity;
    }
    operating.servo_timeout_s = so.command_timeout;
    unit->operating_limits.store(operating);
    unit->interpolator = std::make_unique<teleop::QuinticInterpolator>(unit->n);

    // Buses and their drives.
    std::map<std::string, BusUnit*> robot_buses;
    for (const auto& bc : rc.buses) {
      auto bus = std::make_unique<BusUnit>();
      bus->config = bc;
      bus->robot = rc.name;
      std::vector<canopen::DriveSetup> setups;
      std::vector<std::size_t> joint_index;
      for (std::size_t i = 0; i < unit->n; ++i) {
        const auto& j = rc.joints[i];
        if (j.drive.bus != bc.name) continue;
        canopen::DriveSetup ds;
        ds.name = j.name;
        ds.node_id = static_cast<std::uint8_t>(j.drive.node_id);
        ds.counts_per_unit = j.drive.counts_per_unit;
        ds.offset_counts = j.drive.offset_counts;
        ds.heartbeat_producer_ms = static_cast<std::uint16_t>(bc.drive_heartbeat_period_ms);
        ds.master_heartbeat_timeout_ms = static_cast<std::uint16_t>(bc.master_heartbeat_timeout_ms);
        setups.push_back(ds);
        joint_index.push_back(i);
      }
      const auto load = canopen::estimate_bus_load(bc.bitrate, std::chrono::microseconds(bc.sync_period_us),
                                                   setups, std::chrono::milliseconds(bc.heartbeat_period_ms));
      bus->load = load.load;
      bus->load_breakdown = load.breakdown;
      if (load.load > bc.max_load) {
        std::ostringstream msg;
        msg.precision(3);
        msg << file << ": buses: bus '" << bc.name << "' would run at " << load.load * 100.0 << " % load ("
            << load.bits_per_second / 1000.0 << " kbit/s worst case of " << bc.bitrate / 1000.0
            << " kbit/s: " << load.breakdown << "), over its ceiling of " << bc.max_load * 100.0
            << " %. Lengthen sync_period_us, raise the bitrate, or move drives to another bus.";
        throw ConfigError(msg.str());
      }
      canopen::MasterSetup ms;
      ms.sync_period = std::chrono::microseconds(bc.sync_period_us);
      ms.heartbeat_period = std::chrono::milliseconds(bc.heartbeat_period_ms);
      ms.drive_heartbeat_timeout = std::chrono::milliseconds(bc.drive_heartbeat_timeout_ms);
      if (bc.interface == "virtual") {
        bus->virtual_bus = std::make_unique<can::VirtualBus>(rc.name + "/" + bc.name, bc.bitrate);
        bus->master_endpoint = bus->virtual_bus->attach("master");
        for (std::size_t k = 0; k < setups.size(); ++k) {
          const auto i = joint_index[k];
          auto params = simulation_parameters(rc.joints[i], file, i);
          auto endpoint = bus->virtual_bus->attach("sim:" + rc.joints[i].name);
          bus->sim_drives.push_back(
              std::make_unique<sim::SimulatedCia402Drive>(setups[k].node_id, *endpoint, std::move(params)));
          bus->sim_endpoints.push_back(std::move(endpoint));
        }
      } else {
        bus->master_endpoint = std::make_unique<can::SocketCanBus>(bc.interface, bc.bitrate);
      }
      bus->master = std::make_unique<canopen::CanopenMaster>(*bus->master_endpoint, ms, setups);
      robot_buses[bc.name] = bus.get();
      im.buses.push_back(std::move(bus));
    }
    unit->bindings.resize(unit->n);
    std::map<std::string, std::size_t> next_drive;
    for (std::size_t i = 0; i < unit->n; ++i) {
      auto* bus = robot_buses.at(rc.joints[i].drive.bus);
      auto k = next_drive[bus->config.name]++;
      unit->bindings[i].bus = bus;
      unit->bindings[i].drive = k;
      unit->bindings[i].sim = bus->virtual_bus ? bus->sim_drives[k].get() : nullptr;
    }
    if (!rc.catheter.is_null()) {
      // Sensor and joystick nodes sit on the bus of the bend drives.
      if (unit->n != 4)
        throw ConfigError(file + ": catheter: settings for a steerable catheter need its 4 joints");
      unit->catheter = make_catheter_unit(rc, *unit->bindings[2].bus, unit->bindings);
      // Its ADC nodes share the bus: each sends a 7-byte TPDO at 100 Hz and a heartbeat at 10 Hz.
      auto& bus = *unit->bindings[2].bus;
      const int nodes = unit->catheter->settings.analog_joystick ? 2 : 1;
      const double bits =
          nodes * (100.0 * canopen::worst_case_frame_bits(7) + 10.0 * canopen::worst_case_frame_bits(1));
      bus.load += bits / bus.config.bitrate;
      bus.load_breakdown +=
          "; " + std::to_string(nodes) + " ADC node(s): " + std::to_string(static_cast<int>(bits)) + " bit/s";
      if (bus.load > bus.config.max_load)
        throw ConfigError(file + ": buses: bus '" + bus.config.name + "' would run at " +
                          std::to_string(bus.load * 100.0) + " % load with the catheter's ADC nodes (" +
                          bus.load_breakdown + "), over its ceiling of " +
                          std::to_string(bus.config.max_load * 100.0) + " %");
    }
    unit->config = std::move(rc);
    im.by_name[unit->config.name] = unit.get();
    im.robots.push_back(std::move(unit));
  }
}

RobotRuntime::~RobotRuntime() { stop(); }

double RobotRuntime::time() const noexcept {
  const auto now = impl_->options.stepped ? impl_->stepped_now : std::chrono::steady_clock::now();
  return seconds_since(impl_->start_time, now);
}

std::size_t RobotRuntime::robot_count() const noexcept { return impl_->robots.size(); }
std::uint64_t RobotRuntime::control_ticks() const noexcept { return impl_->ticks.load(); }
LoopStatistics RobotRuntime::loop_statistics() const noexcept { return impl_->control_thread.statistics(); }

std::unique_ptr<can::Bus> RobotRuntime::tap_bus(const std::string& robot, const std::string& bus) {
  for (auto& b : impl_->buses)
    if (b->robot == robot && b->config.name == bus && b->virtual_bus) return b->virtual_bus->attach("tap");
  return nullptr;
}

sim::SimulatedCia402Drive* RobotRuntime::simulated_drive(const std::string& robot, const std::string& joint) {
  auto it = impl_->by_name.find(robot);
  if (it == impl_->by_name.end()) return nullptr;
  for (std::size_t i = 0; i < it->second->n; ++i)
    if (it->second->config.joints[i].name == joint) return it->second->bindings[i].sim;
  return nullptr;
}

void RobotRuntime::start() {
  auto& im = *impl_;
  if (im.running.load()) return;
  im.start_time = std::chrono::steady_clock::now();
  im.stepped_now = im.start_time;
  im.wall_offset = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  const auto dt =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(im.period));

  for (auto& b : im.buses) {
    if (b->sim_drives.empty()) continue;
    if (im.options.stepped) continue;
    auto* bus = b.get();
    bus->sim_thread.start(
        "sim:" + bus->config.name, std::chrono::milliseconds(1),
        [bus](const CycleTiming& c) {
          // The SIMULATED hardware keeps real time as real hardware would: a late cycle steps the
          // time that really passed (heartbeats, PDO rates, physics), not a nominal 1 ms. Otherwise a
          // loaded machine slows simulated time, and the ADC nodes' 100 Hz PDOs thin out until their
          // sensors look stale. Capped at 1 s of physics per cycle.
          const double dt = std::min(0.001 + std::chrono::duration<double>(c.lost).count(), 1.0);
          for (auto& d : bus->sim_drives) d->pump(c.woke, dt);
          for (auto* p : bus->plants) p->step(dt);
        },
        im.options.realtime_priority, 70);
  }
  for (auto& b : im.buses) {
    auto* bus = b.get();
    bus->master->start(im.blocking_idle(*bus));
  }
  for (auto& r : im.robots)
    if (r->catheter) start_catheter_nodes(*r->catheter, *r->bindings[2].bus);
  if (im.options.stepped) {
    im.stepped_now = std::chrono::steady_clock::now();
  } else {
    for (auto& b : im.buses) {
      auto* bus = b.get();
      bus->bus_thread = std::thread([&im, bus] { im.run_bus(*bus); });
    }
  }
  im.running.store(true);
  im.stopping.store(false);
  if (!im.options.stepped) {
    im.control_thread.start(
        "control", dt,
        [&im](const CycleTiming& c) {
          im.control_cycle(c.deadline, std::chrono::duration<double>(c.lost).count());
        },
        im.options.realtime_priority);
  }
}

std::function<void()> RobotRuntime::Impl::blocking_idle(BusUnit& bus) const {
  if (!options.stepped) return {};
  // Stepped: the simulated nodes only move when someone steps them, so step them while the master
  // waits in its blocking start-up and shutdown exchanges.
  return [&bus] {
    const auto now = std::chrono::steady_clock::now();
    for (auto& d : bus.sim_drives) d->pump(now, 0.001);
  };
}

void RobotRuntime::Impl::run_bus(BusUnit& b) {
  pthread_setname_np(pthread_self(), "canbus");
  if (options.realtime_priority) {
    // Just below the control thread: SYNC and heartbeats must not starve behind the network threads.
    sched_param sp{};
    sp.sched_priority = 75;
    pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  }
  // Sleeps until the master's next deadline (SYNC, heartbeat, a consumer timeout) or a frame. Urgent
  // commands (quick stop, disable) do not wait for that: CanopenMaster::set_command() rings
  // Bus::wake(), and the poll below sends them. The cap only bounds how long stop() may wait.
  constexpr auto kMaxSleep = std::chrono::milliseconds(100);
  auto handle = [&b](const can::Frame& f) {
    const auto at = std::chrono::steady_clock::now();
    b.master->handle(f, at);
    for (auto& listen : b.frame_listeners) listen(f, at);
  };
  while (!stopping.load(std::memory_order_relaxed)) {
    auto now = std::chrono::steady_clock::now();
    auto wait = std::min<std::chrono::nanoseconds>(b.master->next_deadline() - now, kMaxSleep);
    if (wait < std::chrono::nanoseconds(0)) wait = std::chrono::nanoseconds(0);
    if (auto frame = b.master_endpoint->receive(wait)) {
      // The watchdogs run at the time taken before the queue is drained: frames that arrived while
      // this thread was stalled count as heard (they are stamped as handled), so a stall of this
      // thread never looks like a silent drive.
      now = std::chrono::steady_clock::now();
      handle(*frame);
      while (auto more = b.master_endpoint->receive(std::chrono::nanoseconds(0))) handle(*more);
      b.master->poll(now);
    } else {
      b.master->poll(std::chrono::steady_clock::now());
    }
  }
}

void RobotRuntime::Impl::step_buses(std::chrono::steady_clock::time_point now, double dt) {
  for (auto& b : buses) {
    for (auto& d : b->sim_drives) d->pump(now, dt);
    for (auto* p : b->plants) p->step(dt);
    while (auto f = b->master_endpoint->receive(std::chrono::nanoseconds(0))) {
      b->master->handle(*f, now);
      for (auto& listen : b->frame_listeners) listen(*f, now);
    }
    b->master->poll(now);
  }
}

void RobotRuntime::step() {
  auto& im = *impl_;
  if (!im.options.stepped) throw std::logic_error("RobotRuntime::step() is for stepped mode only");
  if (!im.running.load()) throw std::logic_error("RobotRuntime::step() before start()");
  im.stepped_now +=
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(im.period));
  const auto now = im.stepped_now;
  if (im.stepped_sim_lost > 0.0) {
    // After a stall of the whole machine the highest priority runs first: the control cycle, on the
    // feedback and readings from before the stall; then the bus and the simulated hardware catch up.
    im.control_cycle(now, im.stepped_lost);
    im.step_buses(now, im.period + im.stepped_sim_lost);
  } else {
    im.step_buses(now, im.period);
    im.control_cycle(now, im.stepped_lost);
  }
  im.stepped_lost = 0.0;
  im.stepped_sim_lost = 0.0;
  // Urgent requests from this cycle leave now, as the bus thread would when woken.
  for (auto& b : im.buses) b->master->poll(now);
}

void RobotRuntime::stall(std::chrono::nanoseconds duration, Stall what) {
  auto& im = *impl_;
  if (!im.options.stepped) throw std::logic_error("RobotRuntime::stall() is for stepped mode only");
  if (!im.running.load()) throw std::logic_error("RobotRuntime::stall() before start()");
  const auto period =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(im.period));
  for (auto skipped = period; skipped <= duration; skipped += period) {
    im.stepped_now += period;
    if (what == Stall::control_thread) {
      im.step_buses(im.stepped_now, im.period);  // the control cycles that should have run do not
    } else {
      im.stepped_sim_lost += im.period;
    }
  }
  im.stepped_lost += std::chrono::duration<double>(duration).count();
}

void RobotRuntime::stop() {
  auto& im = *impl_;
  if (!im.running.exchange(false)) return;
  im.control_thread.stop();
  im.stopping.store(true);
  for (auto& b : im.buses) b->master_endpoint->wake();
  for (auto& r : im.robots)
    if (r->catheter && r->catheter->evdev) r->catheter->evdev->stop();
  for (auto& b : im.buses)
    if (b->bus_thread.joinable()) b->bus_thread.join();
  for (auto& b : im.buses) {
    auto* bus = b.get();
    try {
      bus->master->shutdown(std::chrono::milliseconds(500), im.blocking_idle(*bus));
    } catch (const std::exception&) {
      // Shutdown is best effort: the drives quick-stop by themselves when the master heartbeat ends.
    }
  }
  for (auto& b : im.buses) b->sim_thread.stop();
}

bool RobotRuntime::drives_disabled(std::vector<std::string>* not_disabled) const {
  bool all = true;
  for (const auto& r : impl_->robots) {
    for (std::size_t i = 0; i < r->n; ++i) {
      const auto& b = r->bindings[i];
      const auto state = b.bus->master->feedback(b.drive).load().state;
      const bool off = state == canopen::Cia402State::switch_on_disabled ||
                       state == canopen::Cia402State::ready_to_switch_on ||
                       state == canopen::Cia402State::not_ready_to_switch_on ||
                       state == canopen::Cia402State::fault;
      if (!off) {
        all = false;
        if (not_disabled)
          not_disabled->push_back(r->config.name + "/" + r->config.joints[i].name + " (" +
                                  canopen::to_string(state) + ")");
      }
    }
  }
  return all;
}

}  // namespace tendril::server
