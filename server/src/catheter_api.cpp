// Steerable-catheter API (network threads): configuration goals, the console joystick, and the
// catheter's part of /robots and operating_state.
#include <cctype>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <utility>

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
  robot["spring_deflection_resume_mm"] = c.settings.deflection.resume_mm;
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

// ---- Ways out of a hold ------------------------------------------------------------------------

namespace tendril::server {

namespace {

std::string mm(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f mm", v);
  return buf;
}

// The spring furthest from rest: its index (0 proximal, 1 distal) and |deflection|.
std::pair<int, double> worst_spring(const RobotSnapshot& s) {
  const double a = std::abs(s.spring_deflection[0]), b = std::abs(s.spring_deflection[1]);
  return a >= b ? std::pair{0, a} : std::pair{1, b};
}

constexpr const char* kSpringNames[2] = {"proximal", "distal"};

std::string node_name(const RobotUnit& r) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "ADC node 0x%02X", r.catheter->settings.deflection.node_id);
  return buf;
}

}  // namespace

void catheter_hold_json(const RobotUnit& r, const RobotSnapshot& s, nlohmann::json& hold) {
  const auto& d = r.catheter->settings.deflection;
  const auto [spring, value] = worst_spring(s);
  const std::string which = std::string("the ") + kSpringNames[spring] + " spring";
  const bool fresh = s.deflection_fresh;
  const bool deflection_hold = s.hold_code == safety::FaultCode::kSpringDeflection;
  const double bound = deflection_hold ? d.resume_mm : d.limit_mm;
  const bool cleared = fresh && value <= bound && !s.relaxing;
  const std::string relax_how =
      "relax the springs (the bend drives follow them down to " + mm(0.5 * d.resume_mm) + ")";
  std::string message = hold.value("message", "");
  std::string next = hold.value("next", "");
  if (deflection_hold) {
    hold["cause"] = "spring_deflection";
    message = fresh ? which + " deflected " + mm(value) + " (hold bound " + mm(d.limit_mm) + ")"
                    : "spring deflection over its bound; the sensor now sends no reading";
  } else if (s.hold_code == safety::FaultCode::kSensorStale) {
    hold["cause"] = "sensor_stale";
    message =
        fresh ? "the spring-deflection sensor (" + node_name(r) + ") sent no valid reading; it reads again"
              : "no valid spring-deflection reading from " + node_name(r);
  }
  if (!fresh) {
    next = "Check the spring-deflection sensor (" + node_name(r) +
           ": cable, power); Resume once the gauges read again." +
           (s.retraction_only ? " Withdrawal (insertion backwards) is allowed meanwhile." : "");
  } else if (s.relaxing) {
    next = "Relaxing: the bend drives follow their springs until both are within " + mm(0.5 * d.resume_mm) +
           " (now " + mm(value) + "). Pause stops it.";
  } else if (value > bound) {
    const bool stuck =
        s.relax_outcome == RelaxOutcome::timed_out || s.relax_outcome == RelaxOutcome::at_limit;
    next = (deflection_hold
                ? std::string()
                : "Resume would hold again at once: " + which + " is deflected " + mm(value) + ". ") +
           "Resume needs both springs within " + mm(bound) + ": " +
           (stuck ? "the last relax stopped short (" + std::string(to_string(s.relax_outcome)) +
                        "), so withdraw the catheter (insertion backwards) and Relax again; then Resume."
                  : relax_how + (s.retraction_only ? " or withdraw the catheter (insertion backwards)" : "") +
                        "; then Resume.");
  } else if (s.hold_code != safety::FaultCode::kNone) {
    next = "The cause has cleared (" + which + " " + mm(value) + "): Resume to continue.";
  }
  if (!next.empty()) next[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(next[0])));
  auto allowed = nlohmann::json::array();
  if (cleared) allowed.push_back("resume");
  if (fresh && value > d.resume_mm && !s.relaxing) allowed.push_back("relax");
  if (s.retraction_only) allowed.push_back("withdraw");
  hold["message"] = message;
  hold["next"] = next;
  hold["cleared"] = cleared;
  hold["allowed"] = allowed;
  hold["resume_bound_mm"] = bound;
  hold["withdraw"] = {{"running", s.withdrawing}};
  hold["relax"] = {
      {"running", s.relaxing},
      {"outcome", s.relax_outcome == RelaxOutcome::none ? nlohmann::json(nullptr)
                                                        : nlohmann::json(to_string(s.relax_outcome))}};
}

std::optional<ApiResult> catheter_resume_refusal(const RobotUnit& r, const RobotSnapshot& s) {
  if (s.state != OperatingState::kPaused) return std::nullopt;
  const auto& d = r.catheter->settings.deflection;
  const std::string robot = r.config.name;
  const std::string held = s.hold_code == safety::FaultCode::kNone
                               ? std::string("paused by the operator")
                               : std::string("held: ") + safety::to_string(s.hold_code);
  if (!s.deflection_fresh)
    return ApiResult::error(
        409, "hold_not_cleared",
        "cannot resume robot '" + robot + "' (" + held +
            "): there is no valid spring-deflection reading from " + node_name(r) +
            ", so it would hold again at once; check the sensor's cable and power and resume "
            "once it reads again" +
            (s.retraction_only ? " (withdrawal is allowed meanwhile)" : ""));
  const auto [spring, value] = worst_spring(s);
  const bool deflection_hold = s.hold_code == safety::FaultCode::kSpringDeflection;
  const double bound = deflection_hold ? d.resume_mm : d.limit_mm;
  if (s.relaxing)
    return ApiResult::error(409, "hold_not_cleared",
                            "cannot resume robot '" + robot + "' yet: the springs are relaxing (the " +
                                kSpringNames[spring] + " at " + mm(value) + ", resume at " + mm(d.resume_mm) +
                                "); wait until the relax ends");
  if (value <= bound) return std::nullopt;
  return ApiResult::error(409, "hold_not_cleared",
                          "cannot resume robot '" + robot + "' (" + held + "): the " + kSpringNames[spring] +
                              " spring is deflected " + mm(value) + ", over the " +
                              (deflection_hold ? "resume bound " : "hold bound ") + mm(bound) +
                              "; relax the springs first (POST /api/v1/robots/" + robot +
                              "/state_command {\"command\": \"relax\"})" +
                              (s.retraction_only ? " or withdraw the catheter" : ""));
}

ApiResult relax_springs(RobotUnit& r, const RobotSnapshot& s) {
  const auto& d = r.catheter->settings.deflection;
  const std::string robot = r.config.name;
  if (s.estop)
    return ApiResult::error(409, "estop_latched",
                            "the e-stop is latched; reset it (POST /api/v1/estop/reset) first");
  if (s.state != OperatingState::kPaused)
    return ApiResult::error(409, "invalid_state",
                            "relax is a way out of a hold: robot '" + robot + "' is " +
                                safety::to_string(s.state) +
                                ", not held (PAUSED); in active_compliance mode the bend drives follow their "
                                "springs anyway");
  if (!s.drives_ready)
    return ApiResult::error(409, "not_enabled", "the drives of robot '" + robot + "' are not ready yet");
  if (!s.deflection_fresh)
    return ApiResult::error(409, "sensor_stale",
                            "relax needs the spring-deflection sensor, and " + node_name(r) +
                                " sends no valid reading; check its cable and power");
  if (s.relaxing)
    return ApiResult::success({{"state", "PAUSED"}, {"relaxing", true}, {"resume_bound_mm", d.resume_mm}},
                              202);
  const auto [spring, value] = worst_spring(s);
  if (value <= d.resume_mm)
    return ApiResult::error(409, "already_relaxed",
                            std::string("both springs are within ") + mm(d.resume_mm) + " already (the " +
                                kSpringNames[spring] + " at " + mm(value) + "): resume");
  RobotCommand cmd;
  cmd.kind = CommandKind::relax;
  cmd.received = std::chrono::steady_clock::now();
  if (!r.mailbox.push(cmd)) {
    r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
    return ApiResult::error(
        503, "control_busy",
        "the control loop of '" + robot + "' is not taking commands fast enough; try again");
  }
  return ApiResult::success({{"state", "PAUSED"},
                             {"relaxing", true},
                             {"resume_bound_mm", d.resume_mm},
                             {"timeout_s", d.relax_timeout_s}},
                            202);
}

ApiResult withdraw_catheter(RobotUnit& r, const RobotSnapshot& s, const nlohmann::json& body) {
  const std::string robot = r.config.name;
  constexpr double kMaxDistanceMm = 10.0;  // one press; more is more presses, each a deliberate act
  if (!body.contains("distance_mm") || !body["distance_mm"].is_number())
    return ApiResult::error(400, "bad_request",
                            "expected {\"command\": \"withdraw\", \"distance_mm\": d} with 0 < d <= 10");
  const double distance = body["distance_mm"].get<double>();
  if (!std::isfinite(distance) || distance <= 0.0 || distance > kMaxDistanceMm)
    return ApiResult::error(422, "out_of_range", "distance_mm must be greater than 0 and at most 10 mm");
  if (s.estop)
    return ApiResult::error(409, "estop_latched",
                            "the e-stop is latched; reset it (POST /api/v1/estop/reset) first");
  if (s.state != OperatingState::kPaused || !s.retraction_only)
    return ApiResult::error(409, "invalid_state",
                            "withdraw is the way out of a limit hold: robot '" + robot + "' is " +
                                safety::to_string(s.state) +
                                (s.state == OperatingState::kPaused ? " by the operator" : "") +
                                "; move the insertion in joint mode or with a joystick instead");
  if (!s.drives_ready)
    return ApiResult::error(409, "not_enabled", "the drives of robot '" + robot + "' are not ready yet");
  const auto& insertion = r.config.joints[0];
  const double lowest = std::max(insertion.lower + insertion.soft_margin, r.operating_limits.load().lower[0]);
  const double to = std::max(s.setpoint[0] - distance, lowest);
  if (!(to < s.setpoint[0]))
    return ApiResult::error(
        422, "out_of_limits",
        "the insertion is at its lower limit (" + mm(lowest) + "): nothing left to withdraw");
  RobotCommand cmd;
  cmd.kind = CommandKind::withdraw;
  cmd.count = 1;
  cmd.values[0] = to;
  cmd.received = std::chrono::steady_clock::now();
  if (!r.mailbox.push(cmd)) {
    r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
    return ApiResult::error(
        503, "control_busy",
        "the control loop of '" + robot + "' is not taking commands fast enough; try again");
  }
  return ApiResult::success({{"state", "PAUSED"}, {"withdrawing_to_mm", to}}, 202);
}

}  // namespace tendril::server
