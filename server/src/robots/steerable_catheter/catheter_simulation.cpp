// The SIMULATED steerable catheter behind a virtual bus: the series-elastic plant (springs and
// floating carriages on the bend drives, coupling, the vessel wall), the spring-deflection
// potentiometers and the analog joystick as simulated CiA 401 ADC nodes on the same bus.
#include <algorithm>
#include <atomic>
#include <cmath>

#include "steerable_catheter/catheter_simulation.hpp"
#include "steerable_catheter/image_guidance.hpp"
#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"

namespace tendril::server {

// Here, where CatheterSimulation is complete.
SteerableCatheter::~SteerableCatheter() {
  if (evdev_) evdev_->stop();
}

void SteerableCatheter::attach_simulation(RobotAssembly& assembly, RobotAssembly::BusAccess& bus) {
  const auto& s = settings_;
  const std::string file = config_.file.string();
  auto simulation = std::make_unique<CatheterSimulation>();
  std::array<sim::SimulatedCia402Drive*, 4> drives{};
  for (std::size_t j = 0; j < 4; ++j) {
    drives[j] = assembly.simulated_drive(j);
    if (!drives[j] || assembly.joint_bus(j) != bus.name)
      throw ConfigError(
          file + ": catheter.simulation: the simulated plant needs all four drives simulated on bus '" +
          bus.name + "'");
  }

  sim::AnalogInputNodeParameters sensor;
  sensor.node_id = s.deflection.node_id;
  simulation->sensor_endpoint = bus.attach("sim:" + config_.name + "/spring-deflection-adc");
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
  // The plant bends as the true catheter does: the model's assembled shape, or with a true_catheter
  // the shape that differs from it (the controller and the planner keep the model).
  const auto& truth = s.simulation.true_catheter;
  const auto plant_shape = truth.enabled ? true_shape(assembled_shape(s), truth) : assembled_shape(s);
  p.shape = plant_shape;
  simulation->plant = std::make_unique<sim::SrmcPlant>(drives, p);
  simulation->plant_kinematics.emplace(plant_shape);
  simulation->plant->set_potentiometer_node(simulation->sensor_node.get());
  // "centerline": "scene" in a server whose scene has no vessel ("vessel": false, or a runtime built
  // without a server file): the catheter moves in free space, as the world has no vessel to touch.
  const bool scene_without_vessel =
      s.simulation.vessel && s.simulation.vessel->from_scene && assembly.scene_vessel().empty();
  if (s.simulation.vessel && !scene_without_vessel) {
    const auto& tube = *s.simulation.vessel;
    lumen_radius_mm_ = tube.lumen_radius_mm;
    sim::CatheterVesselContactParameters cp;
    cp.catheter_radius = s.simulation.catheter_outer_radius_mm;
    cp.wall_stiffness = s.simulation.wall_stiffness_n_per_mm;
    const std::string key = file + ": catheter.simulation.vessel.centerline";
    if (tube.from_scene) {
      // The server's one vessel, where imaging, the vessel map and plans put it: its start at the
      // insertion point. The branch the catheter enters is the first in the file.
      const auto& scene = assembly.scene_vessel();
      teleop::CenterlinePolyline placed;
      try {
        placed =
            teleop::transformed(scene.front(), teleop::placement_at_entry(scene.front(), *vessel_entry()));
      } catch (const std::exception& e) {
        throw ConfigError(key + ": the scene vessel: " + e.what());
      }
      // Before the entry the catheter runs straight up the insertion axis (an introducer, as the path
      // planner's straight extension assumes): that part of the tube is prepended, as wide as the
      // vessel's start, reaching back past the steerable base at zero insertion.
      const Eigen::Isometry3d entry = *vessel_entry();
      const double reach = entry.translation().z() + 1.0;
      const bool with_radii = placed.radii.size() == placed.points.size();
      const double start_radius = with_radii ? placed.radii.front() : tube.lumen_radius_mm;
      vessel_.clear();
      const auto introducer_points = static_cast<int>(std::ceil(reach / 0.5));
      for (int i = introducer_points; i > 0; --i) {
        vessel_.push_back(entry * Eigen::Vector3d(0.0, 0.0, -0.5 * i));
        if (with_radii) cp.lumen_radii.push_back(start_radius);
      }
      vessel_.insert(vessel_.end(), placed.points.begin(), placed.points.end());
      if (with_radii) {
        cp.lumen_radii.insert(cp.lumen_radii.end(), placed.radii.begin(), placed.radii.end());
        lumen_radius_mm_ = *std::min_element(placed.radii.begin(), placed.radii.end());
      }
    } else {
      vessel_ = vessel_centerline(tube);
    }
    cp.lumen_radius = tube.lumen_radius_mm;
    try {
      simulation->contact = std::make_unique<sim::CatheterVesselContact>(vessel_, plant_shape, cp);
    } catch (const std::invalid_argument& e) {
      throw ConfigError(key + ": " + e.what());
    }
    // In the scene's vessel the passive shaft lies along it (issue 31): the plant's steerable section
    // starts on the centerline, as the display, the imaged backbone and the planner put it.
    if (shaft_) simulation->contact->set_shaft(*shaft_);
    simulation->plant->set_vessel(simulation->contact.get());
  }
  bus.add_plant(simulation->plant.get());
  if (truth.enabled) {
    simulation->insertion = std::make_unique<TrueInsertion>(*simulation->plant, truth);
    simulation->true_kinematics.emplace(plant_shape);
    bus.add_plant(simulation->insertion.get());
  }
  bus.add_plant(simulation->sensor_node.get());
  if (s.analog_joystick && s.simulation.analog_joystick_node) {
    sim::AnalogJoystickNodeParameters j;
    j.node_id = s.analog_joystick->node_id;
    simulation->joystick_endpoint = bus.attach("sim:" + config_.name + "/joystick-adc");
    simulation->joystick_node =
        std::make_unique<sim::SimulatedAnalogJoystick>(*simulation->joystick_endpoint, j);
    bus.add_plant(simulation->joystick_node.get());
  }
  simulation_ = std::move(simulation);
}

void TrueInsertion::step(double dt) noexcept {
  (void)dt;
  const double q = plant_.state().q[sim::SrmcPlant::kInsertion];
  if (!started_.load(std::memory_order_relaxed)) {
    s_ = q;  // at start the catheter sits where the drive put it, its slack still to take up
    started_.store(true, std::memory_order_release);
  }
  const double pushed = q - truth_.slack_mm;  // where pushing puts the catheter with the slack taken up
  if (pushed > s_) {
    const double stored = pushed - s_;  // drive travel stored in the buckled shaft
    if (truth_.stick_mm <= 0.0) {
      s_ = pushed;
    } else if (stored >= truth_.stick_mm) {
      s_ += truth_.slip_fraction * stored;
    }
  }
  if (q < s_) s_ = q;  // pulling back drags the catheter with the drive
  inserted_.store(s_, std::memory_order_relaxed);
}

bool SteerableCatheter::true_backbone(std::vector<Eigen::Vector3d>& out) const {
  if (!simulation_ || !simulation_->true_kinematics || !simulation_->insertion ||
      !simulation_->insertion->started())
    return false;
  const auto st = simulation_->plant->state();
  const teleop::ModalCatheterKinematics::JointVector q(simulation_->insertion->inserted_mm(), st.q[1],
                                                       st.carriage[0], st.distal_actuation);
  constexpr std::size_t kPointsPerSegment = 20;
  const auto& kinematics = *simulation_->true_kinematics;
  out.resize(kinematics.backbone_point_count(kPointsPerSegment));
  if (shaft_) {
    const teleop::ModalCatheterKinematics::JointVector at_zero(0.0, q[1], q[2], q[3]);
    out.resize(kinematics.backbone(at_zero, kPointsPerSegment, out));
    shaft_->place(q[0], out);
    return !out.empty();
  }
  out.resize(kinematics.backbone(q, kPointsPerSegment, out));
  return !out.empty();
}

bool SteerableCatheter::simulated_backbone(std::vector<Eigen::Vector3d>& out) const {
  if (true_backbone(out)) return true;
  if (!simulation_ || !simulation_->plant_kinematics) return false;
  const auto st = simulation_->plant->state();
  constexpr std::size_t kPointsPerSegment = 20;
  const auto& kinematics = *simulation_->plant_kinematics;
  out.resize(kinematics.backbone_point_count(kPointsPerSegment));
  const teleop::ModalCatheterKinematics::JointVector q(shaft_ ? 0.0 : st.q[0], st.q[1], st.carriage[0],
                                                       st.distal_actuation);
  out.resize(kinematics.backbone(q, kPointsPerSegment, out));
  if (shaft_) shaft_->place(st.q[0], out);
  return !out.empty();
}

std::optional<double> SteerableCatheter::true_insertion_mm() const noexcept {
  if (!simulation_ || !simulation_->insertion || !simulation_->insertion->started()) return std::nullopt;
  return simulation_->insertion->inserted_mm();
}

CatheterSimulationView SteerableCatheter::simulation_view() const noexcept {
  CatheterSimulationView v;
  if (!simulation_) return v;
  const auto st = simulation_->plant->state();
  v.present = true;
  v.contact_force_n = st.contact_force;
  v.max_contact_force_n = st.max_contact_force;
  v.tip_bend_rad = st.tip_bend;
  if (const auto s = true_insertion_mm()) {
    v.true_catheter = true;
    v.true_insertion_mm = *s;
  }
  return v;
}

sim::SimulatedAnalogJoystick* SteerableCatheter::simulated_analog_joystick() noexcept {
  return simulation_ ? simulation_->joystick_node.get() : nullptr;
}

sim::SimulatedAnalogInputNode* SteerableCatheter::simulated_spring_sensor() noexcept {
  return simulation_ ? simulation_->sensor_node.get() : nullptr;
}

}  // namespace tendril::server
