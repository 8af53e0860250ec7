// Builds the steerable-catheter parts of a robot (model, controller, sensor and joystick inputs) and
// wires them to the robot's bus. The simulated plant is in catheter_simulation.cpp.
#include <cmath>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"

namespace tendril::server {

RobotUnit::~RobotUnit() = default;  // here, where CatheterUnit is complete

std::unique_ptr<CatheterUnit> make_catheter_unit(const RobotConfig& rc, BusUnit& bus,
                                                 const std::vector<JointBinding>& bindings) {
  const std::string file = rc.file.string();
  auto c = std::make_unique<CatheterUnit>();
  c->settings = parse_catheter_settings(rc);
  try {
    c->map = std::make_unique<teleop::CatheterConfigurationMap>(c->settings.nominal, c->settings.rates);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": catheter.model: " + e.what());
  }
  // ψ bounds for the configuration quintic: insertion and roll as configured; a bend angle may move as
  // fast as its drive's limit allows through the map's slope at the straight pose (the slope is
  // constant for the m = 2 models of the seed), less 10 % for the coupling.
  const Eigen::Vector4d zero = Eigen::Vector4d::Zero();
  const Eigen::Vector4d base = c->map->configuration(zero);
  for (Eigen::Index i = 0; i < 4; ++i) {
    const auto& j = rc.joints[static_cast<std::size_t>(i)];
    double slope = 1.0;
    if (i >= 2) {
      Eigen::Vector4d dq = zero;
      dq[i] = 1e-3;
      slope = std::abs(c->map->configuration(dq)[i] - base[i]) / 1e-3;
      if (!(slope > 0) || !std::isfinite(slope))
        throw ConfigError(file + ": catheter.model: the bend of joint '" + j.name +
                          "' does not change with its drive (zero slope): configuration control cannot work");
    }
    // 10 % headroom on the bends: the coupling term adds to the distal drive's rate.
    const double headroom = i >= 2 ? 0.9 : 1.0;
    c->psi_max_velocity[i] = headroom * j.max_velocity * slope;
    c->psi_max_acceleration[i] = headroom * j.max_acceleration * slope;
  }
  c->configuration = std::make_unique<teleop::ConfigurationSpaceController>(*c->map, c->psi_max_velocity,
                                                                            c->psi_max_acceleration);

  // Spring-deflection potentiometers and the analog joystick: CiA 401 ADC nodes on the bend drives' bus.
  const auto& d = c->settings.deflection;
  canopen::AnalogInputSetup deflection_setup;
  deflection_setup.node_id = d.node_id;
  deflection_setup.stale_after_ns = static_cast<std::int64_t>(d.stale_ms * 1e6);
  c->deflection_receiver = std::make_unique<canopen::AnalogInputReceiver>(deflection_setup);
  if (c->settings.analog_joystick)
    c->joystick_receiver = std::make_unique<input::AnalogJoystickReceiver>(*c->settings.analog_joystick);
  CatheterUnit* unit = c.get();
  bus.frame_listeners.emplace_back(
      [unit](const can::Frame& frame, std::chrono::steady_clock::time_point now) {
        const std::int64_t now_ns =
            std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
        unit->bus_heard_ns.store(now_ns, std::memory_order_relaxed);
        if (unit->deflection_receiver->handle(frame, now_ns)) {
          const auto reading = unit->deflection_receiver->reading(now_ns);
          DeflectionReading out;
          const double centre = 0.5 * canopen::AnalogInputSetup{}.supply_volts;
          const double gain = unit->settings.deflection.volts_per_mm;
          out.valid = true;
          for (std::size_t i = 0; i < 2; ++i) {
            out.mm[i] = (reading.volts[i] - centre) / gain;
            out.valid = out.valid && !reading.wiring_fault[i];
          }
          out.stamp_ns = now_ns;
          unit->deflection.store(out);
        } else if (unit->joystick_receiver && unit->joystick_receiver->handle(frame, now_ns)) {
          unit->analog_joystick.store(unit->joystick_receiver->state(now_ns));
        }
      });

  if (c->settings.evdev_joystick) {
    const auto& o = *c->settings.evdev_joystick;
    for (std::size_t j = 0; j < 4; ++j) c->evdev_output[j] = o.mapping.output_index(rc.joints[j].name);
    c->evdev = std::make_unique<input::EvdevJoystick>(o);
  }

  if (bus.virtual_bus) attach_catheter_simulation(*c, rc, bus, bindings);
  return c;
}

void start_catheter_nodes(CatheterUnit& c, BusUnit& bus) {
  // NMT "start remote node" for each ADC node: they send their PDOs only when operational.
  auto start = [&bus](std::uint8_t node) {
    can::Frame f;
    f.id = 0x000;
    f.len = 2;
    f.data[0] = 0x01;
    f.data[1] = node;
    bus.master_endpoint->send(f);
  };
  start(c.settings.deflection.node_id);
  if (c.settings.analog_joystick) start(c.settings.analog_joystick->node_id);
  if (c.evdev) c.evdev->start();
}

}  // namespace tendril::server
