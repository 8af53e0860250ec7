#include "tendril/server/http/control_json.hpp"

#include <algorithm>
#include <cmath>

#include "tendril/safety/safety_types.hpp"

namespace tendril::server {

using nlohmann::json;

int http_status(ErrorKind kind) noexcept {
  switch (kind) {
    case ErrorKind::malformed:
      return 400;
    case ErrorKind::forbidden:
      return 403;
    case ErrorKind::not_found:
      return 404;
    case ErrorKind::conflict:
      return 409;
    case ErrorKind::not_supported:
    case ErrorKind::invalid:
      return 422;
    case ErrorKind::busy:
      return 503;
    case ErrorKind::internal:
      break;
  }
  return 500;
}

ApiResult to_api_result(const ServiceError& error) {
  return ApiResult::error(http_status(error.kind), error.code, error.message);
}

namespace {

template <class T>
ApiResult failed(const Result<T>& result) {
  return to_api_result(result.error());
}

json vector3(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

json stamp(double t) {
  const auto sec = static_cast<std::int64_t>(t);
  return {{"sec", sec}, {"nsec", static_cast<std::int64_t>((t - static_cast<double>(sec)) * 1e9)}};
}

json joint_state_json(const JointStateView& v) {
  return {{"name", v.name},
          {"position", v.position},
          {"velocity", v.velocity},
          {"effort", v.effort},
          {"timestamp", v.timestamp}};
}

// Reads body[key] as an array of numbers (sizes and finiteness are the service's to check, so its
// message names the joints).
std::optional<ApiResult> read_numbers(const json& body, const char* key, std::vector<double>& out) {
  if (!body.is_object() || !body.contains(key))
    return ApiResult::error(400, "bad_request",
                            std::string("expected a JSON object with \"") + key + "\": an array of numbers");
  const auto& v = body.at(key);
  if (!v.is_array())
    return ApiResult::error(400, "bad_request", std::string("\"") + key + "\" must be an array of numbers");
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (!v[i].is_number())
      return ApiResult::error(400, "bad_request",
                              std::string("\"") + key + "\"[" + std::to_string(i) + "] is not a number");
    out.push_back(v[i].get<double>());
  }
  return std::nullopt;
}

std::optional<Eigen::Vector3d> read_point(const json& p) {
  if (!p.is_array() || p.size() != 3 || !p[0].is_number() || !p[1].is_number() || !p[2].is_number())
    return std::nullopt;
  Eigen::Vector3d v(p[0].get<double>(), p[1].get<double>(), p[2].get<double>());
  if (!v.allFinite()) return std::nullopt;
  return v;
}

// {"position":[x,y,z], "orientation":[qx,qy,qz,qw]} (mm; a unit quaternion).
std::optional<ApiResult> read_pose(const json& body, CartesianPose& pose) {
  if (!body.is_object() || !body.contains("position") || !body.contains("orientation"))
    return ApiResult::error(400, "bad_request",
                            "expected {\"position\": [x, y, z] (mm), \"orientation\": [qx, qy, qz, qw]}");
  const auto position = read_point(body["position"]);
  if (!position) return ApiResult::error(422, "bad_pose", "\"position\" must be 3 finite numbers (mm)");
  const auto& o = body["orientation"];
  if (!o.is_array() || o.size() != 4 ||
      !std::all_of(o.begin(), o.end(), [](const json& x) { return x.is_number(); }))
    return ApiResult::error(422, "bad_pose", "\"orientation\" must be a quaternion [qx, qy, qz, qw]");
  Eigen::Quaterniond q(o[3].get<double>(), o[0].get<double>(), o[1].get<double>(), o[2].get<double>());
  if (!q.coeffs().allFinite() || std::abs(q.norm() - 1.0) > 1e-3)
    return ApiResult::error(422, "bad_pose",
                            "\"orientation\" must be a finite unit quaternion (norm 1 ± 0.001)");
  pose.position = *position;
  pose.orientation = q.normalized();
  return std::nullopt;
}

json pose_json(const PoseView& p) {
  const auto& o = p.orientation;
  return {{"position", vector3(p.position)},
          {"orientation", {o.x(), o.y(), o.z(), o.w()}},
          {"frame", p.frame},
          {"timestamp", p.timestamp}};
}

json hold_json(const HoldView& h) {
  return {{"cause", h.cause},
          {"message", h.message},
          {"joint", h.joint.empty() ? json(nullptr) : json(h.joint)},
          {"cleared", h.cleared},
          {"next", h.next},
          {"allowed", h.allowed}};
}

json state_json(const OperatingStateView& v) {
  json out = {{"state", safety::to_string(v.state)},
              {"mode", v.mode},
              {"is_homed", true},
              {"is_busy", v.busy},
              {"estop", v.estop},
              {"drives_ready", v.drives_ready}};
  // The loop-timing policy's record: lost control time (beyond one period) and the bound that faults
  // a moving robot (README, "Control-loop timing").
  out["loop_timing"] = {{"max_lost_control_ms", v.loop_timing.max_lost_control_ms},
                        {"lost_max_ms", v.loop_timing.lost_max_ms},
                        {"lost_max_moving_ms", v.loop_timing.lost_max_moving_ms},
                        {"stalls_over_bound", v.loop_timing.stalls_over_bound},
                        {"stalls_over_bound_at_rest", v.loop_timing.stalls_over_bound_at_rest}};
  if (v.fault)
    out["fault"] = {{"code", v.fault->code},
                    {"message", v.fault->message},
                    {"joint", v.fault->joint.empty() ? json(nullptr) : json(v.fault->joint)}};
  out["hold"] = v.hold ? hold_json(*v.hold) : json(nullptr);
  out["mode_refusal"] = v.mode_refusal ? json{{"mode", v.mode_refusal->mode},
                                              {"code", v.mode_refusal->code},
                                              {"reason", v.mode_refusal->reason},
                                              {"timestamp", v.mode_refusal->timestamp}}
                                       : json(nullptr);
  return out;
}

json event_json(const SafetyEventView& e) {
  json j = {{"time", e.time}, {"robot", e.robot}, {"kind", e.kind},      {"code", e.code},
            {"from", e.from}, {"to", e.to},       {"message", e.message}};
  if (!e.joint.empty()) j["joint"] = e.joint;
  return j;
}

// Whether two scenes look the same: equal but for numbers within what a viewer can see (0.05 mm; 0.005
// of a quaternion component, about 0.6 degrees: a 10 mm arrow's tip moves 0.1 mm).
bool visibly_same(const json& a, const json& b, double step = 0.05) {
  if (a.is_number() && b.is_number()) return std::abs(a.get<double>() - b.get<double>()) <= step;
  if (a.type() != b.type() || a.size() != b.size()) return false;
  if (a.is_object()) {
    for (const auto& [key, value] : a.items()) {
      const auto it = b.find(key);
      if (it == b.end() || !visibly_same(value, *it, key == "orientation" ? 0.005 : step)) return false;
    }
    return true;
  }
  if (a.is_array()) {
    for (std::size_t i = 0; i < a.size(); ++i)
      if (!visibly_same(a[i], b[i], step)) return false;
    return true;
  }
  return a == b;
}

void erase_path(json& j, const std::string& dotted) {
  const auto dot = dotted.find('.');
  if (!j.is_object()) return;
  if (dot == std::string::npos) {
    j.erase(dotted);
    return;
  }
  const auto head = dotted.substr(0, dot);
  if (j.contains(head)) erase_path(j[head], dotted.substr(dot + 1));
}

json scene_update(const std::string& robot, const ShapeView& shape, const PoseView& tip) {
  const json ts = stamp(shape.timestamp);
  const json identity = {{"position", {{"x", 0}, {"y", 0}, {"z", 0}}},
                         {"orientation", {{"x", 0}, {"y", 0}, {"z", 0}, {"w", 1}}}};
  auto points = json::array();
  for (const auto& p : shape.points) points.push_back(json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
  auto empty = json::array();
  json backbone = {{"timestamp", ts},
                   {"frame_id", "world"},
                   {"id", robot + "/backbone"},
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
  auto arrows = json::array();
  const Eigen::Matrix3d R = tip.orientation.toRotationMatrix();
  const std::array<std::pair<Eigen::Vector3d, std::array<double, 3>>, 3> axes{
      {{R.col(0), {1, 0.2, 0.2}}, {R.col(1), {0.2, 1, 0.2}}, {R.col(2), {0.3, 0.5, 1}}}};
  for (const auto& [axis, c] : axes) {
    const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), axis);
    arrows.push_back(
        json{{"pose",
              {{"position", {{"x", tip.position.x()}, {"y", tip.position.y()}, {"z", tip.position.z()}}},
               {"orientation", {{"x", q.x()}, {"y", q.y()}, {"z", q.z()}, {"w", q.w()}}}}},
             {"shaft_length", 4.0},
             {"shaft_diameter", 0.3},
             {"head_length", 1.0},
             {"head_diameter", 0.8},
             {"color", {{"r", c[0]}, {"g", c[1]}, {"b", c[2]}, {"a", 1}}}});
  }
  json tip_entity = backbone;
  tip_entity["id"] = robot + "/tip_frame";
  tip_entity["lines"] = empty;
  tip_entity["arrows"] = arrows;
  return {{"deletions", empty}, {"entities", {backbone, tip_entity}}};
}

// The loaded plan in the scene: the vessel centerline and the planned tip path.
void add_path_entities(const std::string& robot, const PathView& path, json& msg) {
  if (!path.loaded || msg["entities"].empty()) return;
  auto line = [&](const std::string& id, const std::vector<Eigen::Vector3d>& pts, double thickness,
                  std::array<double, 4> c) {
    json e = msg["entities"][0];  // the backbone entity: same stamp and frame
    auto points = json::array();
    for (const auto& p : pts) points.push_back(json{{"x", p.x()}, {"y", p.y()}, {"z", p.z()}});
    e["id"] = robot + "/" + id;
    e["lines"][0]["points"] = std::move(points);
    e["lines"][0]["thickness"] = thickness;
    e["lines"][0]["color"] = {{"r", c[0]}, {"g", c[1]}, {"b", c[2]}, {"a", c[3]}};
    msg["entities"].push_back(std::move(e));
  };
  if (path.vessel.size() >= 2) line("vessel", path.vessel, 4.0, {0.8, 0.25, 0.25, 0.35});
  if (path.tips.size() >= 2) line("planned_path", path.tips, 0.5, {0.3, 0.9, 0.4, 1.0});
}

json parameter_json(const Parameter& p) {
  return {{"name", p.name}, {"value", p.value}, {"type", "float64"}};
}

}  // namespace

JsonControlApi::JsonControlApi(RobotService& service, ExtensionLookup extensions, SchemaLookup schemas)
    : service_(service), extensions_(std::move(extensions)), schemas_(std::move(schemas)) {}

RobotApiExtension* JsonControlApi::extension(const std::string& robot) const {
  return extensions_ ? extensions_(robot) : nullptr;
}

json JsonControlApi::robots() const {
  auto out = json::array();
  for (const auto& d : service_.robots()) {
    auto joints = json::array();
    for (const auto& j : d.joints)
      joints.push_back(json{{"name", j.name},
                            {"unit", j.unit},
                            {"lower", j.lower},
                            {"upper", j.upper},
                            {"max_velocity", j.max_velocity},
                            {"max_acceleration", j.max_acceleration}});
    auto buses = json::array();
    for (const auto& b : d.buses)
      buses.push_back(
          json{{"name", b.name}, {"interface", b.interface}, {"simulated", b.simulated}, {"load", b.load}});
    auto modes = json::array();
    for (const auto& m : d.modes) modes.push_back(m.name);
    auto commands = json::array();
    for (const auto& c : robot_commands(d.name)) commands.push_back(c.name);
    json robot = {
        {"name", d.name},       {"kind", d.kind},           {"description", d.description},
        {"joints", joints},     {"modes", modes},           {"buses", buses},
        {"commands", commands}, {"cartesian", d.cartesian}, {"command_timeout_ms", d.command_timeout_ms}};
    if (d.vessel_entry) {
      const Eigen::Vector3d t = d.vessel_entry->translation();
      const Eigen::Quaterniond q(d.vessel_entry->linear());
      robot["vessel_entry"] = {
          {"position", {t.x(), t.y(), t.z()}},
          {"orientation", {q.x(), q.y(), q.z(), q.w()}},
          {"frame", "robot base {0} (mm); a plan's insertion frame maps into it by this pose"}};
    }
    if (auto* ext = extension(d.name)) ext->describe(robot);
    out.push_back(std::move(robot));
  }
  return out;
}

bool JsonControlApi::has_robot(const std::string& robot) const { return service_.has_robot(robot); }

ApiResult JsonControlApi::measured_js(const std::string& robot) const {
  auto r = service_.measured_js(robot);
  return r ? ApiResult::success(joint_state_json(*r)) : failed(r);
}

ApiResult JsonControlApi::setpoint_js(const std::string& robot) const {
  auto r = service_.setpoint_js(robot);
  return r ? ApiResult::success(joint_state_json(*r)) : failed(r);
}

ApiResult JsonControlApi::measured_cp(const std::string& robot) const {
  auto r = service_.measured_cp(robot);
  return r ? ApiResult::success(pose_json(*r)) : failed(r);
}

ApiResult JsonControlApi::measured_cv(const std::string& robot) const {
  auto r = service_.measured_cv(robot);
  if (!r) return failed(r);
  return ApiResult::success({{"linear", vector3(r->twist.linear)},
                             {"angular", vector3(r->twist.angular)},
                             {"frame", r->frame},
                             {"timestamp", r->timestamp}});
}

ApiResult JsonControlApi::measured_cf(const std::string& robot) const {
  auto r = service_.measured_cf(robot);
  if (!r) return failed(r);
  return ApiResult::success({{"force", vector3(r->force)}, {"frame", r->frame}, {"timestamp", r->timestamp}});
}

ApiResult JsonControlApi::robot_schema(const std::string& robot) const {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  if (schemas_) {
    if (auto schema = schemas_(robot)) return ApiResult::success(*schema);
  }
  return ApiResult::error(404, "not_found", "no schema is known for robot '" + robot + "'");
}

ApiResult JsonControlApi::shape(const std::string& robot) const {
  auto r = service_.shape(robot);
  if (!r) return failed(r);
  auto points = json::array();
  for (const auto& p : r->points) points.push_back(vector3(p));
  return ApiResult::success({{"points", points}, {"frame", r->frame}, {"timestamp", r->timestamp}});
}

json JsonControlApi::operating_state_json(const std::string& robot) const {
  auto r = service_.operating_state(robot);
  if (!r) return nullptr;
  json out = state_json(*r);
  if (auto* ext = extension(robot)) ext->state(out);
  return out;
}

ApiResult JsonControlApi::operating_state(const std::string& robot) const {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  json out = operating_state_json(robot);
  if (out.is_null()) return to_api_result(unknown_robot(robot));
  return ApiResult::success(std::move(out));
}

ApiResult JsonControlApi::state_command(const std::string& robot, const json& body) {
  if (!body.is_object() || !body.contains("command") || !body["command"].is_string())
    return ApiResult::error(
        400, "bad_request",
        "expected {\"command\": \"enable\" | \"disable\" | \"pause\" | \"resume\" | \"home\"} or one "
        "of the robot type's own commands");
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  const auto cmd = body["command"].get<std::string>();
  StateRequest request;
  if (cmd == "enable") {
    request = StateRequest::enable;
  } else if (cmd == "disable") {
    request = StateRequest::disable;
  } else if (cmd == "pause") {
    request = StateRequest::pause;
  } else if (cmd == "resume") {
    request = StateRequest::resume;
  } else if (cmd == "home") {
    request = StateRequest::home;
  } else {
    // A robot type's own state command (a way out of its holds, e.g. relaxing springs).
    for (const auto& c : robot_commands(robot))
      if (c.name == cmd) return robot_command(robot, cmd, body);
    std::string known = "enable, disable, pause, resume, home";
    for (const auto& c : robot_commands(robot)) known += ", " + c.name;
    return ApiResult::error(400, "bad_request", "unknown state command '" + cmd + "'; expected " + known);
  }
  auto r = service_.state_command(robot, request);
  if (!r) return failed(r);
  return ApiResult::success(state_json(*r));
}

ApiResult JsonControlApi::mode(const std::string& robot, const json& body) {
  if (!body.is_object() || !body.contains("mode") || !body["mode"].is_string()) {
    std::string available;
    for (const auto& d : service_.robots())
      if (d.name == robot)
        for (const auto& m : d.modes) available += (available.empty() ? "" : ", ") + m.name;
    return ApiResult::error(400, "bad_request", "expected {\"mode\": one of " + available + "}");
  }
  const auto m = body["mode"].get<std::string>();
  auto r = service_.mode(robot, m);
  return r ? ApiResult::success({{"mode", m}}) : failed(r);
}

ApiResult JsonControlApi::move_jp(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  std::vector<double> goal;
  if (auto e = read_numbers(body, "goal", goal)) return *e;
  auto r = service_.move_jp(robot, goal);
  return r ? ApiResult::success({{"duration_s", *r}}, 202) : failed(r);
}

ApiResult JsonControlApi::servo_jv(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  std::vector<double> velocity;
  if (auto e = read_numbers(body, "velocity", velocity)) return *e;
  auto r = service_.servo_jv(robot, velocity);
  if (!r) return failed(r);
  int timeout_ms = 0;
  for (const auto& d : service_.robots())
    if (d.name == robot) timeout_ms = d.command_timeout_ms;
  return ApiResult::success({{"command_timeout_ms", timeout_ms}});
}

ApiResult JsonControlApi::move_cp(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  CartesianPose goal;
  if (auto e = read_pose(body.is_object() && body.contains("goal") ? body["goal"] : body, goal)) return *e;
  auto r = service_.move_cp(robot, goal);
  return r ? ApiResult::success({{"duration_s", *r}}, 202) : failed(r);
}

ApiResult JsonControlApi::servo_cp(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  CartesianPose goal;
  if (auto e = read_pose(body.is_object() && body.contains("goal") ? body["goal"] : body, goal)) return *e;
  auto r = service_.servo_cp(robot, goal);
  return r ? ApiResult::success(json::object()) : failed(r);
}

ApiResult JsonControlApi::servo_cv(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  const auto linear = body.is_object() && body.contains("linear") ? read_point(body["linear"]) : std::nullopt;
  const auto angular =
      body.is_object() && body.contains("angular") ? read_point(body["angular"]) : std::nullopt;
  if (!linear || !angular)
    return ApiResult::error(
        400, "bad_request",
        "expected {\"linear\": [vx, vy, vz] (mm/s), \"angular\": [wx, wy, wz] (rad/s)}, finite");
  CartesianTwist twist;
  twist.linear = *linear;
  twist.angular = *angular;
  auto r = service_.servo_cv(robot, twist);
  return r ? ApiResult::success(json::object()) : failed(r);
}

std::vector<RobotCommandInfo> JsonControlApi::robot_commands(const std::string& robot) const {
  auto* ext = extension(robot);
  return ext ? ext->commands() : std::vector<RobotCommandInfo>{};
}

ApiResult JsonControlApi::robot_command(const std::string& robot, const std::string& name, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  auto* ext = extension(robot);
  if (!ext) return ApiResult::error(404, "not_found", "robot '" + robot + "' has no command '" + name + "'");
  for (const auto& c : ext->commands())
    if (c.name == name) return ext->command(name, body);
  return ApiResult::error(404, "not_found", "robot '" + robot + "' has no command '" + name + "'");
}

ApiResult JsonControlApi::estop() { return estop_from("an unnamed client"); }

ApiResult JsonControlApi::estop_from(const std::string& actor) {
  auto r = service_.estop(actor);
  return r ? ApiResult::success({{"estop", true}}) : failed(r);
}

ApiResult JsonControlApi::estop_reset() {
  auto r = service_.estop_reset("");
  return r ? ApiResult::success({{"estop", false}}) : failed(r);
}

json JsonControlApi::faults(std::size_t max_events) const {
  auto out = json::array();
  for (const auto& e : service_.faults(max_events)) out.push_back(event_json(e));
  return out;
}

std::string JsonControlApi::metrics() const { return service_.metrics(); }

std::vector<std::string> JsonControlApi::topics() const {
  std::vector<std::string> t;
  for (const auto& d : service_.robots()) {
    t.push_back("/" + d.name + "/joint_states");
    t.push_back("/" + d.name + "/operating_state");
    t.push_back("/" + d.name + "/scene");
    t.push_back("/" + d.name + "/diagnostics");
    if (auto* ext = extension(d.name))
      if (auto live = ext->live_state()) t.push_back("/" + d.name + "/" + live->topic);
  }
  t.push_back("/safety/events");
  return t;
}

std::optional<TopicInfo> JsonControlApi::topic_schema(const std::string& topic) const {
  const auto slash = topic.find('/', 1);
  if (topic.empty() || topic[0] != '/' || slash == std::string::npos) return std::nullopt;
  auto* ext = extension(topic.substr(1, slash - 1));
  if (!ext) return std::nullopt;
  auto live = ext->live_state();
  if (!live || topic.substr(slash + 1) != live->topic) return std::nullopt;
  // The robot's whole operating state: the operating_state schema under the type's name.
  json schema = {{"title", live->schema_name},
                 {"type", "object"},
                 {"properties",
                  {{"state", {{"type", "string"}, {"enum", {"DISABLED", "ENABLED", "PAUSED", "FAULT"}}}},
                   {"mode", {{"type", "string"}}},
                   {"is_homed", {{"type", "boolean"}}},
                   {"is_busy", {{"type", "boolean"}}},
                   {"estop", {{"type", "boolean"}}}}}};
  return TopicInfo{topic, live->schema_name, schema.dump()};
}

std::string JsonControlApi::visible_scene_key(const std::string& topic, json scene) const {
  std::lock_guard lock(topic_mutex_);
  auto& reference = scene_reference_[topic];
  if (reference.first.is_null() || !visibly_same(reference.first, scene)) {
    reference.first = std::move(scene);
    ++reference.second;
  }
  return std::to_string(reference.second);
}

std::uint64_t JsonControlApi::topic_version(const std::string& topic, const std::string& key) const {
  std::lock_guard lock(topic_mutex_);
  auto& cached = topic_cache_[topic];
  if (cached.first != key) {
    cached.first = key;
    ++cached.second;
  }
  return cached.second;
}

std::optional<json> JsonControlApi::topic_message(const std::string& topic, std::uint64_t since_version,
                                                  std::uint64_t& version) const {
  if (topic == "/safety/events") {
    std::uint64_t total = 0;
    auto fresh = service_.events_since(since_version, total);
    version = total;
    if (version == since_version) return std::nullopt;
    auto list = json::array();
    for (const auto& e : fresh) list.push_back(event_json(e));
    // A slow reader gets only the newest message of a topic (ws_connection.cpp), so a message alone
    // could skip events: `recent` repeats the last ones (oldest first) for a reader to fill that hole.
    constexpr std::size_t kRecentEvents = 32;
    auto recent = json::array();
    const auto last = service_.faults(kRecentEvents);
    for (auto it = last.rbegin(); it != last.rend(); ++it) recent.push_back(event_json(*it));
    return json{{"events", list}, {"recent", recent}};
  }
  const auto slash = topic.find('/', 1);
  if (topic.empty() || topic[0] != '/' || slash == std::string::npos) return std::nullopt;
  const std::string robot = topic.substr(1, slash - 1);
  if (!service_.has_robot(robot)) return std::nullopt;
  const auto leaf = topic.substr(slash + 1);
  auto* ext = extension(robot);
  const auto live = ext ? ext->live_state() : std::nullopt;
  json msg;
  std::string key;
  if (leaf == "joint_states") {
    auto measured = service_.measured_js(robot);
    auto setpoint = service_.setpoint_js(robot);
    if (!measured || !setpoint) return std::nullopt;
    msg = joint_state_json(*measured);
    msg["setpoint"] = setpoint->position;
    key = std::to_string(measured->tick);
  } else if (leaf == "operating_state") {
    msg = operating_state_json(robot);
    if (live)
      for (const auto& field : live->fields) erase_path(msg, field);
    // A hold keeps the core's wording here, which changes only with the hold (the robot's live wording
    // follows on its own topic): a page that has only this topic still says why the robot holds.
    if (auto base = service_.operating_state(robot);
        base && base->hold && msg.contains("hold") && msg["hold"].is_object()) {
      auto& hold = msg["hold"];
      if (!hold.contains("message")) hold["message"] = base->hold->message;
      if (!hold.contains("next")) hold["next"] = base->hold->next;
    }
    key = msg.dump();
  } else if (live && leaf == live->topic) {
    msg = operating_state_json(robot);
    auto js = service_.measured_js(robot);
    key = std::to_string(static_cast<std::int64_t>((js ? js->timestamp : 0.0) * live->rate_hz));
  } else if (leaf == "scene") {
    auto shape = service_.shape(robot);
    auto tip = service_.measured_cp(robot);
    if (!shape || !tip) return std::nullopt;
    msg = scene_update(robot, *shape, *tip);
    if (auto path = service_.path_following(robot)) add_path_entities(robot, *path, msg);
    if (ext) ext->scene(msg["entities"]);
    // The scene carries its timestamp: compare without it, and against the last scene sent within
    // what a viewer can see, so that neither an unchanged scene nor the sensors' noise at rest (a few
    // thousandths of a millimetre) resends it 50 times a second.
    json without = msg;
    for (auto& e : without["entities"]) e.erase("timestamp");
    key = visible_scene_key(topic, std::move(without));
  } else if (leaf == "diagnostics") {
    auto d = service_.diagnostics(robot);
    if (!d) return std::nullopt;
    msg = {
        {"timestamp", stamp(d->timestamp)},
        // The loop statistics keep the deviation from the nominal period (jitter), not the period.
        {"nominal_period_us", d->nominal_period_us},
        {"period_us",
         {{"p50", d->period_error_p50_us}, {"p99", d->period_error_p99_us}, {"max", d->period_error_max_us}}},
        {"work_us", {{"p50", d->work_p50_us}, {"p99", d->work_p99_us}, {"max", d->work_max_us}}},
        {"overruns", d->overruns},
        {"late_cycles", d->late_cycles},
        {"lost_max_us", d->lost_max_us},
        {"bus_load", d->bus_load},
        {"setpoint", d->setpoint},
        {"measured", d->measured}};
    key = std::to_string(static_cast<std::int64_t>(d->timestamp * 10.0));  // 10 Hz
  } else {
    return std::nullopt;
  }
  if (msg.is_null()) return std::nullopt;
  version = topic_version(topic, key);
  if (version == since_version) return std::nullopt;
  return msg;
}

void JsonControlApi::operator_lost(const std::string& robot) { service_.operator_lost(robot); }

ApiResult JsonControlApi::load_path(const std::string& robot, const json& plan, const std::string& plan_id) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  if (!plan.is_object() || !plan.contains("steps") || !plan["steps"].is_array() || plan["steps"].empty())
    return ApiResult::error(400, "bad_request", "expected a plan {\"steps\": [{\"q\": [joint values]}, …]}");
  // The robot type's own check first (a catheter refuses a plan made for another design): it says why
  // in the operator's words, where a step's joint values out of limits would only be its symptom.
  if (auto* ext = extension(robot))
    if (auto refused = ext->refuse_plan(plan)) return *refused;
  PathPlan typed;
  typed.id = plan_id;
  const auto& steps = plan["steps"];
  constexpr std::size_t kMaxSteps = 10000;
  if (steps.size() > kMaxSteps)
    return ApiResult::error(422, "too_many_steps",
                            "the plan has " + std::to_string(steps.size()) + " steps; at most " +
                                std::to_string(kMaxSteps) + " are accepted");
  for (std::size_t k = 0; k < steps.size(); ++k) {
    const std::string which = "step " + std::to_string(k);
    if (!steps[k].is_object())
      return ApiResult::error(400, "bad_request", which + ": expected an object with \"q\"");
    std::vector<double> q;
    if (auto e = read_numbers(steps[k], "q", q))
      return ApiResult::error(e->status, e->code, which + ": " + e->message);
    typed.steps.push_back(std::move(q));
    if (steps[k].contains("backbone") && steps[k]["backbone"].is_array() && !steps[k]["backbone"].empty())
      if (auto tip = read_point(steps[k]["backbone"].back())) typed.tips.push_back(*tip);
  }
  if (plan.contains("vessel_path") && plan["vessel_path"].is_array())
    for (const auto& p : plan["vessel_path"])
      if (auto v = read_point(p)) typed.vessel.push_back(*v);
  const auto count = typed.steps.size();
  auto r = service_.load_path(robot, std::move(typed));
  if (!r) return failed(r);
  return ApiResult::success(
      {{"steps", count}, {"step", -1}, {"plan", plan_id.empty() ? json() : json(plan_id)}});
}

ApiResult JsonControlApi::path_step(const std::string& robot, const json& body) {
  if (!service_.has_robot(robot)) return to_api_result(unknown_robot(robot));
  const bool by_index = body.is_object() && body.contains("step");
  const bool by_advance = body.is_object() && body.contains("advance");
  if (by_index == by_advance || (by_index && !body["step"].is_number_integer()) ||
      (by_advance && !(body["advance"] == 1 || body["advance"] == -1)))
    return ApiResult::error(400, "bad_request", "expected {\"step\": k} (0-based) or {\"advance\": 1 | -1}");
  std::optional<std::int32_t> step;
  std::int32_t advance = 0;
  if (by_index) {
    const auto k = body["step"].get<std::int64_t>();
    step = static_cast<std::int32_t>(std::clamp<std::int64_t>(k, -1, 1'000'000));
  } else {
    advance = body["advance"].get<std::int32_t>();
  }
  auto r = service_.path_step(robot, step, advance);
  if (!r) return failed(r);
  return ApiResult::success({{"step", r->first}, {"duration_s", r->second}}, 202);
}

ApiResult JsonControlApi::path_following(const std::string& robot) const {
  auto r = service_.path_following(robot);
  if (!r) return failed(r);
  return ApiResult::success({{"loaded", r->loaded},
                             {"steps", r->steps},
                             {"step", r->step},
                             {"target", r->target},
                             {"moving", r->moving},
                             {"mode", r->mode},
                             {"plan", r->plan.empty() ? json() : json(r->plan)}});
}

json JsonControlApi::parameters() const {
  auto out = json::array();
  for (const auto& p : service_.parameters()) out.push_back(parameter_json(p));
  return out;
}

ApiResult JsonControlApi::set_parameters(const json& list) {
  if (!list.is_array() || list.empty())
    return ApiResult::error(400, "bad_parameter", "expected a non-empty list of {\"name\", \"value\"}");
  std::vector<ParameterChange> changes;
  for (const auto& item : list) {
    if (!item.is_object() || !item.contains("name") || !item["name"].is_string())
      return ApiResult::error(400, "bad_parameter", "every parameter needs a \"name\" string");
    ParameterChange change;
    change.name = item["name"].get<std::string>();
    const auto value = item.find("value");
    if (value != item.end() && !value->is_null()) {
      if (!value->is_number())
        return ApiResult::error(400, "bad_parameter",
                                "parameter " + change.name + ": value must be a number");
      change.value = value->get<double>();
    }
    changes.push_back(std::move(change));
  }
  auto r = service_.set_parameters(changes);
  if (!r) return failed(r);
  auto out = json::array();
  for (const auto& p : *r) out.push_back(parameter_json(p));
  return ApiResult::success(out);
}

}  // namespace tendril::server
