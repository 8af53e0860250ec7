// RobotRuntime's ControlApi: request validation (network threads) and state read-out.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"

namespace tendril::server {

namespace {
using safety::OperatingState;

const char* state_name(OperatingState s) { return safety::to_string(s); }  // API.md names

ApiResult unknown_robot(const std::string& robot) {
  return ApiResult::error(404, "unknown_robot", "there is no robot named '" + robot + "'");
}

// Reads body[key] as an array of exactly n finite numbers.
std::optional<ApiResult> read_vector(const nlohmann::json& body, const char* key, std::size_t n,
                                     const RobotConfig& rc, JointArray& out) {
  if (!body.is_object() || !body.contains(key))
    return ApiResult::error(400, "bad_request",
                            std::string("expected a JSON object with \"") + key + "\": an array of " +
                                std::to_string(n) + " numbers");
  const auto& v = body.at(key);
  if (!v.is_array())
    return ApiResult::error(400, "bad_request", std::string("\"") + key + "\" must be an array of numbers");
  if (v.size() != n) {
    std::string names;
    for (const auto& j : rc.joints) names += (names.empty() ? "" : ", ") + j.name;
    return ApiResult::error(422, "wrong_size",
                            std::string("\"") + key + "\" has " + std::to_string(v.size()) +
                                " values; robot '" + rc.name + "' has " + std::to_string(n) + " joints (" +
                                names + ")");
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!v[i].is_number())
      return ApiResult::error(400, "bad_request",
                              std::string("\"") + key + "\"[" + std::to_string(i) + "] (joint '" +
                                  rc.joints[i].name + "') is not a number");
    out[i] = v[i].get<double>();
    if (!std::isfinite(out[i]))
      return ApiResult::error(422, "not_finite", "joint '" + rc.joints[i].name + "': value is not finite");
  }
  return std::nullopt;
}

nlohmann::json joint_state_json(const RobotUnit& r, const RobotSnapshot& s, double wall_offset,
                                bool setpoint) {
  nlohmann::json names = nlohmann::json::array(), pos = nlohmann::json::array(),
                 vel = nlohmann::json::array(), eff = nlohmann::json::array();
  for (std::size_t i = 0; i < r.n; ++i) {
    names.push_back(r.config.joints[i].name);
    pos.push_back(setpoint ? s.setpoint[i] : s.position[i]);
    vel.push_back(setpoint ? s.setpoint_velocity[i] : s.velocity[i]);
    eff.push_back(setpoint ? 0.0 : s.effort[i]);
  }
  return {{"name", names},
          {"position", pos},
          {"velocity", vel},
          {"effort", eff},
          {"timestamp", wall_offset + s.time}};
}

// The operating limits (tightened through parameters) are checked after the configured ones, so the
// message names the parameter that refused the command.
std::optional<ApiResult> operating_limit_violation(const RobotUnit& r, const OperatingLimits& limits,
                                                   const JointArray& values, bool velocity) {
  for (std::size_t i = 0; i < r.n; ++i) {
    const auto& j = r.config.joints[i];
    std::ostringstream why;
    if (velocity && std::abs(values[i]) > limits.max_velocity[i]) {
      why << "joint '" << j.name << "' velocity " << values[i] << " " << j.unit
          << "/s exceeds the operating limit " << limits.max_velocity[i] << " " << j.unit << "/s (parameter /"
          << r.config.name << "/" << j.name << "/max_velocity)";
    } else if (!velocity && (values[i] < limits.lower[i] || values[i] > limits.upper[i])) {
      why << "joint '" << j.name << "' goal " << values[i] << " " << j.unit
          << " is outside the operating range [" << limits.lower[i] << ", " << limits.upper[i] << "] "
          << j.unit << " (parameters /" << r.config.name << "/" << j.name << "/lower and /upper)";
    } else {
      continue;
    }
    return ApiResult::error(422, "out_of_limits", why.str());
  }
  return std::nullopt;
}

// Path following plays back plans of the shape-error planner, which models the steerable catheter.
bool supports_path_following(const RobotUnit& r) {
  return r.n == 4 && r.config.kinematics.value("model", std::string{}) == "constant_curvature_catheter";
}

// Joint values for the display model (shape, tip pose, scene). A catheter's bends are drawn from
// what the sensors say reaches the tubes (catheter_display_positions).
std::vector<double> positions(const RobotUnit& r, const RobotSnapshot& s) {
  if (r.catheter) return catheter_display_positions(r, s);
  return std::vector<double>(s.position.begin(), s.position.begin() + static_cast<std::ptrdiff_t>(r.n));
}

std::vector<ControlMode> available_modes(const RobotUnit& r) {
  std::vector<ControlMode> modes{ControlMode::joint};
  if (r.catheter)
    modes.insert(modes.end(),
                 {ControlMode::configuration, ControlMode::active_compliance, ControlMode::telemanipulation});
  if (supports_path_following(r)) modes.push_back(ControlMode::path_following);
  return modes;
}

}  // namespace

const char* to_string(ControlMode mode) noexcept {
  switch (mode) {
    case ControlMode::path_following:
      return "path_following";
    case ControlMode::configuration:
      return "configuration";
    case ControlMode::active_compliance:
      return "active_compliance";
    case ControlMode::telemanipulation:
      return "telemanipulation";
    case ControlMode::joint:
      break;
  }
  return "joint";
}

bool parse_control_mode(const std::string& name, ControlMode& mode) noexcept {
  for (auto m : {ControlMode::joint, ControlMode::path_following, ControlMode::configuration,
                 ControlMode::active_compliance, ControlMode::telemanipulation}) {
    if (name == to_string(m)) {
      mode = m;
      return true;
    }
  }
  return false;
}

#define TENDRIL_FIND_ROBOT(name)                                 \
  auto found = impl_->by_name.find(name);                        \
  if (found == impl_->by_name.end()) return unknown_robot(name); \
  RobotUnit& r = *found->second;

nlohmann::json RobotRuntime::robots() const {
  auto out = nlohmann::json::array();
  for (const auto& r : impl_->robots) {
    auto joints = nlohmann::json::array();
    for (const auto& j : r->config.joints)
      joints.push_back(nlohmann::json{{"name", j.name},
                                      {"unit", j.unit},
                                      {"lower", j.lower},
                                      {"upper", j.upper},
                                      {"max_velocity", j.max_velocity},
                                      {"max_acceleration", j.max_acceleration}});
    auto buses = nlohmann::json::array();
    for (const auto& b : impl_->buses)
      if (b->robot == r->config.name)
        buses.push_back(nlohmann::json{{"name", b->config.name},
                                       {"interface", b->config.interface},
                                       {"simulated", b->virtual_bus != nullptr},
                                       {"load", b->load}});
    auto modes = nlohmann::json::array();
    for (auto m : available_modes(*r)) modes.push_back(to_string(m));
    out.push_back(nlohmann::json{{"name", r->config.name},
                                 {"kind", r->config.kind},
                                 {"description", r->config.description},
                                 {"joints", joints},
                                 {"modes", modes},
                                 {"buses", buses},
                                 {"command_timeout_ms", r->config.command_timeout_ms}});
    if (r->catheter) catheter_robot_json(*r, out.back());
  }
  return out;
}

bool RobotRuntime::has_robot(const std::string& robot) const { return impl_->by_name.count(robot) > 0; }

ApiResult RobotRuntime::measured_js(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  return ApiResult::success(joint_state_json(r, r.snapshot.load(), impl_->wall_offset, false));
}

ApiResult RobotRuntime::setpoint_js(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  return ApiResult::success(joint_state_json(r, r.snapshot.load(), impl_->wall_offset, true));
}

ApiResult RobotRuntime::measured_cp(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  const auto s = r.snapshot.load();
  const auto q = positions(r, s);
  const auto pose = r.kinematics->tip(q);
  const auto& o = pose.orientation;
  return ApiResult::success({{"position", {pose.position.x(), pose.position.y(), pose.position.z()}},
                             {"orientation", {o.x(), o.y(), o.z(), o.w()}},
                             {"frame", r.kinematics->frame()},
                             {"timestamp", impl_->wall_offset + s.time}});
}

ApiResult RobotRuntime::shape(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  const auto s = r.snapshot.load();
  auto points = nlohmann::json::array();
  for (const auto& p : r.kinematics->shape(positions(r, s)))
    points.push_back(nlohmann::json::array({p.x(), p.y(), p.z()}));
  return ApiResult::success(
      {{"points", points}, {"frame", r.kinematics->frame()}, {"timestamp", impl_->wall_offset + s.time}});
}

ApiResult RobotRuntime::operating_state(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  const auto s = r.snapshot.load();
  nlohmann::json out = {{"state", state_name(s.state)},
                        {"mode", to_string(s.mode)},
                        {"is_homed", true},
                        {"is_busy", s.busy},
                        {"estop", s.estop},
                        {"drives_ready", s.drives_ready}};
  // The loop-timing policy's record: lost control time (beyond one period) and the bound that faults
  // a moving robot (README, "Control-loop timing").
  out["loop_timing"] = {{"max_lost_control_ms", r.supervisor->options().max_lost_control_time * 1e3},
                        {"lost_max_ms", s.lost_control.max_lost * 1e3},
                        {"lost_max_moving_ms", s.lost_control.max_lost_moving * 1e3},
                        {"stalls_over_bound", s.lost_control.stalls_over_bound},
                        {"stalls_over_bound_at_rest", s.lost_control.stalls_over_bound_at_rest}};
  if (s.state == OperatingState::kFault || s.estop)
    out["fault"] = {
        {"code", safety::to_string(s.fault.code)},
        {"message", std::string(s.fault.text)},
        {"joint", s.fault.joint >= 0
                      ? nlohmann::json(r.config.joints[static_cast<std::size_t>(s.fault.joint)].name)
                      : nlohmann::json(nullptr)}};
  // Why the robot holds and the way out, whenever it is PAUSED.
  if (s.state == OperatingState::kPaused && !s.estop) {
    nlohmann::json hold = {{"cause", "operator_pause"},
                           {"message", "paused by the operator"},
                           {"cleared", true},
                           {"next", "Resume to continue; nothing moves until then."},
                           {"allowed", {"resume"}}};
    if (r.catheter) catheter_hold_json(r, s, hold);
    out["hold"] = std::move(hold);
  } else {
    out["hold"] = nullptr;
  }
  if (r.catheter) {
    catheter_state_json(r, s, out);
    std::lock_guard lock(r.refusal_mutex);
    out["mode_refusal"] = r.mode_refusal;
  }
  return ApiResult::success(out);
}

namespace {
bool post(RobotUnit& r, const RobotCommand& c) {
  if (r.mailbox.push(c)) return true;
  r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
  return false;
}
ApiResult busy_mailbox(const std::string& robot) {
  return ApiResult::error(
      503, "control_busy",
      "the control loop of '" + robot + "' is not taking commands fast enough; try again");
}
}  // namespace

ApiResult RobotRuntime::state_command(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  if (!body.is_object() || !body.contains("command") || !body["command"].is_string())
    return ApiResult::error(400, "bad_request",
                            "expected {\"command\": \"enable\" | \"disable\" | \"pause\" | \"resume\" | "
                            "\"home\" | \"relax\" | \"withdraw\"}");
  const auto cmd = body["command"].get<std::string>();
  if (cmd == "relax") {
    // tendril's way out of a spring-deflection hold (catheter robots), next to the CRTK commands.
    if (!r.catheter)
      return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no springs to relax");
    return relax_springs(r, r.snapshot.load());
  }
  if (cmd == "withdraw") {
    if (!r.catheter)
      return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no held withdrawal");
    return withdraw_catheter(r, r.snapshot.load(), body);
  }
  safety::StateCommand sc;
  if (cmd == "enable")
    sc = safety::StateCommand::kEnable;
  else if (cmd == "disable")
    sc = safety::StateCommand::kDisable;
  else if (cmd == "pause")
    sc = safety::StateCommand::kPause;
  else if (cmd == "resume")
    sc = safety::StateCommand::kResume;
  else if (cmd == "home")
    return ApiResult::error(
        422, "not_supported",
        "robot '" + robot + "' has absolute encoders and needs no homing (is_homed is true)");
  else
    return ApiResult::error(400, "bad_request",
                            "unknown state command '" + cmd +
                                "'; expected enable, disable, pause, resume, home, relax or withdraw");
  const auto s = r.snapshot.load();
  if (s.estop && sc != safety::StateCommand::kDisable)
    return ApiResult::error(409, "estop_latched",
                            "the e-stop is latched; reset it (POST /api/v1/estop/reset) first");
  using OS = OperatingState;
  const bool allowed =
      (sc == safety::StateCommand::kEnable && (s.state == OS::kDisabled || s.state == OS::kEnabled)) ||
      sc == safety::StateCommand::kDisable ||
      (sc == safety::StateCommand::kPause && (s.state == OS::kEnabled || s.state == OS::kPaused)) ||
      (sc == safety::StateCommand::kResume && (s.state == OS::kPaused || s.state == OS::kEnabled));
  if (!allowed) {
    std::string why =
        std::string("cannot ") + cmd + " robot '" + robot + "' while it is " + state_name(s.state);
    if (s.state == OS::kFault)
      why += " (" + std::string(s.fault.text) + "); send disable to acknowledge the fault first";
    return ApiResult::error(409, "invalid_state", why);
  }
  // Resume is refused while the hold's cause persists, with the cause and what to do, rather than
  // accepted and held again at the next tick.
  if (sc == safety::StateCommand::kResume && r.catheter)
    if (auto refusal = catheter_resume_refusal(r, s)) return *refusal;
  RobotCommand c;
  c.kind = CommandKind::state;
  c.state = sc;
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  const OS expected = [&] {
    switch (sc) {
      case safety::StateCommand::kEnable:
        return OS::kEnabled;
      case safety::StateCommand::kDisable:
        return OS::kDisabled;
      case safety::StateCommand::kPause:
        return OS::kPaused;
      case safety::StateCommand::kResume:
        return OS::kEnabled;
    }
    return s.state;  // unknown command value: report the state unchanged
  }();
  return ApiResult::success({{"state", state_name(expected)},
                             {"mode", to_string(s.mode)},
                             {"is_homed", true},
                             {"is_busy", sc == safety::StateCommand::kEnable || s.busy},
                             {"estop", false}});
}

ApiResult RobotRuntime::mode(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  const auto modes = available_modes(r);
  std::string available;
  for (auto m : modes) available += (available.empty() ? "" : ", ") + std::string(to_string(m));
  if (!body.is_object() || !body.contains("mode") || !body["mode"].is_string())
    return ApiResult::error(400, "bad_request", "expected {\"mode\": one of " + available + "}");
  const auto m = body["mode"].get<std::string>();
  ControlMode to{};
  if (!parse_control_mode(m, to) || std::find(modes.begin(), modes.end(), to) == modes.end())
    return ApiResult::error(
        422, "unknown_mode",
        "mode '" + m + "' is not available for robot '" + robot + "' (available: " + available + ")");
  const auto s = r.snapshot.load();
  if (to_string(s.mode) == m) return ApiResult::success({{"mode", m}});
  // Every refusal is kept for operating_state, so a console that did not send the switch sees why.
  auto refuse = [&](int status, const std::string& code, const std::string& why) {
    std::lock_guard lock(r.refusal_mutex);
    r.mode_refusal = {
        {"mode", m}, {"code", code}, {"reason", why}, {"timestamp", impl_->wall_offset + s.time}};
    return ApiResult::error(status, code, why);
  };
  if (s.estop)
    return refuse(409, "estop_latched",
                  "the e-stop is latched; reset it (POST /api/v1/estop/reset) before changing mode");
  if (s.state == OperatingState::kFault)
    return refuse(409, "invalid_state",
                  "robot '" + robot + "' is in fault (" + std::string(s.fault.text) +
                      "); send disable to acknowledge it before changing mode");
  if (s.busy) {
    std::string why = "robot '" + robot + "' is moving";
    if (s.joystick_deadman) why += " (a joystick's deadman is held)";
    return refuse(409, "not_holding", why + "; modes change only while it holds");
  }
  if (s.retraction_only)
    return refuse(409, "held_after_limit",
                  "robot '" + robot + "' is held after a safety limit (" + safety::to_string(s.hold_code) +
                      "); retract if needed, then resume before changing mode");
  if (to == ControlMode::path_following) {
    std::lock_guard lock(r.path_mutex);
    if (!r.path)
      return refuse(409, "no_plan",
                    "no plan is loaded for robot '" + robot + "'; load one first (POST /api/v1/robots/" +
                        robot + "/path_following {\"plan\": \"<job id>\"})");
  }
  if (to == ControlMode::active_compliance && r.catheter && !s.deflection_fresh)
    return refuse(409, "sensor_stale",
                  "robot '" + robot + "' has no valid spring-deflection reading; active compliance needs it");
  {
    std::lock_guard lock(r.refusal_mutex);
    r.mode_refusal = nullptr;
  }
  RobotCommand c;
  c.kind = CommandKind::mode;
  c.index = static_cast<std::int32_t>(to);
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  return ApiResult::success({{"mode", m}});
}

ApiResult RobotRuntime::move_jp(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  RobotCommand c;
  c.kind = CommandKind::move_jp;
  c.count = static_cast<std::uint32_t>(r.n);
  if (auto err = read_vector(body, "goal", r.n, r.config, c.values)) return *err;
  if (auto v = r.supervisor->check_goal({c.values.data(), r.n}))
    return ApiResult::error(422, "out_of_limits", r.supervisor->describe(v));
  const OperatingLimits limits = r.operating_limits.load();
  if (auto why = operating_limit_violation(r, limits, c.values, false)) return *why;
  const auto s = r.snapshot.load();
  if (s.mode != ControlMode::joint)
    return ApiResult::error(409, "wrong_mode",
                            std::string("robot '") + robot + "' is in " + to_string(s.mode) +
                                " mode; switch to joint mode for joint commands");
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled)
    return ApiResult::error(
        409, "not_enabled",
        std::string("robot '") + robot + "' is " + state_name(s.state) + "; enable it before moving");
  // While the drives are still enabling, the goal waits in the control thread and starts when they are.
  // Predict the duration with the same interpolator the control thread will use.
  teleop::QuinticInterpolator predict(r.n);
  predict.reset({s.setpoint.data(), r.n}, 0.0);
  predict.retarget(0.0, {c.values.data(), r.n}, {limits.max_velocity.data(), r.n},
                   {r.max_acceleration.data(), r.n});
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  return ApiResult::success({{"duration_s", predict.duration()}}, 202);
}

ApiResult RobotRuntime::servo_jv(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  RobotCommand c;
  c.kind = CommandKind::servo_jv;
  c.count = static_cast<std::uint32_t>(r.n);
  if (auto err = read_vector(body, "velocity", r.n, r.config, c.values)) return *err;
  if (auto v = r.supervisor->check_velocity({c.values.data(), r.n}))
    return ApiResult::error(422, "out_of_limits", r.supervisor->describe(v));
  if (auto why = operating_limit_violation(r, r.operating_limits.load(), c.values, true)) return *why;
  const auto s = r.snapshot.load();
  const bool bends_still = r.n == 4 && c.values[2] == 0.0 && c.values[3] == 0.0;
  if (s.retraction_only && s.state == OperatingState::kPaused) {
    // Held after a limit: only withdrawal of the catheter.
    if (!bends_still || c.values[1] != 0.0 || c.values[0] > 0.0)
      return ApiResult::error(409, "retraction_only",
                              "robot '" + robot + "' is held after a safety limit (" +
                                  safety::to_string(s.hold_code) +
                                  "); only retraction (negative insertion velocity, all else 0) may move it");
  } else if (s.mode == ControlMode::active_compliance) {
    if (!bends_still)
      return ApiResult::error(409, "wrong_mode",
                              "robot '" + robot +
                                  "' is in active_compliance mode: the bend drives follow their springs, so "
                                  "their velocities must be 0 (insertion and roll may move)");
  } else if (s.mode != ControlMode::joint) {
    return ApiResult::error(409, "wrong_mode",
                            std::string("robot '") + robot + "' is in " + to_string(s.mode) +
                                " mode; switch to joint mode for joint commands");
  }
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (!(s.state == OperatingState::kEnabled || (s.retraction_only && s.state == OperatingState::kPaused)) ||
      !s.drives_ready)
    return ApiResult::error(409, "not_enabled",
                            std::string("robot '") + robot + "' is " + state_name(s.state) +
                                (s.drives_ready ? "" : " and its drives are not ready") +
                                "; enable it before streaming velocities");
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  return ApiResult::success({{"command_timeout_ms", r.config.command_timeout_ms}});
}

ApiResult RobotRuntime::estop() { return estop_from({}); }

ApiResult RobotRuntime::estop_from(const std::string& actor) {
  // The latch is set directly as well as through the mailbox, so a full mailbox cannot delay it; the
  // command carries who pressed it into the event log.
  for (auto& r : impl_->robots) {
    r->supervisor->request_estop();
    RobotCommand c;
    c.kind = CommandKind::estop;
    std::snprintf(c.actor, sizeof c.actor, "%s", actor.c_str());
    c.received = std::chrono::steady_clock::now();
    post(*r, c);
  }
  return ApiResult::success({{"estop", true}});
}

ApiResult RobotRuntime::estop_reset() {
  for (auto& r : impl_->robots) {
    RobotCommand c;
    c.kind = CommandKind::estop_reset;
    c.received = std::chrono::steady_clock::now();
    if (!post(*r, c)) return busy_mailbox(r->config.name);
  }
  return ApiResult::success({{"estop", false}});
}

// ---- Path following -------------------------------------------------------------------------

namespace {
ApiResult no_path_following(const std::string& robot) {
  return ApiResult::error(
      422, "not_supported",
      "robot '" + robot + "' has no path following (plans are made for the steerable catheter)");
}

std::optional<Eigen::Vector3d> read_point(const nlohmann::json& p) {
  if (!p.is_array() || p.size() != 3 || !p[0].is_number() || !p[1].is_number() || !p[2].is_number())
    return std::nullopt;
  Eigen::Vector3d v(p[0].get<double>(), p[1].get<double>(), p[2].get<double>());
  if (!v.allFinite()) return std::nullopt;
  return v;
}
}  // namespace

ApiResult RobotRuntime::load_path(const std::string& robot, const nlohmann::json& plan,
                                  const std::string& plan_id) {
  TENDRIL_FIND_ROBOT(robot)
  if (!supports_path_following(r)) return no_path_following(robot);
  constexpr std::size_t kMaxSteps = 10000;
  if (!plan.is_object() || !plan.contains("steps") || !plan["steps"].is_array() || plan["steps"].empty())
    return ApiResult::error(
        400, "bad_request",
        "expected a plan {\"steps\": [{\"q\": [insertion, roll, proximal_bend, distal_bend]}, …]}");
  const auto& steps = plan["steps"];
  if (steps.size() > kMaxSteps)
    return ApiResult::error(422, "too_many_steps",
                            "the plan has " + std::to_string(steps.size()) + " steps; at most " +
                                std::to_string(kMaxSteps) + " are accepted");
  auto loaded = std::make_shared<LoadedPath>();
  loaded->plan_id = plan_id;
  const OperatingLimits limits = r.operating_limits.load();
  for (std::size_t k = 0; k < steps.size(); ++k) {
    const std::string which = "step " + std::to_string(k);
    JointArray q{};
    if (!steps[k].is_object())
      return ApiResult::error(400, "bad_request", which + ": expected an object with \"q\"");
    if (auto err = read_vector(steps[k], "q", r.n, r.config, q))
      return ApiResult::error(err->status, err->code, which + ": " + err->message);
    if (auto v = r.supervisor->check_goal({q.data(), r.n}))
      return ApiResult::error(422, "out_of_limits", which + ": " + r.supervisor->describe(v));
    if (auto why = operating_limit_violation(r, limits, q, false))
      return ApiResult::error(422, "out_of_limits", which + ": " + why->message);
    // The control loop holds setpoints inside the soft margins, so a step beyond them would never be reached.
    for (std::size_t i = 0; i < r.n; ++i) {
      const auto& j = r.config.joints[i];
      if (q[i] < j.lower + j.soft_margin || q[i] > j.upper - j.soft_margin) {
        std::ostringstream why;
        why << which << ": joint '" << j.name << "' " << q[i] << " " << j.unit
            << " lies within the soft margin (" << j.soft_margin << " " << j.unit << ") of its limits ["
            << j.lower << ", " << j.upper
            << "]; the setpoint is held short of it, so the step could not be reached";
        return ApiResult::error(422, "out_of_limits", why.str());
      }
    }
    loaded->steps.push_back(q);
    if (steps[k].contains("backbone") && steps[k]["backbone"].is_array() && !steps[k]["backbone"].empty())
      if (auto tip = read_point(steps[k]["backbone"].back())) loaded->tips.push_back(*tip);
  }
  if (loaded->tips.size() != loaded->steps.size()) loaded->tips.clear();
  if (plan.contains("vessel_path") && plan["vessel_path"].is_array()) {
    // The scene shows at most ~200 points of the vessel.
    const auto& path = plan["vessel_path"];
    const std::size_t stride = std::max<std::size_t>(1, path.size() / 200);
    for (std::size_t i = 0; i < path.size(); i += stride)
      if (auto p = read_point(path[i])) loaded->vessel.push_back(*p);
  }
  const auto s = r.snapshot.load();
  if (s.busy)
    return ApiResult::error(409, "not_holding",
                            "robot '" + robot + "' is moving; a plan is loaded only while it holds");
  std::shared_ptr<const LoadedPath> previous;
  {
    std::lock_guard lock(r.path_mutex);
    RobotCommand c;
    c.kind = CommandKind::path_loaded;
    c.received = std::chrono::steady_clock::now();
    if (!post(r, c)) return busy_mailbox(robot);
    previous = std::exchange(r.path, loaded);
  }
  // `previous` is freed here, on this network thread.
  return ApiResult::success({{"steps", loaded->steps.size()},
                             {"step", -1},
                             {"plan", plan_id.empty() ? nlohmann::json() : nlohmann::json(plan_id)}});
}

ApiResult RobotRuntime::path_step(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  if (!supports_path_following(r)) return no_path_following(robot);
  const bool by_index = body.is_object() && body.contains("step");
  const bool by_advance = body.is_object() && body.contains("advance");
  if (by_index == by_advance || (by_index && !body["step"].is_number_integer()) ||
      (by_advance && !(body["advance"] == 1 || body["advance"] == -1)))
    return ApiResult::error(400, "bad_request", "expected {\"step\": k} (0-based) or {\"advance\": 1 | -1}");
  const auto s = r.snapshot.load();
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled || !s.drives_ready)
    return ApiResult::error(409, "not_enabled",
                            std::string("robot '") + robot + "' is " + state_name(s.state) +
                                (s.drives_ready ? "" : " and its drives are not ready") +
                                "; enable it before stepping along the plan");
  if (s.mode != ControlMode::path_following)
    return ApiResult::error(409, "wrong_mode",
                            "robot '" + robot + "' is in " + to_string(s.mode) +
                                " mode; switch to path_following (POST /api/v1/robots/" + robot +
                                "/mode) first");
  if (s.busy)
    return ApiResult::error(409, "not_holding",
                            "robot '" + robot + "' is still moving to step " + std::to_string(s.path_target) +
                                "; wait until it holds");
  std::lock_guard lock(r.path_mutex);
  if (!r.path) return ApiResult::error(409, "no_plan", "no plan is loaded for robot '" + robot + "'");
  const auto count = static_cast<std::int64_t>(r.path->steps.size());
  const std::int64_t k =
      by_index ? body["step"].get<std::int64_t>() : s.path_step + body["advance"].get<std::int64_t>();
  if (k < 0 || k >= count) {
    if (by_index)
      return ApiResult::error(422, "out_of_range",
                              "step " + std::to_string(k) + " does not exist; the plan has steps 0.." +
                                  std::to_string(count - 1));
    return ApiResult::error(409, "end_of_plan",
                            k < 0
                                ? "already at the first step of the plan"
                                : "already at the last step of the plan (" + std::to_string(count - 1) + ")");
  }
  RobotCommand c;
  c.kind = CommandKind::path_step;
  c.index = static_cast<std::int32_t>(k);
  c.count = static_cast<std::uint32_t>(r.n);
  c.values = r.path->steps[static_cast<std::size_t>(k)];
  // The operating limits may have been tightened since the plan was loaded.
  const OperatingLimits limits = r.operating_limits.load();
  if (auto why = operating_limit_violation(r, limits, c.values, false))
    return ApiResult::error(422, "out_of_limits", "step " + std::to_string(k) + ": " + why->message);
  teleop::QuinticInterpolator predict(r.n);
  predict.reset({s.setpoint.data(), r.n}, 0.0);
  predict.retarget(0.0, {c.values.data(), r.n}, {limits.max_velocity.data(), r.n},
                   {r.max_acceleration.data(), r.n});
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  return ApiResult::success({{"step", k}, {"duration_s", predict.duration()}}, 202);
}

ApiResult RobotRuntime::path_following(const std::string& robot) const {
  TENDRIL_FIND_ROBOT(robot)
  if (!supports_path_following(r)) return no_path_following(robot);
  const auto s = r.snapshot.load();
  std::lock_guard lock(r.path_mutex);
  return ApiResult::success(
      {{"loaded", r.path != nullptr},
       {"steps", r.path ? r.path->steps.size() : 0},
       {"step", s.path_step},
       {"target", s.path_target},
       {"moving", s.busy},
       {"mode", to_string(s.mode)},
       {"plan", r.path && !r.path->plan_id.empty() ? nlohmann::json(r.path->plan_id) : nlohmann::json()}});
}

void RobotRuntime::operator_lost() {
  for (auto& r : impl_->robots) {
    RobotCommand c;
    c.kind = CommandKind::hold;
    post(*r, c);
  }
}

// ---- Parameters ----------------------------------------------------------------------------
// Writable: "/{robot}/{joint}/lower|upper|max_velocity" and "/{robot}/servo_timeout_s" (operating
// limits, within the configured ones). Read-only: the configured values ("configured_…"),
// max_acceleration, max_tracking_error and soft_margin.

namespace {
nlohmann::json parameter(const std::string& name, double value) {
  return {{"name", name}, {"value", value}, {"type", "float64"}};
}

void robot_parameters(const RobotUnit& r, nlohmann::json& out) {
  const OperatingLimits limits = r.operating_limits.load();
  const std::string prefix = "/" + r.config.name + "/";
  for (std::size_t i = 0; i < r.n; ++i) {
    const auto& j = r.config.joints[i];
    const std::string jp = prefix + j.name + "/";
    out.push_back(parameter(jp + "lower", limits.lower[i]));
    out.push_back(parameter(jp + "upper", limits.upper[i]));
    out.push_back(parameter(jp + "max_velocity", limits.max_velocity[i]));
    out.push_back(parameter(jp + "configured_lower", j.lower));
    out.push_back(parameter(jp + "configured_upper", j.upper));
    out.push_back(parameter(jp + "configured_max_velocity", j.max_velocity));
    out.push_back(parameter(jp + "max_acceleration", j.max_acceleration));
    out.push_back(parameter(jp + "max_tracking_error", j.max_tracking_error));
    out.push_back(parameter(jp + "soft_margin", j.soft_margin));
  }
  out.push_back(parameter(prefix + "servo_timeout_s", limits.servo_timeout_s));
  out.push_back(parameter(prefix + "configured_servo_timeout_s", r.config.command_timeout_ms / 1000.0));
}

enum class LimitField { kLower, kUpper, kMaxVelocity, kServoTimeout };
struct ParameterChange {
  RobotUnit* robot = nullptr;
  std::size_t joint = 0;
  LimitField field = LimitField::kLower;
  std::optional<double> value;  // nullopt: back to the configured value
  std::string name;
};
}  // namespace

nlohmann::json RobotRuntime::parameters() const {
  auto out = nlohmann::json::array();
  for (const auto& r : impl_->robots) robot_parameters(*r, out);
  return out;
}

ApiResult RobotRuntime::set_parameters(const nlohmann::json& list) {
  if (!list.is_array() || list.empty())
    return ApiResult::error(400, "bad_parameter", "expected a non-empty list of {\"name\", \"value\"}");
  std::vector<ParameterChange> changes;
  for (const auto& item : list) {
    if (!item.is_object() || !item.contains("name") || !item["name"].is_string())
      return ApiResult::error(400, "bad_parameter", "every parameter needs a \"name\" string");
    ParameterChange change;
    change.name = item["name"].get<std::string>();
    const auto& name = change.name;
    const auto first = name.find('/', 1);
    const auto last = name.rfind('/');
    RobotUnit* r = nullptr;
    if (!name.empty() && name[0] == '/' && first != std::string::npos) {
      const auto found = impl_->by_name.find(name.substr(1, first - 1));
      if (found != impl_->by_name.end()) r = found->second;
    }
    bool known = false;
    if (r) {
      const std::string leaf = name.substr(last + 1);
      if (first == last) {
        known = leaf == "servo_timeout_s" || leaf == "configured_servo_timeout_s";
        change.field = LimitField::kServoTimeout;
        if (leaf != "servo_timeout_s" && known)
          return ApiResult::error(403, "read_only_parameter", "parameter " + name + " is read-only");
      } else {
        const std::string joint = name.substr(first + 1, last - first - 1);
        for (std::size_t i = 0; i < r->n; ++i)
          if (r->config.joints[i].name == joint) {
            change.joint = i;
            known = true;
          }
        if (known) {
          if (leaf == "lower") {
            change.field = LimitField::kLower;
          } else if (leaf == "upper") {
            change.field = LimitField::kUpper;
          } else if (leaf == "max_velocity") {
            change.field = LimitField::kMaxVelocity;
          } else if (leaf == "configured_lower" || leaf == "configured_upper" ||
                     leaf == "configured_max_velocity" || leaf == "max_acceleration" ||
                     leaf == "max_tracking_error" || leaf == "soft_margin") {
            return ApiResult::error(
                403, "read_only_parameter",
                "parameter " + name + " is read-only (it comes from " + r->config.file.string() + ")");
          } else {
            known = false;
          }
        }
      }
    }
    if (!known)
      return ApiResult::error(404, "unknown_parameter",
                              "no parameter named \"" + name + "\" (getParameters with no names lists them)");
    change.robot = r;
    const auto value = item.find("value");
    if (value != item.end() && !value->is_null()) {
      if (!value->is_number())
        return ApiResult::error(400, "bad_parameter", "parameter " + name + ": value must be a number");
      change.value = value->get<double>();
      if (!std::isfinite(*change.value))
        return ApiResult::error(422, "not_finite", "parameter " + name + ": value is not finite");
    }
    changes.push_back(std::move(change));
  }

  // Per robot, all or nothing: compute the new limits, validate, then publish them in one store.
  std::map<RobotUnit*, OperatingLimits> updated;
  std::vector<std::unique_lock<std::mutex>> locks;
  for (auto& r : impl_->robots) {
    bool touched = false;
    for (const auto& c : changes) touched = touched || c.robot == r.get();
    if (!touched) continue;
    locks.emplace_back(r->limits_write_mutex);
    updated[r.get()] = r->operating_limits.load();
  }
  for (const auto& c : changes) {
    auto& limits = updated[c.robot];
    const auto& jc = c.robot->config.joints[c.joint];
    switch (c.field) {
      case LimitField::kLower:
        limits.lower[c.joint] = c.value.value_or(jc.lower);
        break;
      case LimitField::kUpper:
        limits.upper[c.joint] = c.value.value_or(jc.upper);
        break;
      case LimitField::kMaxVelocity:
        limits.max_velocity[c.joint] = c.value.value_or(jc.max_velocity);
        break;
      case LimitField::kServoTimeout:
        limits.servo_timeout_s = c.value.value_or(c.robot->config.command_timeout_ms / 1000.0);
        break;
    }
  }
  for (auto& [r, limits] : updated) {
    const auto& rc = r->config;
    std::ostringstream why;
    for (std::size_t i = 0; i < r->n && why.tellp() == 0; ++i) {
      const auto& j = rc.joints[i];
      const std::string p = "/" + rc.name + "/" + j.name + "/";
      if (limits.lower[i] < j.lower)
        why << p << "lower " << limits.lower[i] << " " << j.unit << " is below the configured limit "
            << j.lower << " " << j.unit << ": limits may only be tightened";
      else if (limits.upper[i] > j.upper)
        why << p << "upper " << limits.upper[i] << " " << j.unit << " is above the configured limit "
            << j.upper << " " << j.unit << ": limits may only be tightened";
      else if (limits.lower[i] + 2 * j.soft_margin >= limits.upper[i])
        why << p << "lower (" << limits.lower[i] << ") must be below upper (" << limits.upper[i]
            << ") by more than twice the soft margin (" << j.soft_margin << " " << j.unit << ")";
      else if (!(limits.max_velocity[i] > 0) || limits.max_velocity[i] > j.max_velocity)
        why << p << "max_velocity " << limits.max_velocity[i] << " " << j.unit
            << "/s must be above 0 and at most the configured " << j.max_velocity << " " << j.unit << "/s";
    }
    const double configured_timeout = rc.command_timeout_ms / 1000.0;
    if (why.tellp() == 0 &&
        (!(limits.servo_timeout_s >= 0.005) || limits.servo_timeout_s > configured_timeout))
      why << "/" << rc.name << "/servo_timeout_s " << limits.servo_timeout_s
          << " s must be between 0.005 s and the configured " << configured_timeout << " s";
    if (why.tellp() != 0) return ApiResult::error(422, "out_of_range", why.str());
    // Limits change only while the robot holds inside them, so no running motion is cut short.
    const auto s = r->snapshot.load();
    if (s.busy)
      return ApiResult::error(409, "not_holding",
                              "robot '" + rc.name + "' is moving; limits change only while it holds");
    for (std::size_t i = 0; i < r->n; ++i) {
      if (s.setpoint[i] < limits.lower[i] || s.setpoint[i] > limits.upper[i])
        return ApiResult::error(422, "out_of_range",
                                "joint '" + rc.joints[i].name + "' of robot '" + rc.name + "' is at " +
                                    std::to_string(s.setpoint[i]) + " " + rc.joints[i].unit +
                                    ", outside the new range; move it inside first");
    }
  }
  for (auto& [r, limits] : updated) r->operating_limits.store(limits);
  auto all = parameters();
  auto out = nlohmann::json::array();
  for (const auto& p : all)
    for (const auto& c : changes)
      if (p["name"] == c.name) {
        out.push_back(p);
        break;
      }
  return ApiResult::success(out);
}

void RobotRuntime::Impl::collect_events() const {
  std::lock_guard lock(events_mutex);
  for (const auto& r : robots) {
    r->supervisor->events().drain([&](const safety::SafetyEvent& e) {
      nlohmann::json j = {{"time", wall_offset + e.time},      {"robot", r->config.name},
                          {"kind", safety::to_string(e.kind)}, {"code", safety::to_string(e.code)},
                          {"from", state_name(e.from)},        {"to", state_name(e.to)},
                          {"message", std::string(e.text)}};
      if (e.joint >= 0 && static_cast<std::size_t>(e.joint) < r->n)
        j["joint"] = r->config.joints[static_cast<std::size_t>(e.joint)].name;
      events.push_back(std::move(j));
      ++events_total;
      if (events.size() > 1000) events.pop_front();
    });
  }
}

nlohmann::json RobotRuntime::faults(std::size_t max_events) const {
  impl_->collect_events();
  std::lock_guard lock(impl_->events_mutex);
  auto out = nlohmann::json::array();
  for (auto it = impl_->events.rbegin(); it != impl_->events.rend() && out.size() < max_events; ++it)
    out.push_back(*it);
  return out;
}

std::string RobotRuntime::metrics() const {
  std::ostringstream m;
  const auto ls = impl_->control_thread.statistics();
  m << "# HELP tendril_control_cycles_total Control loop cycles run.\n# TYPE tendril_control_cycles_total "
       "counter\n"
    << "tendril_control_cycles_total " << impl_->ticks.load() << "\n";
  m << "# HELP tendril_control_overruns_total Control cycles that ran past their deadline.\n"
       "# TYPE tendril_control_overruns_total counter\ntendril_control_overruns_total "
    << ls.overruns << "\n";
  m << "# HELP tendril_control_late_cycles_total Control cycles that started a full period or more late "
       "(at least one cycle missed).\n# TYPE tendril_control_late_cycles_total counter\n"
       "tendril_control_late_cycles_total "
    << ls.late_cycles << "\n";
  m << "# HELP tendril_control_lost_time_max_us Longest time the control loop went without a cycle, "
       "beyond one period (microseconds).\n# TYPE tendril_control_lost_time_max_us gauge\n"
       "tendril_control_lost_time_max_us "
    << ls.lost_max_us << "\n";
  m << "# HELP tendril_control_period_error_us Absolute control period error (microseconds).\n"
       "# TYPE tendril_control_period_error_us gauge\n"
    << "tendril_control_period_error_us{quantile=\"0.5\"} " << ls.period_error_p50_us << "\n"
    << "tendril_control_period_error_us{quantile=\"0.99\"} " << ls.period_error_p99_us << "\n"
    << "tendril_control_period_error_us{quantile=\"1\"} " << ls.period_error_max_us << "\n";
  m << "# HELP tendril_control_work_us Control cycle compute time (microseconds).\n"
       "# TYPE tendril_control_work_us gauge\n"
    << "tendril_control_work_us{quantile=\"0.5\"} " << ls.work_p50_us << "\n"
    << "tendril_control_work_us{quantile=\"0.99\"} " << ls.work_p99_us << "\n"
    << "tendril_control_work_us{quantile=\"1\"} " << ls.work_max_us << "\n";
  m << "# HELP tendril_control_realtime Whether SCHED_FIFO and mlockall were granted.\n"
       "# TYPE tendril_control_realtime gauge\n"
    << "tendril_control_realtime{kind=\"sched_fifo\"} " << (ls.realtime_scheduling ? 1 : 0) << "\n"
    << "tendril_control_realtime{kind=\"mlockall\"} " << (ls.memory_locked ? 1 : 0) << "\n";
  m << "# HELP tendril_bus_load Worst-case CAN bus load computed from the configuration (fraction).\n"
       "# TYPE tendril_bus_load gauge\n";
  for (const auto& b : impl_->buses)
    m << "tendril_bus_load{robot=\"" << b->robot << "\",bus=\"" << b->config.name << "\"} " << b->load
      << "\n";
  m << "# HELP tendril_bus_frames_total CAN frames by direction.\n# TYPE tendril_bus_frames_total counter\n";
  for (const auto& b : impl_->buses) {
    const auto st = b->master_endpoint->statistics();
    m << "tendril_bus_frames_total{bus=\"" << b->config.name << "\",direction=\"sent\"} " << st.frames_sent
      << "\n"
      << "tendril_bus_frames_total{bus=\"" << b->config.name << "\",direction=\"received\"} "
      << st.frames_received << "\n"
      << "tendril_bus_frames_total{bus=\"" << b->config.name << "\",direction=\"send_failed\"} "
      << st.send_failures << "\n"
      << "tendril_bus_frames_total{bus=\"" << b->config.name << "\",direction=\"error\"} " << st.error_frames
      << "\n";
  }
  m << "# HELP tendril_robot_state Operating state (1 for the current one).\n# TYPE tendril_robot_state "
       "gauge\n";
  for (const auto& r : impl_->robots) {
    const auto s = r->snapshot.load();
    for (auto st : {OperatingState::kDisabled, OperatingState::kEnabled, OperatingState::kPaused,
                    OperatingState::kFault})
      m << "tendril_robot_state{robot=\"" << r->config.name << "\",state=\"" << state_name(st) << "\"} "
        << (s.state == st ? 1 : 0) << "\n";
    m << "tendril_robot_estop{robot=\"" << r->config.name << "\"} " << (s.estop ? 1 : 0) << "\n";
    m << "tendril_robot_mailbox_full_total{robot=\"" << r->config.name << "\"} " << s.mailbox_full << "\n";
  }
  return m.str();
}

std::vector<std::string> RobotRuntime::topics() const {
  std::vector<std::string> t;
  for (const auto& r : impl_->robots) {
    t.push_back("/" + r->config.name + "/joint_states");
    t.push_back("/" + r->config.name + "/operating_state");
    t.push_back("/" + r->config.name + "/scene");
    t.push_back("/" + r->config.name + "/diagnostics");
    if (r->catheter) t.push_back("/" + r->config.name + "/catheter");
  }
  t.push_back("/safety/events");
  return t;
}

namespace {
nlohmann::json scene_update(const RobotUnit& r, const std::vector<Eigen::Vector3d>& pts, const Pose& tip,
                            double stamp) {
  const auto sec = static_cast<std::int64_t>(stamp);
  const nlohmann::json ts = {{"sec", sec},
                             {"nsec", static_cast<std::int64_t>((stamp - static_cast<double>(sec)) * 1e9)}};
  const nlohmann::json identity = {{"position", {{"x", 0}, {"y", 0}, {"z", 0}}},
                                   {"orientation", {{"x", 0}, {"y", 0}, {"z", 0}, {"w", 1}}}};
  auto points = nlohmann::json::array();
  for (const auto& p : pts) points.push_back(nlohmann::json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
  auto empty = nlohmann::json::array();
  nlohmann::json backbone = {{"timestamp", ts},
                             {"frame_id", "world"},
                             {"id", r.config.name + "/backbone"},
                             {"lifetime", {{"sec", 0}, {"nsec", 0}}},
                             {"frame_locked", false},
                             {"metadata", empty},
                             {"arrows", empty},
                             {"cubes", empty},
                             {"spheres", empty},
                             {"cylinders", empty},
                             {"lines",
                              {{{"type", 0},
                                {"pose", identity},
                                {"thickness", 0.9},
                                {"scale_invariant", false},
                                {"points", points},
                                {"color", {{"r", 0.85}, {"g", 0.75}, {"b", 0.3}, {"a", 1}}},
                                {"colors", empty},
                                {"indices", empty}}}},
                             {"triangles", empty},
                             {"texts", empty},
                             {"models", empty}};
  // Tip frame: three arrows along the tip's x (red), y (green), z (blue) axes.
  auto arrows = nlohmann::json::array();
  const Eigen::Matrix3d R = tip.orientation.toRotationMatrix();
  const Eigen::Quaterniond to_x = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), R.col(0));
  const Eigen::Quaterniond to_y = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), R.col(1));
  const Eigen::Quaterniond to_z = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), R.col(2));
  const std::array<std::pair<Eigen::Quaterniond, std::array<double, 3>>, 3> axes{
      {{to_x, {1, 0.2, 0.2}}, {to_y, {0.2, 1, 0.2}}, {to_z, {0.3, 0.5, 1}}}};
  for (const auto& [q, c] : axes)
    arrows.push_back(nlohmann::json{
        {"pose",
         {{"position", {{"x", tip.position.x()}, {"y", tip.position.y()}, {"z", tip.position.z()}}},
          {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}}},
        {"shaft_length", 4.0},
        {"shaft_diameter", 0.3},
        {"head_length", 1.0},
        {"head_diameter", 0.8},
        {"color", {{"r", c[0]}, {"g", c[1]}, {"b", c[2]}, {"a", 1}}}});
  nlohmann::json tip_entity = backbone;
  tip_entity["id"] = r.config.name + "/tip_frame";
  tip_entity["lines"] = empty;
  tip_entity["arrows"] = arrows;
  return {{"deletions", empty}, {"entities", {backbone, tip_entity}}};
}
}  // namespace

namespace {
// The loaded plan in the scene: the vessel centerline and the planned tip path, in the insertion
// frame the planner used (vessel start at the origin, initial tangent +z).
void add_path_entities(RobotUnit& r, nlohmann::json& msg) {
  std::shared_ptr<const LoadedPath> path;
  {
    std::lock_guard lock(r.path_mutex);
    path = r.path;
  }
  if (!path || msg["entities"].empty()) return;
  auto line = [&](const std::string& id, const std::vector<Eigen::Vector3d>& pts, double thickness,
                  std::array<double, 4> c) {
    nlohmann::json e = msg["entities"][0];  // the backbone entity: same stamp and frame
    auto points = nlohmann::json::array();
    for (const auto& p : pts) points.push_back(nlohmann::json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
    e["id"] = r.config.name + "/" + id;
    e["lines"][0]["points"] = std::move(points);
    e["lines"][0]["thickness"] = thickness;
    e["lines"][0]["color"] = {{"r", c[0]}, {"g", c[1]}, {"b", c[2]}, {"a", c[3]}};
    msg["entities"].push_back(std::move(e));
  };
  if (path->vessel.size() >= 2) line("vessel", path->vessel, 4.0, {0.8, 0.25, 0.25, 0.35});
  if (path->tips.size() >= 2) line("planned_path", path->tips, 0.5, {0.3, 0.9, 0.4, 1.0});
}

nlohmann::json diagnostics(const RobotUnit& r, const RobotSnapshot& s, const RuntimeImplBase& im) {
  const auto ls = im.control_thread.statistics();
  double bus_load = 0.0;
  for (const auto& b : im.buses)
    if (b->robot == r.config.name) bus_load = std::max(bus_load, b->load);
  auto setpoint = nlohmann::json::array(), measured = nlohmann::json::array();
  for (std::size_t i = 0; i < r.n; ++i) {
    setpoint.push_back(s.setpoint[i]);
    measured.push_back(s.position[i]);
  }
  const double stamp = im.wall_offset + s.time;
  const auto sec = static_cast<std::int64_t>(stamp);
  return {
      {"timestamp",
       {{"sec", sec}, {"nsec", static_cast<std::int64_t>((stamp - static_cast<double>(sec)) * 1e9)}}},
      // LoopStatistics keeps the deviation from the nominal period (jitter), not the period itself.
      {"nominal_period_us", im.period * 1e6},
      {"period_us",
       {{"p50", ls.period_error_p50_us}, {"p99", ls.period_error_p99_us}, {"max", ls.period_error_max_us}}},
      {"work_us", {{"p50", ls.work_p50_us}, {"p99", ls.work_p99_us}, {"max", ls.work_max_us}}},
      {"overruns", ls.overruns},
      {"late_cycles", ls.late_cycles},
      {"lost_max_us", ls.lost_max_us},
      {"bus_load", bus_load},
      {"setpoint", setpoint},
      {"measured", measured}};
}
}  // namespace

std::optional<nlohmann::json> RobotRuntime::topic_message(const std::string& topic,
                                                          std::uint64_t since_version,
                                                          std::uint64_t& version) const {
  auto& im = *impl_;
  nlohmann::json msg;
  if (topic == "/safety/events") {
    im.collect_events();
    std::lock_guard lock(im.events_mutex);
    version = im.events_total;
    if (version == since_version) return std::nullopt;
    auto list = nlohmann::json::array();
    const auto fresh = std::min<std::uint64_t>(im.events_total - since_version, im.events.size());
    for (auto it = im.events.end() - static_cast<std::ptrdiff_t>(fresh); it != im.events.end(); ++it)
      list.push_back(*it);
    return nlohmann::json{{"events", list}};
  }
  const auto slash = topic.find('/', 1);
  if (topic.empty() || topic[0] != '/' || slash == std::string::npos) return std::nullopt;
  auto it = im.by_name.find(topic.substr(1, slash - 1));
  if (it == im.by_name.end()) return std::nullopt;
  const RobotUnit& r = *it->second;
  const auto leaf = topic.substr(slash + 1);
  const auto s = r.snapshot.load();
  if (leaf == "joint_states") {
    msg = joint_state_json(r, s, im.wall_offset, false);
    auto sp = nlohmann::json::array();
    for (std::size_t i = 0; i < r.n; ++i) sp.push_back(s.setpoint[i]);
    msg["setpoint"] = sp;
  } else if (leaf == "operating_state") {
    msg = operating_state(r.config.name).body;
    // The catheter's measured values (deflection, configuration, wall force) change with sensor noise
    // every tick: they go out on /{robot}/catheter at 10 Hz, so this topic still changes only when
    // the state does.
    if (r.catheter) {
      for (const char* k : {"configuration", "spring_deflection_mm", "contact_force_n", "simulation"})
        msg.erase(k);
      msg["joystick"].erase("axes");
      // The hold's wording quotes the live deflection; the catheter topic carries it.
      if (msg["hold"].is_object())
        for (const char* k : {"message", "next"}) msg["hold"].erase(k);
    }
  } else if (leaf == "catheter" && r.catheter) {
    msg = operating_state(r.config.name).body;
  } else if (leaf == "scene") {
    const auto q = positions(r, s);
    msg = scene_update(r, r.kinematics->shape(q), r.kinematics->tip(q), im.wall_offset + s.time);
    add_path_entities(*it->second, msg);
    if (r.catheter) add_catheter_entities(r, msg);
  } else if (leaf == "diagnostics") {
    msg = diagnostics(r, s, im);
  } else {
    return std::nullopt;
  }
  // Change detection: only send what differs from the last message of this topic; diagnostics and the
  // catheter's measured values at 10 Hz.
  std::string key;
  if (leaf == "joint_states") {
    key = std::to_string(s.tick);
  } else if (leaf == "diagnostics" || leaf == "catheter") {
    key = std::to_string(static_cast<std::int64_t>(s.time * 10.0));
  } else {
    key = msg.dump();
  }
  std::lock_guard lock(im.topic_mutex);
  auto& cached = im.topic_cache[topic];
  if (cached.first != key) {
    cached.first = key;
    ++cached.second;
  }
  version = cached.second;
  if (version == since_version) return std::nullopt;
  return msg;
}

}  // namespace tendril::server
