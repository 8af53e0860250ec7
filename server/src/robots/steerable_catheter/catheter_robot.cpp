// The steerable catheter's robot type and the building of one catheter robot: model, controller,
// sensor and joystick inputs wired to the bus of its bend drives. The simulated plant is in
// catheter_simulation.cpp, the control cycle in catheter_controller.cpp, the API in catheter_api.cpp.
#include "steerable_catheter/catheter_robot.hpp"

#include <cmath>
#include <cstdio>
#include <numbers>

#include "steerable_catheter/catheter_simulation.hpp"
#include "steerable_catheter/image_guidance.hpp"
#include "steerable_catheter/planning_service.hpp"
#include "steerable_catheter/steerable_catheter_schema.hpp"
#include "tendril/drivers/canopen/bus_load.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/robot_api_extension.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {

namespace {

std::string mm(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f mm", v);
  return buf;
}

class SteerableCatheterType final : public RobotType {
 public:
  std::string kind() const override { return "steerable_catheter"; }
  std::string description() const override {
    return "steerable robotic microcatheter (Abah 2022, ch. 4): insertion, roll and two bend drives with "
           "series-elastic spring sensing";
  }
  nlohmann::json settings_schema() const override {
    static const nlohmann::json schema = nlohmann::json::parse(schema_files::k_steerable_catheter);
    return schema;
  }
  std::optional<sim::DriveParameters> simulated_drive(const std::string& preset,
                                                      const JointConfig& joint) const override {
    // The SRMC's drive hardware: Velmex lead screws on the bends; the insertion stage and roll gear
    // as assumed in drivers/sim/README.md.
    if (preset == "srmc_insertion") return sim::DriveParameters::srmc_insertion(joint.name());
    if (preset == "srmc_roll") return sim::DriveParameters::srmc_roll(joint.name());
    if (preset == "srmc_bend") return sim::DriveParameters::srmc_bend(joint.name());
    return std::nullopt;
  }
  std::unique_ptr<RobotPlugin> create(const RobotConfig& config, RobotAssembly& assembly) const override {
    return std::make_unique<SteerableCatheter>(config, assembly);
  }
  std::unique_ptr<PlanningApi> planning_service(const std::vector<RobotConfig>& robots) const override {
    return std::make_unique<PlanningService>(robots);
  }
};

}  // namespace

void register_steerable_catheter(RobotTypes& types) { types.add(std::make_unique<SteerableCatheterType>()); }

SteerableCatheter::SteerableCatheter(const RobotConfig& rc, RobotAssembly& assembly)
    : config_(rc), guidance_(std::make_unique<ImageGuidance>(*this)) {
  const std::string file = rc.file.string();
  // The kinematic model first: its error names the model that needs the four joints.
  display_ = make_catheter_display_model(rc.settings.value("kinematics", nlohmann::json::object()),
                                         rc.joints.size(), file);
  settings_ = parse_catheter_settings(rc);
  if (const auto it = rc.settings.find("kinematics"); it != rc.settings.end()) {
    const auto g = it->find("bend_gain_rad_per_mm");
    if (g != it->end() && g->is_array() && g->size() == 2)
      for (std::size_t i = 0; i < 2; ++i)
        if ((*g)[i].is_number() && (*g)[i].get<double>() != 0) display_gains_[i] = (*g)[i].get<double>();
  }
  if (settings_.calibrated_shape) {
    // Draw the model the robot uses: with a calibrated shape matrix that is no longer constant curvature.
    modal_display_.emplace(assembled_shape(settings_));
    display_ = make_modal_catheter_display_model(assembled_shape(settings_),
                                                 rc.settings.value("kinematics", nlohmann::json::object()));
  }
  // The passive shaft lies along the scene's vessel when the catheter is in it (issue 31; vessel_shaft.hpp):
  // the scene has a vessel, and a simulated plant, if configured with a vessel, touches that one.
  const auto& scene = assembly.scene_vessel();
  const bool other_channel = settings_.simulation.vessel && !settings_.simulation.vessel->from_scene;
  if (!scene.empty() && !other_channel) {
    try {
      const auto placed =
          teleop::transformed(scene.front(), teleop::placement_at_entry(scene.front(), *vessel_entry()));
      shaft_.emplace(placed, settings_.nominal.proximal.length + settings_.nominal.distal.length);
    } catch (const std::exception& e) {
      throw ConfigError(file + ": the scene vessel, along which the catheter's shaft lies: " + e.what());
    }
    display_ = make_shaft_display_model(std::move(display_), *shaft_,
                                        rc.settings.value("kinematics", nlohmann::json::object()));
  }
  try {
    map_ = std::make_unique<teleop::CatheterConfigurationMap>(settings_.nominal, settings_.rates);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": catheter.model: " + e.what());
  }
  // ψ bounds for the configuration quintic: insertion and roll as configured; a bend angle may move as
  // fast as its drive's limit allows through the map's slope at the straight pose (the slope is
  // constant for the m = 2 models of the dissertation), less 10 % for the coupling.
  const Eigen::Vector4d zero = Eigen::Vector4d::Zero();
  const Eigen::Vector4d base = map_->configuration(zero);
  for (Eigen::Index i = 0; i < 4; ++i) {
    const auto& j = rc.joints[static_cast<std::size_t>(i)].limit;
    double slope = 1.0;
    if (i >= 2) {
      Eigen::Vector4d dq = zero;
      dq[i] = 1e-3;
      slope = std::abs(map_->configuration(dq)[i] - base[i]) / 1e-3;
      if (!(slope > 0) || !std::isfinite(slope))
        throw ConfigError(file + ": catheter.model: the bend of joint '" + j.name +
                          "' does not change with its drive (zero slope): configuration control cannot work");
    }
    // 10 % headroom on the bends: the coupling term adds to the distal drive's rate.
    const double headroom = i >= 2 ? 0.9 : 1.0;
    psi_max_velocity_[i] = headroom * j.max_velocity * slope;
    psi_max_acceleration_[i] = headroom * j.max_acceleration * slope;
  }
  configuration_ =
      std::make_unique<teleop::ConfigurationSpaceController>(*map_, psi_max_velocity_, psi_max_acceleration_);

  // Spring-deflection potentiometers and the analog joystick: CiA 401 ADC nodes on the bend drives' bus.
  const std::string bus_name = assembly.joint_bus(2);
  if (bus_name.empty())
    throw ConfigError(
        file +
        ": joints[2].drive: the steerable catheter's sensors sit on the bus of its bend drives, "
        "which need CiA 402 drives");
  auto bus = assembly.bus(bus_name);
  const auto& d = settings_.deflection;
  bus.claim_node(d.node_id, "catheter.spring_deflection.node_id", "spring-deflection ADC");
  if (settings_.analog_joystick)
    bus.claim_node(settings_.analog_joystick->node_id, "catheter.joysticks.analog.node_id",
                   "analog joystick ADC");
  canopen::AnalogInputSetup deflection_setup;
  deflection_setup.node_id = d.node_id;
  deflection_setup.stale_after_ns = static_cast<std::int64_t>(d.stale_ms * 1e6);
  deflection_receiver_ = std::make_unique<canopen::AnalogInputReceiver>(deflection_setup);
  if (settings_.analog_joystick)
    joystick_receiver_ = std::make_unique<input::AnalogJoystickReceiver>(*settings_.analog_joystick);
  bus.listen([this](const can::Frame& frame, std::chrono::steady_clock::time_point now) {
    const std::int64_t now_ns =
        std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
    bus_heard_ns_.store(now_ns, std::memory_order_relaxed);
    if (deflection_receiver_->handle(frame, now_ns)) {
      const auto reading = deflection_receiver_->reading(now_ns);
      DeflectionReading out;
      const double centre = 0.5 * canopen::AnalogInputSetup{}.supply_volts;
      const double gain = settings_.deflection.volts_per_mm;
      out.valid = true;
      for (std::size_t i = 0; i < 2; ++i) {
        out.mm[i] = (reading.volts[i] - centre) / gain;
        out.valid = out.valid && !reading.wiring_fault[i];
      }
      out.stamp_ns = now_ns;
      deflection_.store(out);
    } else if (joystick_receiver_ && joystick_receiver_->handle(frame, now_ns)) {
      analog_joystick_.store(joystick_receiver_->state(now_ns));
    }
  });
  // The ADC nodes share the bus: each sends a 7-byte TPDO at 100 Hz and a heartbeat at 10 Hz.
  const int nodes = settings_.analog_joystick ? 2 : 1;
  bus.add_load(nodes * (100.0 * canopen::worst_case_frame_bits(7) + 10.0 * canopen::worst_case_frame_bits(1)),
               std::to_string(nodes) + " ADC node(s)");
  // NMT "start remote node" for each ADC node once the bus is up: they send their PDOs only when
  // operational.
  std::vector<std::uint8_t> node_ids{d.node_id};
  if (settings_.analog_joystick) node_ids.push_back(settings_.analog_joystick->node_id);
  bus.on_start([send = bus.send, node_ids] {
    for (const auto node : node_ids) {
      can::Frame f;
      f.id = 0x000;
      f.len = 2;
      f.data[0] = 0x01;
      f.data[1] = node;
      send(f);
    }
  });

  if (settings_.evdev_joystick) {
    const auto& o = *settings_.evdev_joystick;
    for (std::size_t j = 0; j < 4; ++j) evdev_output_[j] = o.mapping.output_index(rc.joints[j].name());
    evdev_ = std::make_unique<input::EvdevJoystick>(o);
  }
  if (bus.simulated) attach_simulation(assembly, bus);
}

std::vector<ModeInfo> SteerableCatheter::modes() const {
  return {{"configuration", "move_configuration goals in ψ = (insertion, roll, θ_L1, θ_L2) through eq. 4.21"},
          {"active_compliance",
           "the bend drives follow their springs (eqs. 4.24-4.26); insertion and roll from servo_jv or a "
           "joystick"},
          {"telemanipulation", "joint velocities from a joystick while its deadman is held"},
          {"image_guided",
           "the operator inserts (servo_jv insertion, a joystick's insertion axis); roll and bends follow "
           "targets replanned along the loaded plan's vessel from the tracked tip on every exposure"}};
}

std::optional<Eigen::Isometry3d> SteerableCatheter::vessel_entry() const {
  Eigen::Isometry3d entry = Eigen::Isometry3d::Identity();
  entry.translation() =
      Eigen::Vector3d(0.0, 0.0, settings_.nominal.proximal.length + settings_.nominal.distal.length);
  return entry;
}

void SteerableCatheter::display_positions(std::span<const double> measured, std::span<double> out) const {
  // The drawn bend is the configuration map's θ_L at what reaches the tubes: the drive position less
  // the spring deflection (drive − carriage), divided by the display model's bend gains.
  const auto s = published_.load();
  const std::array<double, 2> d = s.deflection_fresh ? s.spring_deflection : std::array<double, 2>{};
  if (modal_display_) {
    // The calibrated model's own actuation: the carriages, the distal one shifted by the coupling of
    // eq. 4.15 as the plant shifts it (drivers/sim/srmc_plant.cpp).
    const auto& r = settings_.rates;
    const double coupling = r.coupling_enabled ? r.proximal_outer_radius * std::cos(r.plane_offset) : 0.0;
    const double proximal = measured[2] - d[0];
    const double proximal_bend =
        std::numbers::pi / 2.0 - modal_display_->tip_angle(teleop::CatheterSegment::kProximal, proximal);
    out[0] = measured[0];
    out[1] = measured[1];
    out[2] = proximal;
    out[3] = measured[3] - d[1] + coupling * proximal_bend;
    return;
  }
  const auto psi =
      map_->configuration(Eigen::Vector4d(measured[0], measured[1], measured[2] - d[0], measured[3] - d[1]));
  out[0] = measured[0];
  out[1] = measured[1];
  out[2] = psi[2] / display_gains_[0];
  out[3] = psi[3] / display_gains_[1];
}

std::optional<Status> SteerableCatheter::check_servo(ModeId mode, const OperatingStateView& state,
                                                     std::span<const double> v) const {
  const auto s = published_.load();
  const bool bends_still = v.size() == 4 && v[2] == 0.0 && v[3] == 0.0;
  const std::string& robot = config_.name;
  if (s.retraction_only && state.state == safety::OperatingState::kPaused) {
    // Held after a limit: only withdrawal of the catheter.
    if (!bends_still || v[1] != 0.0 || v[0] > 0.0)
      return Status(ServiceError{
          ErrorKind::conflict, "retraction_only",
          "robot '" + robot + "' is held after a safety limit (" + safety::to_string(s.hold_code) +
              "); only retraction (negative insertion velocity, all else 0) may move it"});
    return Status(Done{});
  }
  if (mode == kImageGuidedMode) {
    if (!bends_still || v[1] != 0.0)
      return Status(
          ServiceError{ErrorKind::conflict, "wrong_mode",
                       "robot '" + robot +
                           "' is in image_guided mode: roll and bends follow the replanned targets, so "
                           "only the insertion velocity may be non-zero"});
    if (state.state != safety::OperatingState::kEnabled)
      return Status(ServiceError{ErrorKind::conflict, "not_enabled",
                                 "robot '" + robot + "' is " + safety::to_string(state.state) +
                                     "; enable it before streaming velocities"});
    return Status(Done{});
  }
  if (mode == kActiveComplianceMode) {
    if (!bends_still)
      return Status(
          ServiceError{ErrorKind::conflict, "wrong_mode",
                       "robot '" + robot +
                           "' is in active_compliance mode: the bend drives follow their springs, so their "
                           "velocities must be 0 (insertion and roll may move)"});
    if (state.state != safety::OperatingState::kEnabled)
      return Status(ServiceError{ErrorKind::conflict, "not_enabled",
                                 "robot '" + robot + "' is " + safety::to_string(state.state) +
                                     "; enable it before streaming velocities"});
    return Status(Done{});
  }
  return std::nullopt;
}

std::optional<ServiceError> SteerableCatheter::resume_refusal(const OperatingStateView& state) const {
  if (state.state != safety::OperatingState::kPaused) return std::nullopt;
  const auto s = published_.load();
  const auto& d = settings_.deflection;
  const std::string& robot = config_.name;
  const std::string held = s.hold_code == safety::FaultCode::kNone
                               ? std::string("paused by the operator")
                               : std::string("held: ") + safety::to_string(s.hold_code);
  char node[48];
  std::snprintf(node, sizeof node, "ADC node 0x%02X", d.node_id);
  if (!s.deflection_fresh)
    return ServiceError{
        ErrorKind::conflict, "hold_not_cleared",
        "cannot resume robot '" + robot + "' (" + held +
            "): there is no valid spring-deflection reading from " + node +
            ", so it would hold again at once; check the sensor's cable and power and resume once it "
            "reads again" +
            (s.retraction_only ? " (withdrawal is allowed meanwhile)" : "")};
  const double a = std::abs(s.spring_deflection[0]), b = std::abs(s.spring_deflection[1]);
  const int spring = a >= b ? 0 : 1;
  const double value = std::max(a, b);
  const char* names[2] = {"proximal", "distal"};
  const bool deflection_hold = s.hold_code == safety::FaultCode::kSpringDeflection;
  const double bound = deflection_hold ? d.resume_mm : d.limit_mm;
  if (s.relaxing)
    return ServiceError{ErrorKind::conflict, "hold_not_cleared",
                        "cannot resume robot '" + robot + "' yet: the springs are relaxing (the " +
                            names[spring] + " at " + mm(value) + ", resume at " + mm(d.resume_mm) +
                            "); wait until the relax ends"};
  if (value <= bound) return std::nullopt;
  return ServiceError{ErrorKind::conflict, "hold_not_cleared",
                      "cannot resume robot '" + robot + "' (" + held + "): the " + names[spring] +
                          " spring is deflected " + mm(value) + ", over the " +
                          (deflection_hold ? "resume bound " : "hold bound ") + mm(bound) +
                          "; relax the springs first (POST /api/v1/robots/" + robot +
                          "/state_command {\"command\": \"relax\"})" +
                          (s.retraction_only ? " or withdraw the catheter" : "")};
}

std::optional<ServiceError> SteerableCatheter::refuse_mode(ModeId mode,
                                                           const OperatingStateView& state) const {
  (void)state;
  const auto s = published_.load();
  if (mode == kActiveComplianceMode && !s.deflection_fresh)
    return ServiceError{
        ErrorKind::conflict, "sensor_stale",
        "robot '" + config_.name + "' has no valid spring-deflection reading; active compliance needs it"};
  if (mode == kImageGuidedMode) {
    if (!guidance_->tracking())
      return ServiceError{ErrorKind::conflict, "no_tracking",
                          "robot '" + config_.name +
                              "' has no tip tracking: image_guided needs the bi-plane imaging with tracking "
                              "on for this robot (server file: imaging.enabled, imaging.robot, "
                              "imaging.tracking.enabled)"};
    const auto path = service_ ? service_->path_following(config_.name) : Result<PathView>(ServiceError{});
    if (!path || !path->loaded || path->vessel.size() < 2)
      return ServiceError{ErrorKind::conflict, "no_plan",
                          "robot '" + config_.name +
                              "' has no loaded plan with a vessel: image_guided replans along the plan's "
                              "vessel; load a plan first (POST /api/v1/robots/" +
                              config_.name + "/path_following {\"plan\": \"<job id>\"})"};
    // The replanner is built here, on the network thread, on the plan loaded now (a plan loaded later
    // takes effect when the mode is entered again).
    return guidance_->prepare(path->vessel);
  }
  return std::nullopt;
}

void SteerableCatheter::start() {
  if (evdev_) evdev_->start();
}

void SteerableCatheter::stop() {
  if (evdev_) evdev_->stop();
}

std::unique_ptr<RobotApiExtension> SteerableCatheter::api(RobotService& service,
                                                          std::function<bool(const PluginCommand&)> post) {
  service_ = &service;
  return make_catheter_api(*this, service, std::move(post));
}

ImageFeedback* SteerableCatheter::image_feedback() { return guidance_.get(); }

}  // namespace tendril::server
