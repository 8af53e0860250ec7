// RobotRuntime's ControlApi: request validation (network threads) and state read-out.
#include <cmath>
#include <sstream>

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

std::vector<double> positions(const RobotUnit& r, const RobotSnapshot& s) {
  return std::vector<double>(s.position.begin(), s.position.begin() + static_cast<std::ptrdiff_t>(r.n));
}

}  // namespace

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
    out.push_back(nlohmann::json{{"name", r->config.name},
                                 {"kind", r->config.kind},
                                 {"description", r->config.description},
                                 {"joints", joints},
                                 {"modes", {"joint"}},
                                 {"buses", buses},
                                 {"command_timeout_ms", r->config.command_timeout_ms}});
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
                        {"mode", "joint"},
                        {"is_homed", true},
                        {"is_busy", s.busy},
                        {"estop", s.estop},
                        {"drives_ready", s.drives_ready}};
  if (s.state == OperatingState::kFault || s.estop)
    out["fault"] = {
        {"code", safety::to_string(s.fault.code)},
        {"message", std::string(s.fault.text)},
        {"joint", s.fault.joint >= 0
                      ? nlohmann::json(r.config.joints[static_cast<std::size_t>(s.fault.joint)].name)
                      : nlohmann::json(nullptr)}};
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
    return ApiResult::error(
        400, "bad_request",
        "expected {\"command\": \"enable\" | \"disable\" | \"pause\" | \"resume\" | \"home\"}");
  const auto cmd = body["command"].get<std::string>();
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
    return ApiResult::error(
        400, "bad_request",
        "unknown state command '" + cmd + "'; expected enable, disable, pause, resume or home");
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
                             {"mode", "joint"},
                             {"is_homed", true},
                             {"is_busy", sc == safety::StateCommand::kEnable || s.busy},
                             {"estop", false}});
}

ApiResult RobotRuntime::mode(const std::string& robot, const nlohmann::json& body) {
  TENDRIL_FIND_ROBOT(robot)
  if (!body.is_object() || !body.contains("mode") || !body["mode"].is_string())
    return ApiResult::error(400, "bad_request", "expected {\"mode\": \"joint\"}");
  const auto m = body["mode"].get<std::string>();
  if (m != "joint")
    return ApiResult::error(422, "unknown_mode",
                            "mode '" + m + "' is not available for robot '" + robot + "' (available: joint)");
  const auto s = r.snapshot.load();
  if (s.busy)
    return ApiResult::error(409, "not_holding",
                            "robot '" + robot + "' is moving; modes change only while it holds");
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
  const auto s = r.snapshot.load();
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled)
    return ApiResult::error(
        409, "not_enabled",
        std::string("robot '") + robot + "' is " + state_name(s.state) + "; enable it before moving");
  // While the drives are still enabling, the goal waits in the control thread and starts when they are.
  // Predict the duration with the same interpolator the control thread will use.
  teleop::QuinticInterpolator predict(r.n);
  predict.reset({s.setpoint.data(), r.n}, 0.0);
  predict.retarget(0.0, {c.values.data(), r.n}, {r.max_velocity.data(), r.n},
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
  const auto s = r.snapshot.load();
  if (s.estop) return ApiResult::error(409, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled || !s.drives_ready)
    return ApiResult::error(409, "not_enabled",
                            std::string("robot '") + robot + "' is " + state_name(s.state) +
                                (s.drives_ready ? "" : " and its drives are not ready") +
                                "; enable it before streaming velocities");
  c.received = std::chrono::steady_clock::now();
  if (!post(r, c)) return busy_mailbox(robot);
  return ApiResult::success({{"command_timeout_ms", r.config.command_timeout_ms}});
}

ApiResult RobotRuntime::estop() {
  // The latch is set directly as well as through the mailbox, so a full mailbox cannot delay it.
  for (auto& r : impl_->robots) {
    r->supervisor->request_estop();
    RobotCommand c;
    c.kind = CommandKind::estop;
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

void RobotRuntime::operator_lost() {
  for (auto& r : impl_->robots) {
    RobotCommand c;
    c.kind = CommandKind::hold;
    post(*r, c);
  }
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
  } else if (leaf == "scene") {
    const auto q = positions(r, s);
    msg = scene_update(r, r.kinematics->shape(q), r.kinematics->tip(q), im.wall_offset + s.time);
  } else {
    return std::nullopt;
  }
  // Change detection: only send what differs from the last message of this topic.
  const auto key = leaf == "joint_states" ? std::to_string(s.tick) : msg.dump();
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
