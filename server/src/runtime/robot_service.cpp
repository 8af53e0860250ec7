// RobotRuntime's RobotService: command checks (network threads) and state read-out. Typed in, typed
// out: JSON and status codes belong to the network edge.
#include <algorithm>
#include <cmath>
#include <sstream>

#include "runtime_impl.hpp"

namespace tendril::server {

namespace {
using safety::OperatingState;

const char* state_name(OperatingState s) { return safety::to_string(s); }

ServiceError error(ErrorKind kind, std::string code, std::string message) {
  return {kind, std::move(code), std::move(message)};
}

ServiceError busy_mailbox(const std::string& robot) {
  return error(ErrorKind::busy, "control_busy",
               "the control loop of '" + robot + "' is not taking commands fast enough; try again");
}

// Checks `values` against the robot's joint count and finiteness.
std::optional<ServiceError> check_vector(std::span<const double> values, const RobotUnit& r,
                                         const char* what) {
  if (values.size() != r.n) {
    std::string names;
    for (const auto& j : r.config.joints) names += (names.empty() ? "" : ", ") + j.name();
    return error(ErrorKind::invalid, "wrong_size",
                 std::string("\"") + what + "\" has " + std::to_string(values.size()) + " values; robot '" +
                     r.config.name + "' has " + std::to_string(r.n) + " joints (" + names + ")");
  }
  for (std::size_t i = 0; i < r.n; ++i)
    if (!std::isfinite(values[i]))
      return error(ErrorKind::invalid, "not_finite",
                   "joint '" + r.config.joints[i].name() + "': value is not finite");
  return std::nullopt;
}

// The operating limits (tightened through parameters) are checked after the configured ones, so the
// message names the parameter that refused the command.
std::optional<ServiceError> operating_limit_violation(const RobotUnit& r,
                                                      const safety::OperatingLimits& limits,
                                                      std::span<const double> values, bool velocity) {
  for (std::size_t i = 0; i < r.n; ++i) {
    const auto& j = r.config.joints[i].limit;
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
    return error(ErrorKind::invalid, "out_of_limits", why.str());
  }
  return std::nullopt;
}

std::string joint_name(const RobotUnit& r, int joint) {
  return joint >= 0 && static_cast<std::size_t>(joint) < r.n
             ? r.config.joints[static_cast<std::size_t>(joint)].name()
             : std::string();
}

OperatingStateView state_view(const RobotUnit& r, const RobotSnapshot& s, double wall_offset) {
  OperatingStateView v;
  v.state = s.state;
  v.mode = r.mode_name(s.mode);
  v.busy = s.busy;
  // A press the control thread has not taken yet is shown at once: the snapshot is a control cycle old
  // (more after a stall), and a 200 e-stop must read back as latched.
  v.estop = s.estop || r.supervisor->estop_latched();
  if (v.estop) v.state = OperatingState::kFault;
  v.drives_ready = s.drives_ready;
  v.timestamp = wall_offset + s.time;
  // The loop-timing policy's record (README, "Control-loop timing").
  v.loop_timing.max_lost_control_ms = r.supervisor->options().max_lost_control_time * 1e3;
  v.loop_timing.lost_max_ms = s.lost_control.max_lost * 1e3;
  v.loop_timing.lost_max_moving_ms = s.lost_control.max_lost_moving * 1e3;
  v.loop_timing.stalls_over_bound = s.lost_control.stalls_over_bound;
  v.loop_timing.stalls_over_bound_at_rest = s.lost_control.stalls_over_bound_at_rest;
  if (s.state == OperatingState::kFault || s.estop)
    v.fault =
        FaultView{safety::to_string(s.fault.code), std::string(s.fault.text), joint_name(r, s.fault.joint)};
  // Why the robot holds and the way out, whenever it is PAUSED.
  if (s.state == OperatingState::kPaused && !s.estop) {
    HoldView h;
    if (s.hold_code == safety::FaultCode::kNone) {
      h.cause = "operator_pause";
      h.message = "paused by the operator";
      h.cleared = s.hold_can_resume;
      h.next = "Resume to continue; nothing moves until then.";
      if (!h.cleared) h.allowed.clear();
    } else {
      h.cause = safety::to_string(s.hold_code);
      h.message = s.fault.code == s.hold_code ? std::string(s.fault.text) : std::string();
      h.joint = s.fault.code == s.hold_code ? joint_name(r, s.fault.joint) : std::string();
      h.cleared = s.hold_can_resume;
      h.next = s.hold_can_resume ? "The cause has cleared: resume to continue."
                                 : "The cause persists: clear it before resuming.";
      if (!s.hold_can_resume) h.allowed.clear();
    }
    v.hold = std::move(h);
  }
  return v;
}

ServiceError not_enabled(const std::string& robot, const RobotSnapshot& s, const char* to) {
  return error(ErrorKind::conflict, "not_enabled",
               std::string("robot '") + robot + "' is " + state_name(s.state) +
                   (s.drives_ready ? "" : " and its drives are not ready") + "; enable it before " + to);
}

}  // namespace

RobotUnit* RobotRuntime::Impl::find(const std::string& robot) const {
  auto it = by_name.find(robot);
  return it == by_name.end() ? nullptr : it->second;
}

bool RobotRuntime::Impl::post(RobotUnit& r, const RobotCommand& c) {
  if (r.mailbox.push(c)) return true;
  r.mailbox_full.fetch_add(1, std::memory_order_relaxed);
  return false;
}

#define TENDRIL_ROBOT(name)               \
  RobotUnit* found = impl_->find(name);   \
  if (!found) return unknown_robot(name); \
  RobotUnit& r = *found;

std::vector<RobotDescription> RobotRuntime::robots() const {
  std::vector<RobotDescription> out;
  for (const auto& r : impl_->robots) {
    RobotDescription d;
    d.name = r->config.name;
    d.kind = r->config.kind;
    d.description = r->config.description;
    if (impl_->options.simulated_time)
      d.description += std::string(d.description.empty() ? "" : " ") +
                       "[SIMULATED TIME: the server steps its SIMULATED devices and control loop one period "
                       "at a time; a stall of the machine slips simulated time and is never lost time. Not "
                       "a real-time run]";
    for (const auto& j : r->config.joints) d.joints.push_back(j.limit);
    // Listed as an operator meets them: joint, the robot type's own modes, then path following (when
    // the type's plans apply), whatever their ids.
    for (std::size_t i = 0; i < r->modes.size(); ++i) {
      if (i == kPathFollowingMode) continue;
      d.modes.push_back({r->modes[i].name, r->modes[i].description});
    }
    if (r->plugin->path_following())
      d.modes.push_back({r->modes[kPathFollowingMode].name, r->modes[kPathFollowingMode].description});
    for (const auto* b : r->buses)
      d.buses.push_back({b->config.name, b->config.interface, b->virtual_bus != nullptr,
                         b->load + b->extra_bits_per_second / b->config.bitrate});
    d.command_timeout_ms = r->config.command_timeout_ms;
    d.cartesian = r->plugin->cartesian();
    d.vessel_entry = r->plugin->vessel_entry();
    out.push_back(std::move(d));
  }
  return out;
}

bool RobotRuntime::has_robot(const std::string& robot) const { return impl_->find(robot) != nullptr; }

namespace {
JointStateView joint_state(const RobotUnit& r, const RobotSnapshot& s, double wall_offset, bool setpoint) {
  JointStateView v;
  for (std::size_t i = 0; i < r.n; ++i) {
    v.name.push_back(r.config.joints[i].name());
    v.position.push_back(setpoint ? s.setpoint[i] : s.position[i]);
    v.velocity.push_back(setpoint ? s.setpoint_velocity[i] : s.velocity[i]);
    v.effort.push_back(setpoint ? 0.0 : s.effort[i]);
  }
  v.timestamp = wall_offset + s.time;
  v.tick = s.tick;
  return v;
}

std::vector<double> display_positions(const RobotUnit& r, const RobotSnapshot& s) {
  std::vector<double> q(r.n);
  r.plugin->display_positions({s.position.data(), r.n}, q);
  return q;
}
}  // namespace

Result<JointStateView> RobotRuntime::measured_js(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  return joint_state(r, r.snapshot.load(), impl_->wall_offset, false);
}

Result<JointStateView> RobotRuntime::setpoint_js(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  return joint_state(r, r.snapshot.load(), impl_->wall_offset, true);
}

Result<PoseView> RobotRuntime::measured_cp(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  const auto s = r.snapshot.load();
  const auto pose = r.plugin->kinematics().tip(display_positions(r, s));
  return PoseView{pose.position, pose.orientation, r.plugin->kinematics().frame(),
                  impl_->wall_offset + s.time};
}

Result<TwistView> RobotRuntime::measured_cv(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  const auto s = r.snapshot.load();
  const auto twist = r.plugin->measured_cv({s.position.data(), r.n}, {s.velocity.data(), r.n});
  if (!twist)
    return error(ErrorKind::not_supported, "not_supported",
                 "robot '" + robot + "' does not report a Cartesian velocity");
  return TwistView{*twist, r.plugin->kinematics().frame(), impl_->wall_offset + s.time};
}

Result<WrenchView> RobotRuntime::measured_cf(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  const auto s = r.snapshot.load();
  const auto force = r.plugin->measured_cf();
  if (!force)
    return error(ErrorKind::not_supported, "not_supported", "robot '" + robot + "' has no force sensor");
  return WrenchView{*force, "tool", impl_->wall_offset + s.time};
}

Result<ShapeView> RobotRuntime::shape(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  const auto s = r.snapshot.load();
  return ShapeView{r.plugin->kinematics().shape(display_positions(r, s)), r.plugin->kinematics().frame(),
                   impl_->wall_offset + s.time};
}

Result<OperatingStateView> RobotRuntime::operating_state(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  auto v = state_view(r, r.snapshot.load(), impl_->wall_offset);
  std::lock_guard lock(r.refusal_mutex);
  v.mode_refusal = r.mode_refusal;
  return v;
}

Result<DiagnosticsView> RobotRuntime::diagnostics(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  const auto s = r.snapshot.load();
  const auto ls = impl_->control_thread.statistics();
  DiagnosticsView d;
  d.timestamp = impl_->wall_offset + s.time;
  d.nominal_period_us = impl_->period * 1e6;
  d.period_error_p50_us = ls.period_error_p50_us;
  d.period_error_p99_us = ls.period_error_p99_us;
  d.period_error_max_us = ls.period_error_max_us;
  d.work_p50_us = ls.work_p50_us;
  d.work_p99_us = ls.work_p99_us;
  d.work_max_us = ls.work_max_us;
  d.overruns = ls.overruns;
  d.late_cycles = ls.late_cycles;
  d.lost_max_us = ls.lost_max_us;
  for (const auto* b : r.buses)
    d.bus_load = std::max(d.bus_load, b->load + b->extra_bits_per_second / b->config.bitrate);
  for (std::size_t i = 0; i < r.n; ++i) {
    d.setpoint.push_back(s.setpoint[i]);
    d.measured.push_back(s.position[i]);
  }
  return d;
}

Result<OperatingStateView> RobotRuntime::state_command(const std::string& robot, StateRequest request) {
  TENDRIL_ROBOT(robot)
  if (request == StateRequest::home)
    return error(ErrorKind::not_supported, "not_supported",
                 "robot '" + robot + "' has absolute encoders and needs no homing (is_homed is true)");
  safety::StateCommand sc = safety::StateCommand::kDisable;
  const char* name = "disable";
  switch (request) {
    case StateRequest::enable:
      sc = safety::StateCommand::kEnable;
      name = "enable";
      break;
    case StateRequest::pause:
      sc = safety::StateCommand::kPause;
      name = "pause";
      break;
    case StateRequest::resume:
      sc = safety::StateCommand::kResume;
      name = "resume";
      break;
    case StateRequest::disable:
    case StateRequest::home:
      break;
  }
  const auto s = r.snapshot.load();
  if (s.estop && sc != safety::StateCommand::kDisable)
    return error(ErrorKind::conflict, "estop_latched",
                 "the e-stop is latched; reset it (POST /api/v1/estop/reset) first");
  using OS = OperatingState;
  const bool allowed =
      (sc == safety::StateCommand::kEnable && (s.state == OS::kDisabled || s.state == OS::kEnabled)) ||
      sc == safety::StateCommand::kDisable ||
      (sc == safety::StateCommand::kPause && (s.state == OS::kEnabled || s.state == OS::kPaused)) ||
      (sc == safety::StateCommand::kResume && (s.state == OS::kPaused || s.state == OS::kEnabled));
  if (!allowed) {
    std::string why =
        std::string("cannot ") + name + " robot '" + robot + "' while it is " + state_name(s.state);
    if (s.state == OS::kFault)
      why += " (" + std::string(s.fault.text) + "); send disable to acknowledge the fault first";
    return error(ErrorKind::conflict, "invalid_state", why);
  }
  // Resume is refused while the hold's cause persists, with the cause and what to do, rather than
  // accepted and held again at the next tick.
  if (sc == safety::StateCommand::kResume && s.state == OS::kPaused && !s.hold_can_resume) {
    if (auto refusal = r.plugin->resume_refusal(state_view(r, s, impl_->wall_offset))) return *refusal;
    return error(ErrorKind::conflict, "hold_not_cleared",
                 "robot '" + robot + "' is held (" + safety::to_string(s.hold_code) + ": " +
                     std::string(s.fault.text) + ") and the cause persists; clear it before resuming");
  }
  RobotCommand c;
  c.kind = CommandKind::state;
  c.state = sc;
  c.received = std::chrono::steady_clock::now();
  if (!impl_->post(r, c)) return busy_mailbox(robot);
  OperatingStateView v = state_view(r, s, impl_->wall_offset);
  switch (sc) {
    case safety::StateCommand::kEnable:
      v.state = OS::kEnabled;
      v.busy = true;
      break;
    case safety::StateCommand::kDisable:
      v.state = OS::kDisabled;
      v.hold.reset();
      break;
    case safety::StateCommand::kPause:
      v.state = OS::kPaused;
      break;
    case safety::StateCommand::kResume:
      v.state = OS::kEnabled;
      v.hold.reset();
      break;
  }
  v.estop = false;
  v.fault.reset();
  return v;
}

Status RobotRuntime::mode(const std::string& robot, const std::string& m) {
  TENDRIL_ROBOT(robot)
  std::string available;
  for (std::size_t i = 0; i < r.modes.size(); ++i) {
    if (i == kPathFollowingMode && !r.plugin->path_following()) continue;
    available += (available.empty() ? "" : ", ") + r.modes[i].name;
  }
  const ModeId to = r.mode_id(m);
  if (to >= r.modes.size() || (to == kPathFollowingMode && !r.plugin->path_following()))
    return error(
        ErrorKind::invalid, "unknown_mode",
        "mode '" + m + "' is not available for robot '" + robot + "' (available: " + available + ")");
  const auto s = r.snapshot.load();
  if (s.mode == to) return Done{};
  // Every refusal is kept for operating_state, so a console that did not send the switch sees why.
  auto refuse = [&](ErrorKind kind, const std::string& code, const std::string& why) {
    std::lock_guard lock(r.refusal_mutex);
    r.mode_refusal = ModeRefusal{m, code, why, impl_->wall_offset + s.time};
    return error(kind, code, why);
  };
  if (s.estop)
    return refuse(ErrorKind::conflict, "estop_latched",
                  "the e-stop is latched; reset it (POST /api/v1/estop/reset) before changing mode");
  if (s.state == OperatingState::kFault)
    return refuse(ErrorKind::conflict, "invalid_state",
                  "robot '" + robot + "' is in fault (" + std::string(s.fault.text) +
                      "); send disable to acknowledge it before changing mode");
  if (s.busy)
    return refuse(ErrorKind::conflict, "not_holding",
                  "robot '" + robot + "' is moving; modes change only while it holds");
  if (s.hold_code != safety::FaultCode::kNone && s.state == OperatingState::kPaused)
    return refuse(ErrorKind::conflict, "held_after_limit",
                  "robot '" + robot + "' is held after a safety limit (" + safety::to_string(s.hold_code) +
                      "); clear it and resume before changing mode");
  if (to == kPathFollowingMode) {
    std::lock_guard lock(r.path_mutex);
    if (!r.path)
      return refuse(ErrorKind::conflict, "no_plan",
                    "no plan is loaded for robot '" + robot + "'; load one first (POST /api/v1/robots/" +
                        robot + "/path_following {\"plan\": \"<job id>\"})");
  }
  if (auto why = r.plugin->refuse_mode(to, state_view(r, s, impl_->wall_offset)))
    return refuse(why->kind, why->code, why->message);
  {
    std::lock_guard lock(r.refusal_mutex);
    r.mode_refusal.reset();
  }
  RobotCommand c;
  c.kind = CommandKind::mode;
  c.index = to;
  c.received = std::chrono::steady_clock::now();
  if (!impl_->post(r, c)) return busy_mailbox(robot);
  return Done{};
}

Result<double> RobotRuntime::move_jp(const std::string& robot, std::span<const double> goal) {
  TENDRIL_ROBOT(robot)
  if (auto e = check_vector(goal, r, "goal")) return *e;
  if (auto v = r.supervisor->check_goal(goal))
    return error(ErrorKind::invalid, "out_of_limits", r.supervisor->describe(v));
  const auto limits = r.operating_limits.load();
  if (auto why = operating_limit_violation(r, limits, goal, false)) return *why;
  const auto s = r.snapshot.load();
  if (s.mode != kJointMode)
    return error(ErrorKind::conflict, "wrong_mode",
                 "robot '" + robot + "' is in " + r.mode_name(s.mode) +
                     " mode; switch to joint mode for joint commands");
  if (s.estop)
    return error(ErrorKind::conflict, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled)
    return error(
        ErrorKind::conflict, "not_enabled",
        std::string("robot '") + robot + "' is " + state_name(s.state) + "; enable it before moving");
  RobotCommand c;
  c.kind = CommandKind::move_jp;
  c.count = static_cast<std::uint32_t>(r.n);
  std::copy(goal.begin(), goal.end(), c.values.begin());
  // While the drives are still enabling, the goal waits in the control thread and starts when they are.
  // Predict the duration with the same interpolator the control thread will use.
  teleop::QuinticInterpolator predict(r.n);
  predict.reset({s.setpoint.data(), r.n}, 0.0);
  predict.retarget(0.0, goal, {limits.max_velocity.data(), r.n}, {r.max_acceleration.data(), r.n});
  c.received = std::chrono::steady_clock::now();
  if (!impl_->post(r, c)) return busy_mailbox(robot);
  return predict.duration();
}

Status RobotRuntime::servo_jv(const std::string& robot, std::span<const double> velocity) {
  TENDRIL_ROBOT(robot)
  if (auto e = check_vector(velocity, r, "velocity")) return *e;
  if (auto v = r.supervisor->check_velocity(velocity))
    return error(ErrorKind::invalid, "out_of_limits", r.supervisor->describe(v));
  if (auto why = operating_limit_violation(r, r.operating_limits.load(), velocity, true)) return *why;
  const auto s = r.snapshot.load();
  if (s.estop)
    return error(ErrorKind::conflict, "estop_latched", "the e-stop is latched; reset and enable first");
  const auto type_says = r.plugin->check_servo(s.mode, state_view(r, s, impl_->wall_offset), velocity);
  if (type_says && !type_says->ok()) return type_says->error();
  if (!type_says) {
    if (s.mode != kJointMode)
      return error(ErrorKind::conflict, "wrong_mode",
                   "robot '" + robot + "' is in " + r.mode_name(s.mode) +
                       " mode; switch to joint mode for joint commands");
    if (s.state != OperatingState::kEnabled || !s.drives_ready)
      return not_enabled(robot, s, "streaming velocities");
  } else if (!s.drives_ready) {
    return not_enabled(robot, s, "streaming velocities");
  }
  RobotCommand c;
  c.kind = CommandKind::servo_jv;
  c.count = static_cast<std::uint32_t>(r.n);
  std::copy(velocity.begin(), velocity.end(), c.values.begin());
  c.received = std::chrono::steady_clock::now();
  if (!impl_->post(r, c)) return busy_mailbox(robot);
  return Done{};
}

namespace {
template <class Post>
Result<double> cartesian(RobotUnit& r, const std::string& robot, RobotPlugin::CartesianKind kind,
                         const CartesianPose& pose, const CartesianTwist& twist, double wall_offset,
                         Post&& post) {
  if (!r.plugin->cartesian())
    return error(ErrorKind::not_supported, "not_supported",
                 "robot '" + robot + "' takes no Cartesian commands (its type is " + r.config.kind + ")");
  const auto s = r.snapshot.load();
  if (s.estop)
    return error(ErrorKind::conflict, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled || !s.drives_ready) return not_enabled(robot, s, "moving");
  auto encoded = r.plugin->cartesian_command(kind, pose, twist, state_view(r, s, wall_offset));
  if (!encoded) return encoded.error();
  RobotCommand c;
  c.kind = CommandKind::plugin;
  c.plugin = encoded->first;
  c.received = std::chrono::steady_clock::now();
  if (!post(c)) return busy_mailbox(robot);
  return encoded->second;
}
}  // namespace

Result<double> RobotRuntime::move_cp(const std::string& robot, const CartesianPose& goal) {
  TENDRIL_ROBOT(robot)
  return cartesian(r, robot, RobotPlugin::CartesianKind::move_cp, goal, {}, impl_->wall_offset,
                   [&](const RobotCommand& c) { return impl_->post(r, c); });
}

Status RobotRuntime::servo_cp(const std::string& robot, const CartesianPose& goal) {
  TENDRIL_ROBOT(robot)
  auto result = cartesian(r, robot, RobotPlugin::CartesianKind::servo_cp, goal, {}, impl_->wall_offset,
                          [&](const RobotCommand& c) { return impl_->post(r, c); });
  if (!result) return result.error();
  return Done{};
}

Status RobotRuntime::servo_cv(const std::string& robot, const CartesianTwist& twist) {
  TENDRIL_ROBOT(robot)
  auto result = cartesian(r, robot, RobotPlugin::CartesianKind::servo_cv, {}, twist, impl_->wall_offset,
                          [&](const RobotCommand& c) { return impl_->post(r, c); });
  if (!result) return result.error();
  return Done{};
}

Status RobotRuntime::estop(const std::string& actor) {
  // The latch is set directly as well as through the mailbox, so a full mailbox cannot delay it.
  for (auto& r : impl_->robots) {
    r->supervisor->request_estop();
    RobotCommand c;
    c.kind = CommandKind::estop;
    actor.copy(c.actor, sizeof c.actor - 1);
    c.received = std::chrono::steady_clock::now();
    impl_->post(*r, c);
  }
  return Done{};
}

Status RobotRuntime::estop_reset(const std::string& actor) {
  (void)actor;
  for (auto& r : impl_->robots) {
    RobotCommand c;
    c.kind = CommandKind::estop_reset;
    // A press after this moment (its command queued behind this reset) keeps the latch.
    c.estop_presses = r->supervisor->estop_presses();
    c.received = std::chrono::steady_clock::now();
    if (!impl_->post(*r, c)) return busy_mailbox(r->config.name);
  }
  return Done{};
}

void RobotRuntime::operator_lost(const std::string& robot) {
  for (auto& r : impl_->robots) {
    if (r->config.name != robot) continue;
    RobotCommand c;
    c.kind = CommandKind::hold;
    impl_->post(*r, c);
  }
}

bool RobotRuntime::report_warning(const std::string& robot, safety::FaultCode code, const std::string& text) {
  for (auto& r : impl_->robots) {
    if (r->config.name != robot) continue;
    RobotCommand c;
    c.kind = CommandKind::warning;
    c.code = code;
    text.copy(c.text, sizeof c.text - 1);
    return impl_->post(*r, c);
  }
  return false;
}

// ---- Path following -------------------------------------------------------------------------

namespace {
ServiceError no_path_following(const std::string& robot) {
  return error(ErrorKind::not_supported, "not_supported",
               "robot '" + robot + "' has no path following (its type makes no plans)");
}
}  // namespace

Status RobotRuntime::load_path(const std::string& robot, PathPlan plan) {
  TENDRIL_ROBOT(robot)
  if (!r.plugin->path_following()) return no_path_following(robot);
  constexpr std::size_t kMaxSteps = 10000;
  if (plan.steps.empty()) return error(ErrorKind::malformed, "bad_request", "the plan has no steps");
  if (plan.steps.size() > kMaxSteps)
    return error(ErrorKind::invalid, "too_many_steps",
                 "the plan has " + std::to_string(plan.steps.size()) + " steps; at most " +
                     std::to_string(kMaxSteps) + " are accepted");
  auto loaded = std::make_shared<LoadedPath>();
  loaded->plan_id = plan.id;
  const auto limits = r.operating_limits.load();
  for (std::size_t k = 0; k < plan.steps.size(); ++k) {
    const std::string which = "step " + std::to_string(k);
    const auto& q = plan.steps[k];
    if (auto e = check_vector(q, r, "q")) return error(e->kind, e->code, which + ": " + e->message);
    if (auto v = r.supervisor->check_goal(q))
      return error(ErrorKind::invalid, "out_of_limits", which + ": " + r.supervisor->describe(v));
    if (auto why = operating_limit_violation(r, limits, q, false))
      return error(ErrorKind::invalid, "out_of_limits", which + ": " + why->message);
    // The control loop holds setpoints inside the soft margins, so a step beyond them would never be reached.
    for (std::size_t i = 0; i < r.n; ++i) {
      const auto& j = r.config.joints[i].limit;
      if (q[i] < j.lower + j.soft_margin || q[i] > j.upper - j.soft_margin) {
        std::ostringstream why;
        why << which << ": joint '" << j.name << "' " << q[i] << " " << j.unit
            << " lies within the soft margin (" << j.soft_margin << " " << j.unit << ") of its limits ["
            << j.lower << ", " << j.upper
            << "]; the setpoint is held short of it, so the step could not be reached";
        return error(ErrorKind::invalid, "out_of_limits", why.str());
      }
    }
    JointArray a{};
    std::copy(q.begin(), q.end(), a.begin());
    loaded->steps.push_back(a);
  }
  // A plan's geometry is in its insertion frame (vessel start at the origin, tangent +z): the robot's
  // vessel entry puts it where the robot is, in the one world the scene shows.
  if (const auto entry = r.plugin->vessel_entry()) {
    for (auto& p : plan.tips) p = *entry * p;
    for (auto& p : plan.vessel) p = *entry * p;
  }
  if (plan.tips.size() == plan.steps.size()) loaded->tips = std::move(plan.tips);
  // The scene shows at most ~200 points of the vessel.
  const std::size_t stride = std::max<std::size_t>(1, plan.vessel.size() / 200);
  for (std::size_t i = 0; i < plan.vessel.size(); i += stride)
    if (plan.vessel[i].allFinite()) loaded->vessel.push_back(plan.vessel[i]);
  const auto s = r.snapshot.load();
  if (s.busy)
    return error(ErrorKind::conflict, "not_holding",
                 "robot '" + robot + "' is moving; a plan is loaded only while it holds");
  std::shared_ptr<const LoadedPath> previous;
  {
    std::lock_guard lock(r.path_mutex);
    RobotCommand c;
    c.kind = CommandKind::path_loaded;
    c.received = std::chrono::steady_clock::now();
    if (!impl_->post(r, c)) return busy_mailbox(robot);
    previous = std::exchange(r.path, loaded);
  }
  // `previous` is freed here, on this network thread.
  return Done{};
}

Result<std::pair<std::int32_t, double>> RobotRuntime::path_step(const std::string& robot,
                                                                std::optional<std::int32_t> step,
                                                                std::int32_t advance) {
  TENDRIL_ROBOT(robot)
  if (!r.plugin->path_following()) return no_path_following(robot);
  const auto s = r.snapshot.load();
  if (s.estop)
    return error(ErrorKind::conflict, "estop_latched", "the e-stop is latched; reset and enable first");
  if (s.state != OperatingState::kEnabled || !s.drives_ready)
    return not_enabled(robot, s, "stepping along the plan");
  if (s.mode != kPathFollowingMode)
    return error(ErrorKind::conflict, "wrong_mode",
                 "robot '" + robot + "' is in " + r.mode_name(s.mode) +
                     " mode; switch to path_following (POST /api/v1/robots/" + robot + "/mode) first");
  if (s.busy)
    return error(ErrorKind::conflict, "not_holding",
                 "robot '" + robot + "' is still moving to step " + std::to_string(s.path_target) +
                     "; wait until it holds");
  std::lock_guard lock(r.path_mutex);
  if (!r.path) return error(ErrorKind::conflict, "no_plan", "no plan is loaded for robot '" + robot + "'");
  const auto count = static_cast<std::int64_t>(r.path->steps.size());
  const std::int64_t k = step ? *step : s.path_step + static_cast<std::int64_t>(advance);
  if (k < 0 || k >= count) {
    if (step)
      return error(ErrorKind::invalid, "out_of_range",
                   "step " + std::to_string(k) + " does not exist; the plan has steps 0.." +
                       std::to_string(count - 1));
    return error(ErrorKind::conflict, "end_of_plan",
                 k < 0 ? "already at the first step of the plan"
                       : "already at the last step of the plan (" + std::to_string(count - 1) + ")");
  }
  RobotCommand c;
  c.kind = CommandKind::path_step;
  c.index = static_cast<std::int32_t>(k);
  c.count = static_cast<std::uint32_t>(r.n);
  c.values = r.path->steps[static_cast<std::size_t>(k)];
  // The operating limits may have been tightened since the plan was loaded.
  const auto limits = r.operating_limits.load();
  if (auto why = operating_limit_violation(r, limits, {c.values.data(), r.n}, false))
    return error(ErrorKind::invalid, "out_of_limits", "step " + std::to_string(k) + ": " + why->message);
  teleop::QuinticInterpolator predict(r.n);
  predict.reset({s.setpoint.data(), r.n}, 0.0);
  predict.retarget(0.0, {c.values.data(), r.n}, {limits.max_velocity.data(), r.n},
                   {r.max_acceleration.data(), r.n});
  c.received = std::chrono::steady_clock::now();
  if (!impl_->post(r, c)) return busy_mailbox(robot);
  return std::pair{static_cast<std::int32_t>(k), predict.duration()};
}

Result<PathView> RobotRuntime::path_following(const std::string& robot) const {
  TENDRIL_ROBOT(robot)
  if (!r.plugin->path_following()) return no_path_following(robot);
  const auto s = r.snapshot.load();
  std::lock_guard lock(r.path_mutex);
  PathView v;
  v.loaded = r.path != nullptr;
  v.steps = r.path ? static_cast<std::int32_t>(r.path->steps.size()) : 0;
  v.step = s.path_step;
  v.target = s.path_target;
  v.moving = s.busy;
  v.mode = r.mode_name(s.mode);
  if (r.path) {
    v.plan = r.path->plan_id;
    v.vessel = r.path->vessel;
    v.tips = r.path->tips;
  }
  return v;
}

// ---- Parameters ----------------------------------------------------------------------------
// Writable: "/{robot}/{joint}/lower|upper|max_velocity" and "/{robot}/servo_timeout_s" (operating
// limits, within the configured ones). Read-only: the configured values ("configured_…"),
// max_acceleration, max_tracking_error and soft_margin.

namespace {
void robot_parameters(const RobotUnit& r, std::vector<Parameter>& out) {
  const auto limits = r.operating_limits.load();
  const std::string prefix = "/" + r.config.name + "/";
  for (std::size_t i = 0; i < r.n; ++i) {
    const auto& j = r.config.joints[i].limit;
    const std::string jp = prefix + j.name + "/";
    out.push_back({jp + "lower", limits.lower[i], true});
    out.push_back({jp + "upper", limits.upper[i], true});
    out.push_back({jp + "max_velocity", limits.max_velocity[i], true});
    out.push_back({jp + "configured_lower", j.lower, false});
    out.push_back({jp + "configured_upper", j.upper, false});
    out.push_back({jp + "configured_max_velocity", j.max_velocity, false});
    out.push_back({jp + "max_acceleration", j.max_acceleration, false});
    out.push_back({jp + "max_tracking_error", j.max_tracking_error, false});
    out.push_back({jp + "soft_margin", j.soft_margin, false});
  }
  out.push_back({prefix + "servo_timeout_s", limits.servo_timeout_s, true});
  out.push_back({prefix + "configured_servo_timeout_s", r.config.command_timeout_ms / 1000.0, false});
}

enum class LimitField { kLower, kUpper, kMaxVelocity, kServoTimeout };
struct Change {
  RobotUnit* robot = nullptr;
  std::size_t joint = 0;
  LimitField field = LimitField::kLower;
  std::optional<double> value;
  std::string name;
};
}  // namespace

std::vector<Parameter> RobotRuntime::parameters() const {
  std::vector<Parameter> out;
  for (const auto& r : impl_->robots) robot_parameters(*r, out);
  return out;
}

Result<std::vector<Parameter>> RobotRuntime::set_parameters(const std::vector<ParameterChange>& list) {
  if (list.empty())
    return error(ErrorKind::malformed, "bad_parameter", "expected a non-empty list of {\"name\", \"value\"}");
  std::vector<Change> changes;
  for (const auto& item : list) {
    Change change;
    change.name = item.name;
    change.value = item.value;
    const auto& name = change.name;
    const auto first = name.find('/', 1);
    const auto last = name.rfind('/');
    RobotUnit* r = nullptr;
    if (!name.empty() && name[0] == '/' && first != std::string::npos)
      r = impl_->find(name.substr(1, first - 1));
    bool known = false;
    if (r) {
      const std::string leaf = name.substr(last + 1);
      if (first == last) {
        known = leaf == "servo_timeout_s" || leaf == "configured_servo_timeout_s";
        change.field = LimitField::kServoTimeout;
        if (leaf != "servo_timeout_s" && known)
          return error(ErrorKind::forbidden, "read_only_parameter", "parameter " + name + " is read-only");
      } else {
        const std::string joint = name.substr(first + 1, last - first - 1);
        for (std::size_t i = 0; i < r->n; ++i)
          if (r->config.joints[i].name() == joint) {
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
            return error(
                ErrorKind::forbidden, "read_only_parameter",
                "parameter " + name + " is read-only (it comes from " + r->config.file.string() + ")");
          } else {
            known = false;
          }
        }
      }
    }
    if (!known)
      return error(ErrorKind::not_found, "unknown_parameter",
                   "no parameter named \"" + name + "\" (getParameters with no names lists them)");
    if (change.value && !std::isfinite(*change.value))
      return error(ErrorKind::invalid, "not_finite", "parameter " + name + ": value is not finite");
    change.robot = r;
    changes.push_back(std::move(change));
  }

  // Per robot, all or nothing: compute the new limits, validate, then publish them in one store.
  std::map<RobotUnit*, safety::OperatingLimits> updated;
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
    const auto& jc = c.robot->config.joints[c.joint].limit;
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
    const auto configured =
        safety::OperatingLimits::configured(r->supervisor->limits(), r->config.command_timeout_ms / 1000.0);
    std::string why;
    if (!safety::tightens(limits, configured, r->n, r->supervisor->limits(), &why))
      return error(ErrorKind::invalid, "out_of_range", "/" + r->config.name + "/" + why);
    // Limits change only while the robot holds inside them, so no running motion is cut short.
    const auto s = r->snapshot.load();
    if (s.busy)
      return error(ErrorKind::conflict, "not_holding",
                   "robot '" + r->config.name + "' is moving; limits change only while it holds");
    for (std::size_t i = 0; i < r->n; ++i) {
      if (s.setpoint[i] < limits.lower[i] || s.setpoint[i] > limits.upper[i])
        return error(ErrorKind::invalid, "out_of_range",
                     "joint '" + r->config.joints[i].name() + "' of robot '" + r->config.name + "' is at " +
                         std::to_string(s.setpoint[i]) + " " + r->config.joints[i].unit() +
                         ", outside the new range; move it inside first");
    }
  }
  for (auto& [r, limits] : updated) r->operating_limits.store(limits);
  std::vector<Parameter> out;
  for (const auto& p : parameters())
    for (const auto& c : changes)
      if (p.name == c.name) {
        out.push_back(p);
        break;
      }
  return out;
}

// ---- Events and metrics ----------------------------------------------------------------------

void RobotRuntime::Impl::collect_events() const {
  std::lock_guard lock(events_mutex);
  for (const auto& r : robots) {
    r->supervisor->events().drain([&](const safety::SafetyEvent& e) {
      SafetyEventView v{wall_offset + e.time,      r->config.name,     safety::to_string(e.kind),
                        safety::to_string(e.code), state_name(e.from), state_name(e.to),
                        std::string(e.text),       std::string()};
      if (e.joint >= 0 && static_cast<std::size_t>(e.joint) < r->n)
        v.joint = r->config.joints[static_cast<std::size_t>(e.joint)].name();
      events.push_back(std::move(v));
      ++events_total;
      if (events.size() > 1000) events.pop_front();
    });
  }
}

std::vector<SafetyEventView> RobotRuntime::faults(std::size_t max_events) const {
  impl_->collect_events();
  std::lock_guard lock(impl_->events_mutex);
  std::vector<SafetyEventView> out;
  for (auto it = impl_->events.rbegin(); it != impl_->events.rend() && out.size() < max_events; ++it)
    out.push_back(*it);
  return out;
}

std::vector<SafetyEventView> RobotRuntime::events_since(std::uint64_t since, std::uint64_t& total) const {
  impl_->collect_events();
  std::lock_guard lock(impl_->events_mutex);
  total = impl_->events_total;
  std::vector<SafetyEventView> out;
  if (since >= total) return out;
  const auto fresh = std::min<std::uint64_t>(total - since, impl_->events.size());
  for (auto it = impl_->events.end() - static_cast<std::ptrdiff_t>(fresh); it != impl_->events.end(); ++it)
    out.push_back(*it);
  return out;
}

std::string RobotRuntime::metrics() const {
  std::ostringstream m;
  const auto ls = impl_->control_thread.statistics();
  m << "# HELP tendril_simulated_time 1 when the server runs in simulated time (tendrild --simulated-time: "
       "stepped, a stall slips simulated time and is never lost; the control_* figures below then time the "
       "pacing thread), 0 in real time.\n# TYPE tendril_simulated_time gauge\ntendril_simulated_time "
    << (impl_->options.simulated_time ? 1 : 0) << "\n";
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
    m << "tendril_bus_load{bus=\"" << b->config.name << "\"} "
      << b->load + b->extra_bits_per_second / b->config.bitrate << "\n";
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

}  // namespace tendril::server
