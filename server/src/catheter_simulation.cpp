// The SIMULATED steerable catheter behind a virtual bus: the series-elastic plant (springs and
// floating carriages on the bend drives, coupling, the vessel wall), the spring-deflection
// potentiometers and the analog joystick as simulated CiA 401 ADC nodes on the same bus.
#include <algorithm>
#include <atomic>
#include <cmath>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"
#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"

namespace tendril::server {

struct CatheterSimulation {
  std::unique_ptr<can::Bus> sensor_endpoint, joystick_endpoint;
  std::unique_ptr<sim::SimulatedAnalogInputNode> sensor_node;
  std::unique_ptr<sim::SimulatedAnalogJoystick> joystick_node;
  std::unique_ptr<sim::CatheterVesselContact> contact;
  std::unique_ptr<sim::SrmcPlant> plant;
};

// Here, where CatheterSimulation is complete.
CatheterUnit::CatheterUnit() = default;
CatheterUnit::~CatheterUnit() {
  if (evdev) evdev->stop();
}

void attach_catheter_simulation(CatheterUnit& c, const RobotConfig& rc, BusUnit& bus,
                                const std::vector<JointBinding>& bindings) {
  const auto& s = c.settings;
  const std::string file = rc.file.string();
  auto simulation = std::make_unique<CatheterSimulation>();
  std::array<sim::SimulatedCia402Drive*, 4> drives{};
  for (std::size_t j = 0; j < 4; ++j) {
    drives[j] = bindings[j].sim;
    if (!drives[j] || bindings[j].bus != &bus)
      throw ConfigError(
          file + ": catheter.simulation: the simulated plant needs all four drives simulated on bus '" +
          bus.config.name + "'");
  }

  sim::AnalogInputNodeParameters sensor;
  sensor.node_id = s.deflection.node_id;
  simulation->sensor_endpoint = bus.virtual_bus->attach("sim:spring-deflection-adc");
  simulation->sensor_node =
      std::make_unique<sim::SimulatedAnalogInputNode>(*simulation->sensor_endpoint, sensor);

  sim::SrmcPlantParameters p;
  p.spring_stiffness = s.simulation.spring_stiffness_n_per_mm;
  p.tube_stiffness = s.simulation.tube_stiffness_n_per_mm;
  p.potentiometer_noise = s.simulation.potentiometer_noise_mm;
  p.coupling_mm_per_rad =
      s.rates.coupling_enabled ? s.rates.proximal_outer_radius * std::cos(s.rates.plane_offset) : 0.0;
  p.potentiometer_volts_per_mm = s.deflection.volts_per_mm;
  p.carriage_damping = s.simulation.carriage_damping_n_s_per_mm;
  p.shape = assembled_shape(s);
  simulation->plant = std::make_unique<sim::SrmcPlant>(drives, p);
  simulation->plant->set_potentiometer_node(simulation->sensor_node.get());
  if (s.simulation.vessel) {
    c.vessel = vessel_centerline(*s.simulation.vessel);
    c.lumen_radius_mm = s.simulation.vessel->lumen_radius_mm;
    sim::CatheterVesselContactParameters cp;
    cp.lumen_radius = c.lumen_radius_mm;
    cp.catheter_radius = s.simulation.catheter_outer_radius_mm;
    cp.wall_stiffness = s.simulation.wall_stiffness_n_per_mm;
    simulation->contact = std::make_unique<sim::CatheterVesselContact>(c.vessel, assembled_shape(s), cp);
    simulation->plant->set_vessel(simulation->contact.get());
  }
  bus.plants.push_back(simulation->plant.get());
  bus.plants.push_back(simulation->sensor_node.get());
  if (s.analog_joystick && s.simulation.analog_joystick_node) {
    sim::AnalogJoystickNodeParameters j;
    j.node_id = s.analog_joystick->node_id;
    simulation->joystick_endpoint = bus.virtual_bus->attach("sim:joystick-adc");
    simulation->joystick_node =
        std::make_unique<sim::SimulatedAnalogJoystick>(*simulation->joystick_endpoint, j);
    bus.plants.push_back(simulation->joystick_node.get());
  }
  c.simulation = std::move(simulation);
}

CatheterSimulationView CatheterUnit::simulation_view() const noexcept {
  CatheterSimulationView v;
  if (!simulation) return v;
  const auto st = simulation->plant->state();
  v.present = true;
  v.contact_force_n = st.contact_force;
  v.max_contact_force_n = st.max_contact_force;
  v.tip_bend_rad = st.tip_bend;
  return v;
}

}  // namespace tendril::server

namespace tendril::server {

sim::SimulatedAnalogJoystick* RobotRuntime::simulated_analog_joystick(const std::string& robot) {
  auto it = impl_->by_name.find(robot);
  if (it == impl_->by_name.end() || !it->second->catheter || !it->second->catheter->simulation)
    return nullptr;
  return it->second->catheter->simulation->joystick_node.get();
}

sim::SimulatedAnalogInputNode* RobotRuntime::simulated_spring_sensor(const std::string& robot) {
  auto it = impl_->by_name.find(robot);
  if (it == impl_->by_name.end() || !it->second->catheter || !it->second->catheter->simulation)
    return nullptr;
  return it->second->catheter->simulation->sensor_node.get();
}

}  // namespace tendril::server
