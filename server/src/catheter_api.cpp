// Steerable-catheter API (network threads): configuration goals, the console joystick, and the
// catheter's part of /robots and operating_state.
#include <cmath>
#include <numbers>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"

namespace tendril::server {

namespace {

using safety::OperatingState;

constexpr const char* kConfigurationNames[4] = {"insertion", "roll", "theta_proximal", "theta_distal"};

Eigen::Vector4d effective_actuation(const RobotSnapshot& s) {
  // What reaches the tubes: the drive position less the spring deflection (drive − carriage).
  return {s.position[0], s.position[1], s.position[2] - s.spring_deflection[0],
          s.position[3] - s.spring_deflection[1]};
}

nlohmann::json vec(const Eigen::Vector4d& v) { return {v[0], v[1], v[2], v[3]}; }

std::array<double, 2> display_gains(const RobotUnit& r) {
  std::array<double, 2> g{1.0, 1.0};
  const auto it = r.config.kinematics.find("bend_gain_rad_per_mm");
  if (it != r.config.kinematics.end() && it->is_array() && it->size() == 2)
    for (std::size_t i = 0; i < 2; ++i)
      if ((*it)[i].is_number() && (*it)[i].get<double>() != 0) g[i] = (*it)[i].get<double>();
  return g;
}

ApiResult unknown(const std::string& robot) {
  return ApiResult::error(404, "unknown_robot", "there is no robot named '" + robot + "'");
}

}  // namespace

void catheter_robot_json(const RobotUnit& r, nlohmann::json& robot) {
  const auto& c = *r.catheter;
  // Configuration-space bounds: the bend angles the joint limits allow (the map is monotonic in q).
  auto lower = nlohmann::json::array(), upper = nlohmann::json::array();
  lower.push_back(r.config.joints[0].lower);
  upper.push_back(r.config.joints[0].upper);
  lower.push_back(r.config.joints[1].lower);
  upper.push_back(r.config.joints[1].upper);
  for (std::size_t i = 2; i < 4; ++i) {
    Eigen::Vector4d lo = Eigen::Vector4d::Zero(), hi = Eigen::Vector4d::Zero();
    lo[static_cast<Eigen::Index>(i)] = r.config.joints[i].lower;
    hi[static_cast<Eigen::Index>(i)] = r.config.joints[i].upper;
    const double a = c.map->configuration(lo)[static_cast<Eigen::Index>(i)];
    const double b = c.map->configuration(hi)[static_cast<Eigen::Index>(i)];
    lower.push_back(std::min(a, b));
    upper.push_back(std::max(a, b));
  }
  robot["configuration"] = {{"names", {"insertion", "roll", "theta_proximal", "theta_distal"}},
                            {"units", {"mm", "rad", "rad", "rad"}},
                            {"lower", lower},
                            {"upper", upper}};
  robot["spring_deflection_limit_mm"] = c.settings.deflection.limit_mm;
  robot["active_compliance"] = {{"gain", c.settings.compliance.gain},
                                {"min_speed_mm_s", c.settings.compliance.min_speed},
                                {"max_speed_mm_s", c.settings.compliance.max_speed},
                                {"max_deflection_mm", c.settings.compliance.max_deflection},
                                {"deadband_mm", c.settings.compliance.deadband}};
  robot["telemanipulation_max_speed"] = c.settings.telemanipulation_max_speed;
  auto sources = nlohmann::json::array({"console"});
  if (c.evdev) sources.push_back("evdev");
  if (c.joystick_receiver) sources.push_back("analog");
  robot["joystick_sources"] = sources;
}

void catheter_state_json(const RobotUnit& r, const RobotSnapshot& s, nlohmann::json& out) {
  const auto& c = *r.catheter;
  out["spring_deflection_mm"] = s.deflection_fresh
                                    ? nlohmann::json{s.spring_deflection[0], s.spring_deflection[1]}
                                    : nlohmann::json(nullptr);
  out["spring_deflection_limit_mm"] = c.settings.deflection.limit_mm;
  out["configuration"] = vec(c.map->configuration(effective_actuation(s)));
  const bool moving = s.mode == ControlMode::configuration && s.configuration_moving;
  out["configuration_goal"] = moving ? vec(Eigen::Vector4d(s.configuration_goal[0], s.configuration_goal[1],
                                                           s.configuration_goal[2], s.configuration_goal[3]))
                                     : nlohmann::json(nullptr);
  out["retraction_only"] = s.retraction_only;
  out["hold_reason"] = s.hold_code != safety::FaultCode::kNone && s.state == OperatingState::kPaused
                           ? nlohmann::json(safety::to_string(s.hold_code))
                           : nlohmann::json(nullptr);
  const auto source = static_cast<JoystickSource>(s.joystick_source);
  out["joystick"] = {{"source", source == JoystickSource::none ? nlohmann::json(nullptr)
                                                               : nlohmann::json(to_string(source))},
                     {"deadman", s.joystick_deadman},
                     {"conflict", s.joystick_conflict},
                     {"axes", s.joystick_axes}};
  const auto sim = c.simulation_view();
  out["contact_force_n"] = sim.present ? nlohmann::json(sim.contact_force_n) : nlohmann::json(nullptr);
  out["max_contact_force_n"] = c.settings.max_contact_force_n;
  if (sim.present)
    out["simulation"] = {{"tip_bend_rad", sim.tip_bend_rad},
                         {"peak_contact_force_n", sim.max_contact_force_n}};
}

void add_catheter_entities(const RobotUnit& r, nlohmann::json& scene) {
  const auto& c = *r.catheter;
  if (c.vessel.size() < 2 || !scene.contains("entities") || scene["entities"].empty()) return;
  nlohmann::json e = scene["entities"][0];  // the backbone entity: same stamp and frame
  auto points = nlohmann::json::array();
  for (const auto& p : c.vessel) points.push_back(nlohmann::json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
  e["id"] = r.config.name + "/simulated_vessel";
  e["metadata"] =
      nlohmann::json::array({{{"key", "lumen_radius_mm"}, {"value", std::to_string(c.lumen_radius_mm)}},
                             {{"key", "simulated"}, {"value", "true"}}});
  e["lines"][0]["points"] = std::move(points);
  e["lines"][0]["thickness"] = 2.0 * c.lumen_radius_mm;  // the lumen, drawn to scale
  e["lines"][0]["color"] = {{"r", 0.35}, {"g", 0.55}, {"b", 0.95}, {"a", 0.25}};
  scene["entities"].push_back(std::move(e));
}

std::vector<double> catheter_display_positions(const RobotUnit& r, const RobotSnapshot& s) {
  const auto psi = r.catheter->map->configuration(effective_actuation(s));
  const auto g = display_gains(r);
  return {s.position[0], s.position[1], psi[2] / g[0], psi[3] / g[1]};
}

ApiResult RobotRuntime::move_configuration(const std::string& robot, const nlohmann::json& body) {
  auto found = impl_->by_name.find(robot);
  if (found == impl_->by_name.end()) return unknown(robot);
  RobotUnit& r = *found->second;
  if (!r.catheter)
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no configuration space");
  if (!body.is_object() || !body.contains("goal") || !body["goal"].is_object() || body["goal"].empty())
    return ApiResult::error(400, "bad_request",
                            "expected {\"goal\": {\"insertion\": mm, \"roll\": rad, \"theta_proximal\": rad, "
                            "\"theta_distal\": rad}} (any of them)");
  const auto s = r.snapshot.load();
  const auto& c = *r.catheter;
  // Unnamed entries keep the goal the controller is on (or the current setpoint's configuration).
  Eigen::Vector4d psi =
      c.map->configuration(Eigen::Vector4d(s.setpoint[0], s.setpoint[1], s.setpoint[2], s.setpoint[3]));
  if (s.configuration_moving)
    psi = {s.configuration_goal[0], s.configuration_goal[1], s.configuration_goal[2],
           s.configuration_goal[3]};
  for (const auto& [key, value] : body["goal"].items()) {
    int index = -1;
    for (int i = 0; i < 4; ++i)
      if (key == kConfigurationNames[i]) index = i;
    if (index < 0)
      return ApiResult::error(400, "bad_request",
                              "unknown configuration entry '" + key +
                                  "'; expected insertion, roll, theta_proximal or theta_distal");
    if (!value.is_number()) return ApiResult::error(400, "bad_request", "goal." + key + " must be a number");
    const double v = value.get<double>();
    if (!std::isfinite(v)) return ApiResult::error(422, "not_finite", "goal." + key + " is not finite");
    psi[index] = v;
  }
  Eigen::Vector4d q;
  if (!c.map->joints(psi, q)) {
    return ApiResult::error(422, "out_of_limits",
                            "the bend angles (" + std::to_string(psi[2] * 180 / std::numbers::pi) + "°, " +
                                std::to_string(psi[3] * 180 / std::numbers::pi) +
                                "°) are not reachable by the calibrated model");
  }
  JointArray joints{};
  for (std::size_t i = 0; i < 4; ++i) joints[i] = q[static_cast<Eigen::Index>(i)];
  if (auto v = r.supervisor->check_goal({joints.data(), 4})) {
    const char* names[4] = {"insertion", "roll", "theta_proximal", "theta_distal"};
    const auto i = static_cast<std::size_t>(v.joint < 0 ? 0 : v.joint);
    return ApiResult::error(422, "out_of_limits",
                            std::string("goal.") + names[i] + " needs " + r.supervisor->describe(v) +
                                " (joint limits as in GET /robots; configuration bounds there too)");
  }
  const OperatingLimits limits = r.operating_limits.load();
  for (std::size_t i = 0; i < 4; ++i)
    if (joints[i] < limits.lower[i] || joints[i] > limits.upper[i])
      return ApiResult::error(422, "out_of_limits",
                              "the goal needs joint '" + r.config.joints[i].name + "' at " +
                                  std::to_string(joints[i]) + " " + r.config.joints[i].unit +
                                  ", outside its operating range (parameters /" + robot + "/" +
                                  r.config.joints[i].name + "/lower and /upper)");
  if (s.mode != ControlMode::configuration)
    return ApiResult::error(409, "wrong_mode",
                            "robot '" + robot + "' is in " + to_string(s.mode) +
                                " mode; switch to configuration (POST /api/v1/robots/" + robot +
                                "/mode) first");
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled || !s.drives_ready)
    return ApiResult::error(
        409, "not_enabled",
        "robot '" + robot + "' is " + safety::to_string(s.state) + "; enable it before moving");
  // Duration as the controller will plan it: the same quintic in ψ from the current configuration.
  const Eigen::Vector4d from =
      c.map->configuration(Eigen::Vector4d(s.setpoint[0], s.setpoint[1], s.setpoint[2], s.setpoint[3]));
  teleop::QuinticInterpolator predict(4);
  predict.reset({from.data(), 4}, 0.0);
  predict.retarget(0.0, {psi.data(), 4}, {c.psi_max_velocity.data(), 4}, {c.psi_max_acceleration.data(), 4});
  RobotCommand cmd;
  cmd.kind = CommandKind::move_configuration;
  cmd.count = 4;
  for (std::size_t i = 0; i < 4; ++i) cmd.values[i] = psi[static_cast<Eigen::Index>(i)];
  cmd.received = std::chrono::steady_clock::now();
  if (!r.mailbox.push(cmd)) {
    r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
    return ApiResult::error(
        503, "control_busy",
        "the control loop of '" + robot + "' is not taking commands fast enough; try again");
  }
  return ApiResult::success({{"duration_s", predict.duration()}, {"goal", vec(psi)}, {"joints", vec(q)}},
                            202);
}

ApiResult RobotRuntime::joystick(const std::string& robot, const nlohmann::json& body) {
  auto found = impl_->by_name.find(robot);
  if (found == impl_->by_name.end()) return unknown(robot);
  RobotUnit& r = *found->second;
  if (!r.catheter)
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' takes no joystick input");
  if (!body.is_object() || !body.contains("axes") || !body["axes"].is_array() || !body.contains("deadman") ||
      !body["deadman"].is_boolean())
    return ApiResult::error(400, "bad_request",
                            "expected {\"axes\": [insertion, roll, proximal_bend, distal_bend] (each -1..1), "
                            "\"deadman\": true|false}");
  const auto& axes = body["axes"];
  if (axes.size() != 4)
    return ApiResult::error(422, "wrong_size",
                            "\"axes\" has " + std::to_string(axes.size()) +
                                " values; expected 4 (insertion, roll, proximal_bend, distal_bend)");
  RobotCommand cmd;
  cmd.kind = CommandKind::joystick;
  cmd.count = 4;
  for (std::size_t i = 0; i < 4; ++i) {
    if (!axes[i].is_number())
      return ApiResult::error(400, "bad_request", "axes[" + std::to_string(i) + "] is not a number");
    const double v = axes[i].get<double>();
    if (!std::isfinite(v) || v < -1.0 || v > 1.0)
      return ApiResult::error(422, "out_of_range", "axes[" + std::to_string(i) + "] must be within -1..1");
    cmd.values[i] = v;
  }
  cmd.index = body["deadman"].get<bool>() ? 1 : 0;
  const auto s = r.snapshot.load();
  if (cmd.index != 0 && s.mode != ControlMode::telemanipulation && s.mode != ControlMode::active_compliance &&
      !(s.retraction_only && s.state == OperatingState::kPaused))
    return ApiResult::error(409, "wrong_mode",
                            "robot '" + robot + "' is in " + to_string(s.mode) +
                                " mode; the joystick moves it in telemanipulation (all joints) or "
                                "active_compliance (insertion and roll)");
  cmd.received = std::chrono::steady_clock::now();
  if (!r.mailbox.push(cmd)) {
    r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
    return ApiResult::error(
        503, "control_busy",
        "the control loop of '" + robot + "' is not taking commands fast enough; try again");
  }
  return ApiResult::success({{"command_timeout_ms", r.config.command_timeout_ms}});
}

}  // namespace tendril::server
