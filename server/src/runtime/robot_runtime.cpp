// Assembly of the robots and their hardware from the robot files, and the runtime's lifecycle.
#include "tendril/server/robot_runtime.hpp"

#include <cmath>
#include <set>
#include <sstream>

#include "runtime_impl.hpp"
#include "tendril/drivers/can/socketcan_bus.hpp"
#include "tendril/drivers/canopen/bus_load.hpp"
#include "tendril/server/config_schema.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

double seconds_since(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// A generic lead-screw axis whose encoder matches the configured resolution.
sim::DriveParameters generic_drive(const JointConfig& j) {
  sim::DriveParameters p;
  p.name = j.name();
  p.units_per_output_rev =
      static_cast<double>(p.encoder_counts_per_motor_rev) * p.gear_ratio / j.drive->counts_per_unit;
  p.max_velocity = 5.0 * j.limit.max_velocity;
  return p;
}

sim::DriveParameters simulated_drive_parameters(const RobotType& type, const JointConfig& j,
                                                const std::string& file, std::size_t index) {
  std::optional<sim::DriveParameters> preset;
  if (j.simulation_preset != "generic") {
    preset = type.simulated_drive(j.simulation_preset, j);
    if (!preset)
      throw ConfigError(file + ": joints[" + std::to_string(index) +
                        "].simulation.preset: expected generic or a " + type.kind() + " preset, got \"" +
                        j.simulation_preset + "\"");
  }
  sim::DriveParameters p = preset ? *preset : generic_drive(j);
  p.initial_position = j.initial_position;
  const double sim_counts = p.counts_per_unit();
  if (std::abs(sim_counts - j.drive->counts_per_unit) > 1e-6 * sim_counts) {
    std::ostringstream msg;
    msg << file << ": joints[" << index << "].drive.counts_per_unit: expected " << sim_counts
        << " to match the simulated drive '" << j.simulation_preset
        << "' (encoder counts per joint unit), got " << j.drive->counts_per_unit;
    throw ConfigError(msg.str());
  }
  p.validate();
  return p;
}

// What the runtime offers one robot's type while it is built.
class Assembly final : public RobotAssembly {
 public:
  Assembly(RobotRuntime::Impl& im, RobotUnit& unit) : im_(im), unit_(unit) {}

  BusAccess bus(const std::string& name) override {
    CanBusComponent* bus = nullptr;
    for (auto* b : unit_.buses)
      if (b->config.name == name) bus = b;
    if (!bus)
      throw ConfigError(unit_.config.file.string() + ": buses: the robot type needs bus '" + name +
                        "', which the file does not list");
    BusAccess access;
    access.name = name;
    access.simulated = bus->virtual_bus != nullptr;
    access.send = [bus](const can::Frame& frame) {
      return bus->master_endpoint->send(frame) == can::SendResult::ok;
    };
    access.listen = [bus](std::function<void(const can::Frame&, std::chrono::steady_clock::time_point)> f) {
      bus->frame_listeners.push_back(std::move(f));
    };
    if (bus->virtual_bus) {
      access.attach = [bus](const std::string& node) { return bus->virtual_bus->attach(node); };
      access.add_plant = [bus](sim::Plant* plant) { bus->plants.push_back(plant); };
    }
    access.add_load = [bus, robot = unit_.config.name](double bits, const std::string& what) {
      bus->extra_bits_per_second += bits;
      bus->extra_breakdown +=
          "; " + robot + ": " + what + " " + std::to_string(static_cast<long>(bits)) + " bit/s";
    };
    access.on_start = [bus](std::function<void()> hook) { bus->on_start.push_back(std::move(hook)); };
    access.claim_node = [bus, robot = unit_.config.name, file = unit_.config.file.string()](
                            int node_id, const std::string& key, const std::string& what) {
      if (auto [it, fresh] = bus->node_owner.emplace(node_id, robot + "/" + what); !fresh)
        throw ConfigError(file + ": " + key + ": node " + std::to_string(node_id) + " on bus '" +
                          bus->config.name + "' is already " + it->second +
                          " (node ids are unique per bus, across robots)");
    };
    return access;
  }
  hardware::JointInterface* joints() override { return unit_.own_joints.get(); }
  void provide_joints(hardware::JointInterface& joints) override {
    if (unit_.own_joints)
      throw ConfigError(unit_.config.file.string() +
                        ": joints: drives are configured, the type cannot provide them");
    if (joints.size() != unit_.n)
      throw ConfigError(unit_.config.file.string() + ": joints: the robot type provides " +
                        std::to_string(joints.size()) + " joints, the file lists " + std::to_string(unit_.n));
    unit_.joints = &joints;
  }
  sim::SimulatedCia402Drive* simulated_drive(std::size_t joint) override {
    if (joint >= unit_.n || !unit_.config.joints[joint].drive) return nullptr;
    const std::string who = unit_.config.name + "/" + unit_.config.joints[joint].name();
    for (auto* b : unit_.buses) {
      if (b->config.name != unit_.config.joints[joint].drive->bus || !b->virtual_bus) continue;
      for (std::size_t k = 0; k < b->drive_setups.size(); ++k)
        if (b->drive_setups[k].name == who) return b->sim_drives[k].get();
    }
    return nullptr;
  }
  std::string joint_bus(std::size_t joint) const override {
    return joint < unit_.n && unit_.config.joints[joint].drive ? unit_.config.joints[joint].drive->bus
                                                               : std::string();
  }
  void add_component(std::unique_ptr<hardware::HardwareComponent> component) override {
    im_.extra_components.push_back(std::move(component));
  }
  void add_component_in_control_thread(std::unique_ptr<hardware::HardwareComponent> component) override {
    im_.control_thread_components.push_back(component.get());
    im_.extra_components.push_back(std::move(component));
  }
  // Stepped by a test's hand: in simulated time the runtime paces itself, and the types' own threads
  // (a mapper, a poller) run as they do live.
  bool stepped() const override { return im_.options.stepped && !im_.options.simulated_time; }
  double control_period() const override { return im_.period; }
  const std::vector<teleop::CenterlinePolyline>& scene_vessel() const override {
    return im_.options.scene_vessel;
  }

 private:
  RobotRuntime::Impl& im_;
  RobotUnit& unit_;
};

}  // namespace

ModeId RobotUnit::mode_id(const std::string& name) const {
  for (std::size_t i = 0; i < modes.size(); ++i)
    if (modes[i].name == name) return static_cast<ModeId>(i);
  return static_cast<ModeId>(modes.size());
}

const std::string& RobotUnit::mode_name(ModeId id) const {
  static const std::string unknown = "unknown";
  return id < modes.size() ? modes[id].name : unknown;
}

RobotRuntime::RobotRuntime(std::vector<RobotConfig> robots, RuntimeOptions options_in,
                           const RobotTypes& types)
    : impl_(std::make_unique<Impl>()) {
  auto& im = *impl_;
  im.options = std::move(options_in);  // it carries the scene vessel
  const RuntimeOptions& options = im.options;
  if (!(options.control_rate_hz > 0 && options.control_rate_hz <= 10'000))
    throw ConfigError("control_rate_hz: expected a rate in (0, 10000] Hz, got " +
                      std::to_string(options.control_rate_hz));
  im.period = 1.0 / options.control_rate_hz;
  if (robots.empty())
    throw ConfigError("no robot configured: the server file must list at least one robot file");
  if (options.simulated_time) {
    // Simulated time steps every device by hand: a real one would run on its own clock meanwhile.
    for (const auto& rc : robots)
      for (const auto& bc : rc.buses)
        if (bc.interface != "virtual")
          throw ConfigError(rc.file.string() + ": buses: bus '" + bc.name + "' is the SocketCAN interface '" +
                            bc.interface +
                            "'; simulated time (--simulated-time) is only for SIMULATED devices: every bus "
                            "must be \"virtual\". Real hardware runs in real time.");
    im.options.stepped = true;
  }

  // 1. Every file against its type's merged schema; rates and names.
  std::set<std::string> names;
  for (const auto& rc : robots) {
    const std::string file = rc.file.string();
    const RobotType* type = types.find(rc.kind);
    if (!type) {
      std::string message = file + ": kind: expected one of ";
      const auto kinds = types.kinds();
      for (std::size_t i = 0; i < kinds.size(); ++i) {
        if (i > 0) message += ", ";
        message += kinds[i];
      }
      message += ", got \"";
      message += rc.kind;
      message += '"';
      throw ConfigError(message);
    }
    if (!rc.document.is_null()) {
      if (auto why = schema_violation(robot_schema(type->settings_schema(), rc.kind), rc.document))
        throw ConfigError(file + ": " + *why);
    }
    if (rc.control_rate_hz && std::abs(*rc.control_rate_hz - options.control_rate_hz) > 1e-9)
      throw ConfigError(file + ": control_rate_hz: expected " + std::to_string(options.control_rate_hz) +
                        " (the server's control_rate_hz: every robot runs on the one control thread), got " +
                        std::to_string(*rc.control_rate_hz));
    if (!names.insert(rc.name).second)
      throw ConfigError(file + ": name: robot name '" + rc.name + "' is already used by another robot file");
  }

  // 2. Buses: one per name across all files (the same name is the same physical bus).
  std::map<std::string, CanBusComponent*> bus_by_name;
  std::map<std::string, std::string> bus_first_file;
  for (const auto& rc : robots) {
    for (const auto& bc : rc.buses) {
      auto it = bus_by_name.find(bc.name);
      if (it == bus_by_name.end()) {
        auto bus = std::make_unique<CanBusComponent>();
        bus->config = bc;
        bus->stepped = options.stepped;
        bus_by_name[bc.name] = bus.get();
        bus_first_file[bc.name] = rc.file.string();
        im.buses.push_back(std::move(bus));
        it = bus_by_name.find(bc.name);
      } else if (!(it->second->config == bc)) {
        throw ConfigError(rc.file.string() + ": buses: bus '" + bc.name + "' is also configured by " +
                          bus_first_file[bc.name] +
                          " with other settings; robots that share a bus must describe it the same way");
      }
      it->second->robots.push_back(rc.name);
    }
  }

  // 3. Drives on each bus, across robots: node ids unique per bus, one master, the load budget.
  struct DriveRef {
    CanBusComponent* bus;
    std::size_t drive;
  };
  std::map<std::string, std::vector<DriveRef>> drives_of;  // robot -> per joint
  for (const auto& rc : robots) {
    const RobotType& type = *types.find(rc.kind);
    auto& refs = drives_of[rc.name];
    for (std::size_t i = 0; i < rc.joints.size(); ++i) {
      const auto& j = rc.joints[i];
      if (!j.drive) continue;
      auto* bus = bus_by_name.at(j.drive->bus);
      const std::string who = rc.name + "/" + j.name();
      if (auto [it, fresh] = bus->node_owner.emplace(j.drive->node_id, who); !fresh)
        throw ConfigError(rc.file.string() + ": joints[" + std::to_string(i) + "].drive.node_id: node " +
                          std::to_string(j.drive->node_id) + " on bus '" + bus->config.name +
                          "' is already " + it->second);
      const auto& bc = bus->config;
      canopen::DriveSetup ds;
      ds.name = who;
      ds.node_id = static_cast<std::uint8_t>(j.drive->node_id);
      ds.counts_per_unit = j.drive->counts_per_unit;
      ds.offset_counts = j.drive->offset_counts;
      ds.heartbeat_producer_ms = static_cast<std::uint16_t>(bc.drive_heartbeat_period_ms);
      ds.master_heartbeat_timeout_ms = static_cast<std::uint16_t>(bc.master_heartbeat_timeout_ms);
      refs.push_back({bus, bus->drive_setups.size()});
      bus->drive_setups.push_back(ds);
      if (bc.interface == "virtual") {
        bus->sim_drives.push_back(nullptr);  // made below, once the endpoint exists
        bus->sim_endpoints.push_back(nullptr);
        auto params = simulated_drive_parameters(type, j, rc.file.string(), i);
        if (!bus->virtual_bus) bus->virtual_bus = std::make_unique<can::VirtualBus>(bc.name, bc.bitrate);
        bus->sim_endpoints.back() = bus->virtual_bus->attach("sim:" + who);
        bus->sim_drives.back() = std::make_unique<sim::SimulatedCia402Drive>(
            ds.node_id, *bus->sim_endpoints.back(), std::move(params));
      }
    }
  }
  for (auto& bus : im.buses) {
    const auto& bc = bus->config;
    const auto load =
        canopen::estimate_bus_load(bc.bitrate, std::chrono::microseconds(bc.sync_period_us),
                                   bus->drive_setups, std::chrono::milliseconds(bc.heartbeat_period_ms));
    bus->load = load.load;
    bus->load_breakdown = load.breakdown;
    std::string users;
    for (const auto& r : bus->robots) users += (users.empty() ? "" : ", ") + r;
    bus->check_load("robots " + users);
    canopen::MasterSetup ms;
    ms.sync_period = std::chrono::microseconds(bc.sync_period_us);
    ms.heartbeat_period = std::chrono::milliseconds(bc.heartbeat_period_ms);
    ms.drive_heartbeat_timeout = std::chrono::milliseconds(bc.drive_heartbeat_timeout_ms);
    if (bc.interface == "virtual") {
      if (!bus->virtual_bus) bus->virtual_bus = std::make_unique<can::VirtualBus>(bc.name, bc.bitrate);
      bus->master_endpoint = bus->virtual_bus->attach("master");
    } else {
      bus->master_endpoint = std::make_unique<can::SocketCanBus>(bc.interface, bc.bitrate);
    }
    bus->master = std::make_unique<canopen::CanopenMaster>(*bus->master_endpoint, ms, bus->drive_setups);
  }

  // 4. Robots: limits, supervisor, joints, and the type's plug-in.
  for (auto& rc : robots) {
    auto unit = std::make_unique<RobotUnit>();
    unit->type = types.find(rc.kind);
    unit->n = rc.joints.size();
    const std::string file = rc.file.string();
    std::vector<safety::JointLimit> limits;
    for (std::size_t i = 0; i < unit->n; ++i) {
      limits.push_back(rc.joints[i].limit);
      unit->max_acceleration[i] = rc.joints[i].limit.max_acceleration;
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
    // A robot on no CAN bus (its type provides the joints over another link) has no heartbeat consumer
    // time here: the command timeout alone bounds it, and its file states its link's own, tighter bound.
    so.max_lost_control_time = safety::lost_control_bound(
        so.command_timeout, consumer_ms > 0 ? consumer_ms / 1000.0 : so.command_timeout);
    if (rc.max_lost_control_ms > 0) {
      if (rc.max_lost_control_ms / 1000.0 > so.max_lost_control_time)
        throw ConfigError(file + ": max_lost_control_ms: expected at most " +
                          std::to_string(static_cast<int>(so.max_lost_control_time * 1000.0)) +
                          " ms (half the shorter of command_timeout_ms and the buses' "
                          "master_heartbeat_timeout_ms), got " +
                          std::to_string(rc.max_lost_control_ms));
      so.max_lost_control_time = rc.max_lost_control_ms / 1000.0;
    }
    for (std::size_t i = 0; i < unit->n; ++i)
      for (const auto& bc : rc.buses)
        if (rc.joints[i].drive && bc.name == rc.joints[i].drive->bus)
          unit->heartbeat_timeout_ms[i] = bc.drive_heartbeat_timeout_ms;
    safety::LimitSet limit_set(std::move(limits));
    unit->operating_limits.store(safety::OperatingLimits::configured(limit_set, so.command_timeout));
    unit->supervisor = std::make_unique<safety::SafetySupervisor>(std::move(limit_set), so);
    unit->interpolator = std::make_unique<teleop::QuinticInterpolator>(unit->n);
    for (const auto& bc : rc.buses) unit->buses.push_back(bus_by_name.at(bc.name));
    const auto& refs = drives_of[rc.name];
    if (!refs.empty()) {
      std::vector<std::pair<canopen::CanopenMaster*, std::size_t>> drives;
      for (const auto& ref : refs) drives.emplace_back(ref.bus->master.get(), ref.drive);
      unit->own_joints = std::make_unique<canopen::Cia402Joints>(std::move(drives));
      unit->joints = unit->own_joints.get();
    }
    unit->config = rc;
    Assembly assembly(im, *unit);
    unit->plugin = unit->type->create(unit->config, assembly);
    if (!unit->joints)
      throw ConfigError(file + ": joints: no drive is configured and the robot type '" + rc.kind +
                        "' provides none");
    unit->controller = &unit->plugin->controller();
    unit->modes.push_back({"joint", "move_jp (quintic) and servo_jv"});
    unit->modes.push_back({"path_following", "a loaded plan, one step at a time"});
    for (auto& m : unit->plugin->modes()) unit->modes.push_back(std::move(m));
    unit->context = std::make_unique<UnitContext>(*unit);
    unit->context->n = unit->n;
    unit->context->period = im.period;
    unit->context->supervisor = unit->supervisor.get();
    im.by_name[unit->config.name] = unit.get();
    im.robots.push_back(std::move(unit));
  }
  // The types' own nodes count in the budget too.
  for (auto& bus : im.buses) {
    std::string users;
    for (const auto& r : bus->robots) users += (users.empty() ? "" : ", ") + r;
    bus->check_load("robots " + users);
  }
  for (auto& bus : im.buses) im.components.push_back(bus.get());
  for (auto& c : im.extra_components) im.components.push_back(c.get());
}

RobotRuntime::~RobotRuntime() { stop(); }

double RobotRuntime::time() const noexcept {
  if (impl_->options.simulated_time)  // stepped by the pacing thread: its published copy
    return seconds_since(impl_->start_time, std::chrono::steady_clock::time_point(std::chrono::nanoseconds(
                                                impl_->published_now_ns.load(std::memory_order_acquire))));
  const auto now = impl_->options.stepped ? impl_->stepped_now : std::chrono::steady_clock::now();
  return seconds_since(impl_->start_time, now);
}

bool RobotRuntime::simulated_time() const noexcept { return impl_->options.simulated_time; }

std::size_t RobotRuntime::robot_count() const noexcept { return impl_->robots.size(); }
std::uint64_t RobotRuntime::control_ticks() const noexcept { return impl_->ticks.load(); }
LoopStatistics RobotRuntime::loop_statistics() const noexcept { return impl_->control_thread.statistics(); }

std::unique_ptr<can::Bus> RobotRuntime::tap_bus(const std::string& bus) {
  for (auto& b : impl_->buses)
    if (b->config.name == bus && b->virtual_bus) return b->virtual_bus->attach("tap");
  return nullptr;
}

sim::SimulatedCia402Drive* RobotRuntime::simulated_drive(const std::string& robot, const std::string& joint) {
  auto* r = impl_->find(robot);
  if (!r) return nullptr;
  const std::string who = robot + "/" + joint;
  for (const auto& j : r->config.joints) {
    if (j.name() != joint || !j.drive) continue;
    for (auto& b : impl_->buses) {
      if (b->config.name != j.drive->bus || !b->virtual_bus) continue;
      for (std::size_t k = 0; k < b->drive_setups.size(); ++k)
        if (b->drive_setups[k].name == who) return b->sim_drives[k].get();
    }
  }
  return nullptr;
}

std::optional<Eigen::Isometry3d> RobotRuntime::vessel_entry(const std::string& robot) const {
  auto* r = impl_->find(robot);
  return r ? r->plugin->vessel_entry() : std::nullopt;
}

RobotPlugin* RobotRuntime::plugin(const std::string& robot) {
  auto* r = impl_->find(robot);
  return r ? r->plugin.get() : nullptr;
}

RobotApiExtension* RobotRuntime::api_extension(const std::string& robot) {
  auto* r = impl_->find(robot);
  if (!r) return nullptr;
  for (std::size_t i = 0; i < impl_->robots.size(); ++i) {
    if (impl_->robots[i].get() != r) continue;
    if (extensions_.size() < impl_->robots.size()) extensions_.resize(impl_->robots.size());
    if (!extensions_[i]) {
      extensions_[i] = r->plugin->api(*this, [this, r](const PluginCommand& command) {
        RobotCommand c;
        c.kind = CommandKind::plugin;
        c.plugin = command;
        c.received = std::chrono::steady_clock::now();
        return impl_->post(*r, c);
      });
    }
    return extensions_[i].get();
  }
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

  for (auto& b : im.buses) b->start_simulation(im.options.realtime_priority);
  for (auto* c : im.components) c->configure(c->stepped_idle());
  for (auto& r : im.robots) r->plugin->start();
  if (im.options.stepped) {
    im.stepped_now = std::chrono::steady_clock::now();
    im.published_now_ns.store(im.stepped_now.time_since_epoch().count(), std::memory_order_release);
  } else {
    for (auto* c : im.components)
      if (!im.in_control_thread(c)) c->activate(im.options.realtime_priority);
  }
  im.running.store(true);
  if (im.options.simulated_time) {
    // One step per period at real-time pace while the machine keeps up. After a stall the pacing
    // thread skips the periods it missed (PeriodicThread never bursts): simulated time slips behind
    // the wall clock, every step is one nominal period, and no control time is lost. Its statistics
    // (loop_statistics()) still measure the machine's stalls, for the record. Normal priority: its
    // lateness is harmless, and a SCHED_FIFO pacer would starve the threads that serve what it
    // simulates (the topics, the API) on a busy machine, which is what a test would then see.
    im.control_thread.start(
        "sim-time", dt, [&im](const CycleTiming&) { im.advance_one_period(); }, false);
  } else if (!im.options.stepped) {
    im.control_thread.start(
        "control", dt,
        [&im, previous = std::chrono::steady_clock::time_point{}](const CycleTiming& c) mutable {
          // The devices without a thread of their own advance by the time since the previous cycle
          // (a stall included), so their newest reading is as fresh as this cycle.
          const double since = previous == std::chrono::steady_clock::time_point{}
                                   ? im.period
                                   : std::chrono::duration<double>(c.deadline - previous).count();
          previous = c.deadline;
          for (auto* component : im.control_thread_components) component->step(c.deadline, since, false);
          im.control_cycle(c.deadline, std::chrono::duration<double>(c.lost).count());
        },
        im.options.realtime_priority);
  }
}

void RobotRuntime::step() {
  auto& im = *impl_;
  if (!im.options.stepped) throw std::logic_error("RobotRuntime::step() is for stepped mode only");
  if (im.options.simulated_time)
    throw std::logic_error("RobotRuntime::step(): in simulated time the runtime paces itself");
  if (!im.running.load()) throw std::logic_error("RobotRuntime::step() before start()");
  im.advance_one_period();
}

void RobotRuntime::Impl::advance_one_period() {
  auto& im = *this;
  im.stepped_now +=
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(im.period));
  const auto now = im.stepped_now;
  // The control thread's own devices advance with it: by every period since its previous cycle.
  const double control_devices_period = im.period + im.stepped_sim_lost + im.stepped_control_devices_lost;
  if (im.stepped_sim_lost > 0.0) {
    // After a stall of the whole machine the highest priority runs first: the control thread (its own
    // devices, then the cycle), on the feedback and readings from before the stall; then the bus and
    // the simulated hardware with threads of their own catch up.
    for (auto* c : im.control_thread_components) c->step(now, control_devices_period, false);
    im.control_cycle(now, im.stepped_lost);
    for (auto* c : im.components)
      if (!im.in_control_thread(c)) c->step(now, im.period + im.stepped_sim_lost, false);
  } else {
    for (auto* c : im.components)
      c->step(now, im.in_control_thread(c) ? control_devices_period : im.period, false);
    im.control_cycle(now, im.stepped_lost);
  }
  im.stepped_lost = 0.0;
  im.stepped_sim_lost = 0.0;
  im.stepped_control_devices_lost = 0.0;
  for (auto* c : im.components) c->step(now, im.period, true);
  im.published_now_ns.store(now.time_since_epoch().count(), std::memory_order_release);
}

void RobotRuntime::stall(std::chrono::nanoseconds duration, Stall what) {
  auto& im = *impl_;
  if (!im.options.stepped) throw std::logic_error("RobotRuntime::stall() is for stepped mode only");
  if (im.options.simulated_time)
    throw std::logic_error("RobotRuntime::stall(): in simulated time no stall is lost time");
  if (!im.running.load()) throw std::logic_error("RobotRuntime::stall() before start()");
  const auto period =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(im.period));
  for (auto skipped = period; skipped <= duration; skipped += period) {
    im.stepped_now += period;
    if (what == Stall::control_thread) {
      // Buses and simulated hardware run on; the control cycles that should have run do not, nor do
      // the devices the control thread steps.
      for (auto* c : im.components)
        if (!im.in_control_thread(c)) c->step(im.stepped_now, im.period, false);
      im.stepped_control_devices_lost += im.period;
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
  for (auto& r : im.robots) r->plugin->stop();
  for (auto it = im.components.rbegin(); it != im.components.rend(); ++it)
    (*it)->deactivate(std::chrono::milliseconds(500), (*it)->stepped_idle());
}

bool RobotRuntime::drives_disabled(std::vector<std::string>* not_disabled) const {
  bool all = true;
  for (const auto& r : impl_->robots) {
    for (std::size_t i = 0; i < r->n; ++i) {
      hardware::JointFeedback fb;
      r->joints->read(i, fb);
      const bool off = fb.power == hardware::PowerState::off || fb.power == hardware::PowerState::fault;
      if (!off) {
        all = false;
        if (not_disabled)
          not_disabled->push_back(r->config.name + "/" + r->config.joints[i].name() + " (" +
                                  r->joints->device_state_text(fb.device_state) + ")");
      }
    }
  }
  return all;
}

}  // namespace tendril::server
