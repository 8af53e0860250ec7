// The steerable catheter's part of the network API (network threads): configuration goals, the
// console joystick, the ways out of a hold (relax, withdraw), and the catheter's fields of /robots,
// operating_state, the scene and the /{robot}/catheter topic.
#include <cctype>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <utility>

#include "steerable_catheter/catheter_robot.hpp"
#include "steerable_catheter/image_guidance.hpp"
#include "steerable_catheter/plan_design.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;
using safety::OperatingState;

constexpr const char* kConfigurationNames[4] = {"insertion", "roll", "theta_proximal", "theta_distal"};
constexpr const char* kSpringNames[2] = {"proximal", "distal"};
// The distance a hold's "withdraw N mm" offers (mm): about a third of the distal segment, enough to take
// the tip back out of the bend that held it (chosen here; Abah 2022 gives none).
constexpr double kSuggestedWithdrawMm = 5.0;

// Why the last relax stopped, in words: "the distal bend drive at its upper limit (4.9 mm)".
std::string relax_stop_words(const CatheterSnapshot& s) {
  if (s.relax_outcome == RelaxOutcome::at_limit && s.relax_limit_joint >= 2) {
    char text[96];
    std::snprintf(text, sizeof text, "the %s bend drive at its %s limit (%.1f mm)",
                  s.relax_limit_joint == 2 ? "proximal" : "distal", s.relax_limit_upper ? "upper" : "lower",
                  s.relax_limit_mm);
    return text;
  }
  if (s.relax_outcome == RelaxOutcome::timed_out) return "it timed out before the springs relaxed";
  return std::string(to_string(s.relax_outcome)).insert(0, "outcome ");
}

json vec(const Eigen::Vector4d& v) { return {v[0], v[1], v[2], v[3]}; }

std::string mm(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f mm", v);
  return buf;
}

ApiResult busy(const std::string& robot) {
  return ApiResult::error(
      503, "control_busy",
      "the control loop of '" + robot + "' is not taking commands fast enough; try again");
}

class CatheterApi final : public RobotApiExtension {
 public:
  CatheterApi(SteerableCatheter& robot, RobotService& service, std::function<bool(const PluginCommand&)> post)
      : robot_(robot), service_(service), post_(std::move(post)) {}

  void describe(json& out) const override {
    const auto& settings = robot_.settings();
    const auto& joints = robot_.config().joints;
    // Configuration-space bounds: the bend angles the joint limits allow (the map is monotonic in q).
    auto lower = json::array(), upper = json::array();
    for (std::size_t i = 0; i < 2; ++i) {
      lower.push_back(joints[i].limit.lower);
      upper.push_back(joints[i].limit.upper);
    }
    for (std::size_t i = 2; i < 4; ++i) {
      Eigen::Vector4d lo = Eigen::Vector4d::Zero(), hi = Eigen::Vector4d::Zero();
      lo[static_cast<Eigen::Index>(i)] = joints[i].limit.lower;
      hi[static_cast<Eigen::Index>(i)] = joints[i].limit.upper;
      const double a = robot_.map().configuration(lo)[static_cast<Eigen::Index>(i)];
      const double b = robot_.map().configuration(hi)[static_cast<Eigen::Index>(i)];
      lower.push_back(std::min(a, b));
      upper.push_back(std::max(a, b));
    }
    out["configuration"] = {{"names", {"insertion", "roll", "theta_proximal", "theta_distal"}},
                            {"units", {"mm", "rad", "rad", "rad"}},
                            {"lower", lower},
                            {"upper", upper}};
    out["spring_deflection_limit_mm"] = settings.deflection.limit_mm;
    out["active_compliance"] = {{"gain", settings.compliance.gain},
                                {"min_speed_mm_s", settings.compliance.min_speed},
                                {"max_speed_mm_s", settings.compliance.max_speed},
                                {"max_deflection_mm", settings.compliance.max_deflection},
                                {"deadband_mm", settings.compliance.deadband}};
    out["telemanipulation_max_speed"] = settings.telemanipulation_max_speed;
    auto sources = json::array({"console"});
    if (robot_.has_evdev()) sources.push_back("evdev");
    if (robot_.has_analog_joystick()) sources.push_back("analog");
    out["joystick_sources"] = sources;
    // Whether the bi-plane imaging images this catheter (tendrild picks the imaged robot; imaged_robot.hpp).
    out["imaged"] = robot_.guidance().tracking();
    // The mounted catheter's design, as the planner reads it from the robot file ("kinematics"): a plan
    // carries the design it was made for, and one made for another catheter is not followable here.
    const auto design = mounted_design();
    out["design"] = design ? design_json(*design) : json(nullptr);  // null: no planning design in the file
  }

  // A plan is followed only by the catheter it was made for (plan_design.hpp). A robot file without a
  // planning design has nothing to compare with: the planner cannot plan for it either, so its plans are
  // written by hand and taken as they are.
  std::optional<ApiResult> refuse_plan(const json& plan) const override {
    const auto mounted = mounted_design();
    if (!mounted) return std::nullopt;
    if (auto refused = plan_design_refusal(plan, *mounted))
      return ApiResult::error(422, refused->code, refused->message);
    return std::nullopt;
  }

  void state(json& out) const override {
    const auto s = robot_.snapshot();
    const auto& settings = robot_.settings();
    out["spring_deflection_mm"] =
        s.deflection_fresh ? json{s.spring_deflection[0], s.spring_deflection[1]} : json(nullptr);
    out["spring_deflection_limit_mm"] = settings.deflection.limit_mm;
    out["configuration"] = vec(robot_.map().configuration(effective_actuation(s)));
    const bool moving = s.mode == kConfigurationMode && s.configuration_moving;
    out["configuration_goal"] = moving
                                    ? vec(Eigen::Vector4d(s.configuration_goal[0], s.configuration_goal[1],
                                                          s.configuration_goal[2], s.configuration_goal[3]))
                                    : json(nullptr);
    out["retraction_only"] = s.retraction_only;
    out["hold_reason"] = s.hold_code != safety::FaultCode::kNone && s.state == OperatingState::kPaused
                             ? json(safety::to_string(s.hold_code))
                             : json(nullptr);
    out["joystick"] = {
        {"source",
         s.joystick_source == JoystickSource::none ? json(nullptr) : json(to_string(s.joystick_source))},
        {"deadman", s.joystick_deadman},
        {"conflict", s.joystick_conflict},
        {"axes", s.joystick_axes}};
    const auto sim = robot_.simulation_view();
    out["contact_force_n"] = sim.present ? json(sim.contact_force_n) : json(nullptr);
    out["max_contact_force_n"] = settings.max_contact_force_n;
    if (sim.present) {
      out["simulation"] = {{"tip_bend_rad", sim.tip_bend_rad},
                           {"peak_contact_force_n", sim.max_contact_force_n}};
      if (sim.true_catheter) out["simulation"]["true_insertion_mm"] = sim.true_insertion_mm;
    }
    // The image_guided mode's loop: null while another mode runs.
    if (s.mode == kImageGuidedMode) {
      const auto g = robot_.guidance().status();
      const bool fix = g.replans > 0;
      out["image_guidance"] = {
          {"status", s.guidance_lost ? "lost" : to_string(g.state)},
          {"reason", g.reason.empty() ? json(nullptr) : json(g.reason)},
          {"tracking_lost", s.guidance_lost},
          {"tracking_age_s", s.guidance_age_s >= 0 ? json(s.guidance_age_s) : json(nullptr)},
          {"replans", g.replans},
          {"drive_insertion_mm", g.drive_insertion_mm},
          {"image_insertion_mm", fix ? json(g.image_insertion_mm) : json(nullptr)},
          {"measured_insertion_mm", fix ? json(g.measured_insertion_mm) : json(nullptr)},
          {"replanned_target", fix ? json(g.target) : json(nullptr)},
          {"tip_mm", fix ? json(g.tip_mm) : json(nullptr)}};
    } else {
      out["image_guidance"] = nullptr;
    }
    if (out.contains("hold") && out["hold"].is_object() && s.state == OperatingState::kPaused)
      hold(s, out["hold"]);
  }

  void scene(json& entities) const override {
    const auto& vessel = robot_.vessel();
    if (vessel.size() < 2 || !entities.is_array() || entities.empty()) return;
    json e = entities[0];  // the backbone entity: same stamp and frame
    auto points = json::array();
    for (const auto& p : vessel) points.push_back(json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
    e["id"] = robot_.config().name + "/simulated_vessel";
    e["metadata"] =
        json::array({{{"key", "lumen_radius_mm"}, {"value", std::to_string(robot_.lumen_radius_mm())}},
                     {{"key", "simulated"}, {"value", "true"}}});
    e["lines"][0]["points"] = std::move(points);
    e["lines"][0]["thickness"] = 2.0 * robot_.lumen_radius_mm();  // the lumen, drawn to scale
    e["lines"][0]["color"] = {{"r", 0.35}, {"g", 0.55}, {"b", 0.95}, {"a", 0.25}};
    entities.push_back(std::move(e));
  }

  std::vector<RobotCommandInfo> commands() const override {
    const json number = {{"type", "number"}};
    return {
        {"move_configuration",
         {{"type", "object"},
          {"properties",
           {{"goal",
             {{"type", "object"},
              {"properties",
               {{"insertion", number},
                {"roll", number},
                {"theta_proximal", number},
                {"theta_distal", number}}}}}}},
          {"required", {"goal"}}},
         false,
         "",
         "configuration mode: a goal in ψ (any subset of insertion mm, roll rad, theta_proximal rad, "
         "theta_distal rad)"},
        {"joystick",
         {{"type", "object"},
          {"properties",
           {{"axes", {{"type", "array"}, {"items", number}}}, {"deadman", {{"type", "boolean"}}}}},
          {"required", {"axes", "deadman"}}},
         true,
         "deadman",
         "the console joystick: axes per joint in -1..1 and the deadman (telemanipulation, active "
         "compliance, "
         "withdrawal while held)"},
        {"relax",
         {{"type", "object"}, {"properties", json::object()}},
         false,
         "",
         "held: the bend drives follow their springs until both are within the resume bound"},
        {"withdraw",
         {{"type", "object"}, {"properties", {{"distance_mm", number}}}, {"required", {"distance_mm"}}},
         false,
         "",
         "held with retraction allowed: withdraw the insertion by distance_mm (0 < d <= 10)"},
    };
  }

  ApiResult command(const std::string& name, const json& body) override {
    if (name == "move_configuration") return move_configuration(body);
    if (name == "joystick") return joystick(body);
    if (name == "relax") return relax();
    if (name == "withdraw") return withdraw(body);
    return ApiResult::error(404, "not_found", "no command " + name);
  }

  std::optional<LiveState> live_state() const override {
    // The catheter's measured values change with sensor noise every tick: they go out on
    // /{robot}/catheter at 10 Hz, so /{robot}/operating_state changes only with the state.
    return LiveState{"catheter",
                     "tendril.CatheterState",
                     10.0,
                     {"configuration", "spring_deflection_mm", "contact_force_n", "simulation",
                      "joystick.axes", "hold.message", "hold.next"}};
  }

 private:
  std::optional<CatheterDesign> mounted_design() const {
    const auto k = robot_.config().settings.find("kinematics");
    return k == robot_.config().settings.end() ? std::nullopt : design_from_kinematics(*k);
  }

  static Eigen::Vector4d effective_actuation(const CatheterSnapshot& s) {
    // What reaches the tubes: the drive position less the spring deflection (drive − carriage).
    return {s.position[0], s.position[1], s.position[2] - s.spring_deflection[0],
            s.position[3] - s.spring_deflection[1]};
  }

  bool post(const PluginCommand& c) const { return post_(c); }

  std::string node_name() const {
    char buf[48];
    std::snprintf(buf, sizeof buf, "ADC node 0x%02X", robot_.settings().deflection.node_id);
    return buf;
  }

  // The hold's wording for the catheter's causes: what persists and the way out.
  void hold(const CatheterSnapshot& s, json& hold) const {
    const auto& d = robot_.settings().deflection;
    const double a = std::abs(s.spring_deflection[0]), b = std::abs(s.spring_deflection[1]);
    const int spring = a >= b ? 0 : 1;
    const double value = std::max(a, b);
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
          fresh ? "the spring-deflection sensor (" + node_name() + ") sent no valid reading; it reads again"
                : "no valid spring-deflection reading from " + node_name();
    }
    if (!fresh) {
      next = "Check the spring-deflection sensor (" + node_name() +
             ": cable, power); Resume once the gauges read again." +
             (s.retraction_only ? " Withdrawal (insertion backwards) is allowed meanwhile." : "");
    } else if (s.relaxing) {
      next = "Relaxing: the bend drives follow their springs until both are within " + mm(0.5 * d.resume_mm) +
             " (now " + mm(value) + "). Pause stops it.";
    } else if (value > bound) {
      char withdraw_text[64];
      std::snprintf(withdraw_text, sizeof withdraw_text, "(insertion backwards, e.g. withdraw %.0f mm)",
                    kSuggestedWithdrawMm);
      const std::string withdraw_words = withdraw_text;
      const bool stuck =
          s.relax_outcome == RelaxOutcome::timed_out || s.relax_outcome == RelaxOutcome::at_limit;
      next =
          (deflection_hold
               ? std::string()
               : "Resume would hold again at once: " + which + " is deflected " + mm(value) + ". ") +
          "Resume needs both springs within " + mm(bound) + ": " +
          (stuck ? "the last relax stopped short (" + relax_stop_words(s) + "), so withdraw the catheter " +
                       withdraw_words + " and Relax again; then Resume."
                 : relax_how + (s.retraction_only ? " or withdraw the catheter (insertion backwards)" : "") +
                       "; then Resume.");
    } else if (s.hold_code != safety::FaultCode::kNone) {
      next = "The cause has cleared (" + which + " " + mm(value) + "): Resume to continue.";
    }
    if (!next.empty()) next[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(next[0])));
    auto allowed = json::array();
    if (cleared) allowed.push_back("resume");
    if (fresh && value > d.resume_mm && !s.relaxing) allowed.push_back("relax");
    if (s.retraction_only) allowed.push_back("withdraw");
    hold["message"] = message;
    hold["next"] = next;
    hold["cleared"] = cleared;
    hold["allowed"] = allowed;
    hold["resume_bound_mm"] = bound;
    // "withdraw N mm": the command that withdraws a chosen distance, with the distance suggested.
    hold["withdraw"] = {{"running", s.withdrawing},
                        {"suggested_mm", kSuggestedWithdrawMm},
                        {"command", {{"command", "withdraw"}, {"distance_mm", kSuggestedWithdrawMm}}}};
    hold["relax"] = {{"running", s.relaxing},
                     {"outcome", s.relax_outcome == RelaxOutcome::none ? json(nullptr)
                                                                       : json(to_string(s.relax_outcome))}};
    if (s.relax_outcome == RelaxOutcome::at_limit && s.relax_limit_joint >= 2)
      hold["relax"]["limit"] = {
          {"joint", robot_.config().joints[static_cast<std::size_t>(s.relax_limit_joint)].name()},
          {"side", s.relax_limit_upper ? "upper" : "lower"},
          {"limit_mm", s.relax_limit_mm}};
  }

  ApiResult move_configuration(const json& body) {
    const std::string& robot = robot_.config().name;
    if (!body.is_object() || !body.contains("goal") || !body["goal"].is_object() || body["goal"].empty())
      return ApiResult::error(
          400, "bad_request",
          "expected {\"goal\": {\"insertion\": mm, \"roll\": rad, \"theta_proximal\": rad, "
          "\"theta_distal\": rad}} (any of them)");
    const auto s = robot_.snapshot();
    const auto& map = robot_.map();
    // Unnamed entries keep the goal the controller is on (or the current setpoint's configuration).
    Eigen::Vector4d psi =
        map.configuration(Eigen::Vector4d(s.setpoint[0], s.setpoint[1], s.setpoint[2], s.setpoint[3]));
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
      if (!value.is_number())
        return ApiResult::error(400, "bad_request", "goal." + key + " must be a number");
      const double v = value.get<double>();
      if (!std::isfinite(v)) return ApiResult::error(422, "not_finite", "goal." + key + " is not finite");
      psi[index] = v;
    }
    Eigen::Vector4d q;
    if (!map.joints(psi, q)) {
      return ApiResult::error(422, "out_of_limits",
                              "the bend angles (" + std::to_string(psi[2] * 180 / std::numbers::pi) + "°, " +
                                  std::to_string(psi[3] * 180 / std::numbers::pi) +
                                  "°) are not reachable by the calibrated model");
    }
    const auto& joints = robot_.config().joints;
    const char* names[4] = {"insertion", "roll", "theta_proximal", "theta_distal"};
    for (std::size_t i = 0; i < 4; ++i) {
      const auto& j = joints[i].limit;
      const double v = q[static_cast<Eigen::Index>(i)];
      if (v < j.lower || v > j.upper)
        return ApiResult::error(422, "out_of_limits",
                                std::string("goal.") + names[i] + " needs joint '" + j.name + "' at " +
                                    std::to_string(v) + " " + j.unit + ", outside [" +
                                    std::to_string(j.lower) + ", " + std::to_string(j.upper) +
                                    "] (joint limits as in GET /robots; configuration bounds there too)");
    }
    // The operating limits (tightened through parameters).
    for (const auto& p : service_.parameters()) {
      for (std::size_t i = 0; i < 4; ++i) {
        const std::string prefix = "/" + robot + "/" + joints[i].name() + "/";
        const double v = q[static_cast<Eigen::Index>(i)];
        if ((p.name == prefix + "lower" && v < p.value) || (p.name == prefix + "upper" && v > p.value))
          return ApiResult::error(422, "out_of_limits",
                                  "the goal needs joint '" + joints[i].name() + "' at " + std::to_string(v) +
                                      " " + joints[i].unit() + ", outside its operating range (parameters /" +
                                      robot + "/" + joints[i].name() + "/lower and /upper)");
      }
    }
    if (s.mode != kConfigurationMode) {
      const auto state = service_.operating_state(robot);
      return ApiResult::error(
          409, "wrong_mode",
          "robot '" + robot + "' is in " + (state ? state->mode : std::string("another")) +
              " mode; switch to configuration (POST /api/v1/robots/" + robot + "/mode) first");
    }
    const auto state = service_.operating_state(robot);
    if (state && state->estop)
      return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
    if (s.state != OperatingState::kEnabled || !s.drives_ready)
      return ApiResult::error(
          409, "not_enabled",
          "robot '" + robot + "' is " + safety::to_string(s.state) + "; enable it before moving");
    // Duration as the controller will plan it: the same quintic in ψ from the current configuration.
    const Eigen::Vector4d from =
        map.configuration(Eigen::Vector4d(s.setpoint[0], s.setpoint[1], s.setpoint[2], s.setpoint[3]));
    teleop::QuinticInterpolator predict(4);
    predict.reset({from.data(), 4}, 0.0);
    predict.retarget(0.0, {psi.data(), 4}, {robot_.psi_max_velocity().data(), 4},
                     {robot_.psi_max_acceleration().data(), 4});
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(CatheterCommand::move_configuration);
    c.count = 4;
    for (std::size_t i = 0; i < 4; ++i) c.values[i] = psi[static_cast<Eigen::Index>(i)];
    if (!post(c)) return busy(robot);
    return ApiResult::success({{"duration_s", predict.duration()}, {"goal", vec(psi)}, {"joints", vec(q)}},
                              202);
  }

  ApiResult joystick(const json& body) {
    const std::string& robot = robot_.config().name;
    if (!body.is_object() || !body.contains("axes") || !body["axes"].is_array() ||
        !body.contains("deadman") || !body["deadman"].is_boolean())
      return ApiResult::error(
          400, "bad_request",
          "expected {\"axes\": [insertion, roll, proximal_bend, distal_bend] (each -1..1), "
          "\"deadman\": true|false}");
    const auto& axes = body["axes"];
    if (axes.size() != 4)
      return ApiResult::error(422, "wrong_size",
                              "\"axes\" has " + std::to_string(axes.size()) +
                                  " values; expected 4 (insertion, roll, proximal_bend, distal_bend)");
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(CatheterCommand::joystick);
    c.count = 4;
    for (std::size_t i = 0; i < 4; ++i) {
      if (!axes[i].is_number())
        return ApiResult::error(400, "bad_request", "axes[" + std::to_string(i) + "] is not a number");
      const double v = axes[i].get<double>();
      if (!std::isfinite(v) || v < -1.0 || v > 1.0)
        return ApiResult::error(422, "out_of_range", "axes[" + std::to_string(i) + "] must be within -1..1");
      c.values[i] = v;
    }
    c.flag = body["deadman"].get<bool>() ? 1 : 0;
    const auto s = robot_.snapshot();
    // image_guided: the joystick's insertion axis is the operator's share of the loop (the other axes
    // are ignored there; the replanner steers), as an evdev or analog joystick's is.
    if (c.flag != 0 && s.mode != kTelemanipulationMode && s.mode != kActiveComplianceMode &&
        s.mode != kImageGuidedMode && !(s.retraction_only && s.state == OperatingState::kPaused)) {
      const auto state = service_.operating_state(robot);
      return ApiResult::error(
          409, "wrong_mode",
          "robot '" + robot + "' is in " + (state ? state->mode : std::string("another")) +
              " mode; the joystick moves it in telemanipulation (all joints), active_compliance "
              "(insertion and roll) or image_guided (insertion)");
    }
    if (!post(c)) return busy(robot);
    return ApiResult::success({{"command_timeout_ms", robot_.config().command_timeout_ms}});
  }

  ApiResult relax() {
    const std::string& robot = robot_.config().name;
    const auto& d = robot_.settings().deflection;
    const auto s = robot_.snapshot();
    const auto state = service_.operating_state(robot);
    if (state && state->estop)
      return ApiResult::error(409, "estop_latched",
                              "the e-stop is latched; reset it (POST /api/v1/estop/reset) first");
    if (s.state != OperatingState::kPaused)
      return ApiResult::error(
          409, "invalid_state",
          "relax is a way out of a hold: robot '" + robot + "' is " + safety::to_string(s.state) +
              ", not held (PAUSED); in active_compliance mode the bend drives follow their springs "
              "anyway");
    if (!s.drives_ready)
      return ApiResult::error(409, "not_enabled", "the drives of robot '" + robot + "' are not ready yet");
    if (!s.deflection_fresh)
      return ApiResult::error(409, "sensor_stale",
                              "relax needs the spring-deflection sensor, and " + node_name() +
                                  " sends no valid reading; check its cable and power");
    if (s.relaxing)
      return ApiResult::success({{"state", "PAUSED"}, {"relaxing", true}, {"resume_bound_mm", d.resume_mm}},
                                202);
    const double a = std::abs(s.spring_deflection[0]), b = std::abs(s.spring_deflection[1]);
    if (std::max(a, b) <= d.resume_mm)
      return ApiResult::error(409, "already_relaxed",
                              std::string("both springs are within ") + mm(d.resume_mm) + " already (the " +
                                  kSpringNames[a >= b ? 0 : 1] + " at " + mm(std::max(a, b)) + "): resume");
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(CatheterCommand::relax);
    if (!post(c)) return busy(robot);
    return ApiResult::success({{"state", "PAUSED"},
                               {"relaxing", true},
                               {"resume_bound_mm", d.resume_mm},
                               {"timeout_s", d.relax_timeout_s}},
                              202);
  }

  ApiResult withdraw(const json& body) {
    const std::string& robot = robot_.config().name;
    constexpr double kMaxDistanceMm = 10.0;  // one press; more is more presses, each a deliberate act
    if (!body.is_object() || !body.contains("distance_mm") || !body["distance_mm"].is_number())
      return ApiResult::error(400, "bad_request",
                              "expected {\"command\": \"withdraw\", \"distance_mm\": d} with 0 < d <= 10");
    const double distance = body["distance_mm"].get<double>();
    if (!std::isfinite(distance) || distance <= 0.0 || distance > kMaxDistanceMm)
      return ApiResult::error(422, "out_of_range", "distance_mm must be greater than 0 and at most 10 mm");
    const auto s = robot_.snapshot();
    const auto state = service_.operating_state(robot);
    if (state && state->estop)
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
    const auto& insertion = robot_.config().joints[0].limit;
    double lowest = insertion.lower + insertion.soft_margin;
    for (const auto& p : service_.parameters())
      if (p.name == "/" + robot + "/" + insertion.name + "/lower") lowest = std::max(lowest, p.value);
    const double to = std::max(s.setpoint[0] - distance, lowest);
    if (!(to < s.setpoint[0]))
      return ApiResult::error(
          422, "out_of_limits",
          "the insertion is at its lower limit (" + mm(lowest) + "): nothing left to withdraw");
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(CatheterCommand::withdraw);
    c.count = 1;
    c.values[0] = to;
    if (!post(c)) return busy(robot);
    return ApiResult::success({{"state", "PAUSED"}, {"withdrawing_to_mm", to}}, 202);
  }

  SteerableCatheter& robot_;
  RobotService& service_;
  std::function<bool(const PluginCommand&)> post_;
};

}  // namespace

std::unique_ptr<RobotApiExtension> make_catheter_api(SteerableCatheter& robot, RobotService& service,
                                                     std::function<bool(const PluginCommand&)> post) {
  return std::make_unique<CatheterApi>(robot, service, std::move(post));
}

}  // namespace tendril::server
