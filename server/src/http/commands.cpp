// The command preamble every robot command passes (role, robot, lease), the lease actions and
// run-time parameters. Shared by REST, Foxglove services and client-published streams.
#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;
using namespace tendril::server::http;

namespace {
std::string command_name(const CommandRef& command) {
  switch (command.kind) {
    case Command::kEstop:
      return "estop";
    case Command::kEstopReset:
      return "estop_reset";
    case Command::kRobotCommand:
      return command.name;
    default:
      break;
  }
  for (const auto& [name, kind] : core_robot_commands())
    if (kind == command.kind) return name;
  return "command";
}
}  // namespace

ApiResult HttpServer::Impl::execute(const CommandRef& command, const std::string& robot, const json& body,
                                    const Identity& who) {
  ApiResult result = execute_checked(command, robot, body, who);
  if (opts.tap && command.kind != Command::kAuthorizeOnly) {
    try {
      opts.tap->command(wall_time_ns(), robot, command_name(command), who.label, body, result.status,
                        result.ok() ? std::string() : result.code + ": " + result.message);
    } catch (const std::exception& e) {
      log(std::string("recording: a command was not recorded: ") + e.what());
    }
  }
  return result;
}

ApiResult HttpServer::Impl::execute_checked(const CommandRef& command, const std::string& robot,
                                            const json& body, const Identity& who) {
  if (opts.replay && command.kind != Command::kAuthorizeOnly) {
    // Before the role and the lease: in a replay no robot is driven, whoever asks.
    return ApiResult::error(
        409, "replay_mode",
        "this server is replaying a recording (tendrild --replay): it drives no robot, so "
        "it takes no commands; what you see is the recorded session");
  }
  if (command.kind == Command::kEstop) {
    try {
      return api.estop_from(who.label + (who.role == Role::kViewer ? " (viewer)" : " (operator)"));
    } catch (const std::exception& e) {
      return ApiResult::error(500, "internal_error", e.what());
    }
  }
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators command");
  }
  const auto now = SteadyClock::now();
  std::uint64_t generation = 0;
  if (command.kind == Command::kEstopReset) {
    // The reset brings every robot back (DISABLED): no one else may be commanding any of them. The
    // caller holds the lease of at least one robot and of every robot whose lease is held at all.
    bool holds_one = false;
    for (const auto& r : leases.robots()) {
      auto* lease = leases.find(r);
      const auto status = lease->status(who.lease_key, now);
      if (status.held && !status.yours)
        return lease_refusal(who, now, r,
                             "the e-stop reset brings every robot back and needs every held lease");
      if (status.yours) holds_one = lease->use(who.lease_key, now).has_value() || holds_one;
    }
    if (!holds_one) return lease_refusal(who, now, {}, "the e-stop reset needs it");
  } else {
    if (!api.has_robot(robot)) return unknown_robot_result(robot);
    auto* lease = leases.find(robot);
    const auto used = lease ? lease->use(who.lease_key, now) : std::nullopt;
    if (!used) return lease_refusal(who, now, robot, "commands need it");
    generation = *used;
  }
  try {
    switch (command.kind) {
      case Command::kStateCommand:
        return api.state_command(robot, body);
      case Command::kMode:
        return api.mode(robot, body);
      case Command::kMoveJp:
        return api.move_jp(robot, body);
      case Command::kMoveCp:
        return api.move_cp(robot, body);
      case Command::kServoCp:
      case Command::kServoCv:
      case Command::kServoJv: {
        ApiResult result = command.kind == Command::kServoJv   ? api.servo_jv(robot, body)
                           : command.kind == Command::kServoCv ? api.servo_cv(robot, body)
                                                               : api.servo_cp(robot, body);
        if (result.ok()) note_servo(robot, generation, SteadyClock::now());
        return result;
      }
      case Command::kRobotCommand: {
        ApiResult result = api.robot_command(robot, command.name, body);
        // A stream that moves the robot (e.g. a joystick with its deadman held) counts as streaming
        // commands: a takeover must not cut it off silently.
        if (result.ok()) {
          for (const auto& info : api.robot_commands(robot)) {
            if (info.name != command.name || info.motion_flag.empty()) continue;
            const auto flag = body.find(info.motion_flag);
            if (flag != body.end() && flag->is_boolean() && flag->get<bool>())
              note_servo(robot, generation, SteadyClock::now());
          }
        }
        return result;
      }
      case Command::kEstopReset:
        return api.estop_reset();
      case Command::kAuthorizeOnly:
        return ApiResult::success(json::object());
      case Command::kEstop:
        break;
    }
  } catch (const std::exception& e) {
    return ApiResult::error(500, "internal_error", e.what());
  }
  return ApiResult::error(500, "internal_error", "unhandled command");
}

std::string HttpServer::Impl::lease_phrase(const std::vector<std::string>& robots) const {
  if (leases.robots().size() <= 1 || robots.empty()) return "the operator lease";
  std::string phrase = "the operator lease of ";
  for (std::size_t i = 0; i < robots.size(); ++i) {
    if (i > 0) phrase += i + 1 == robots.size() ? " and " : ", ";
    phrase += robots[i];
  }
  return phrase;
}

std::string HttpServer::Impl::lease_route(const std::string& robot) {
  return robot.empty() ? "POST /api/v1/lease" : "POST /api/v1/robots/" + robot + "/lease";
}

ApiResult HttpServer::Impl::lease_refusal(const Identity& who, SteadyClock::time_point now,
                                          const std::string& robot, const std::string& what) const {
  // `what` says what needed the lease, e.g. "commands need it". An empty robot: any robot's lease.
  const auto* lease = robot.empty() ? nullptr : leases.find(robot);
  const auto status = lease ? lease->status(who.lease_key, now) : http::LeaseManager::Status{};
  const std::string phrase = lease_phrase(robot.empty() ? std::vector<std::string>{} : std::vector{robot});
  // On a server of several robots, a robot's own route takes just that robot's lease.
  const std::string route = leases.robots().size() > 1 && !robot.empty()
                                ? lease_route(robot) + " or " + lease_route({})
                                : lease_route({});
  std::string message;
  if (status.held) {
    message = phrase + " is held by " + status.holder_label + "; " + what + " (" + route + ")";
  } else {
    message = "take " + phrase + " first (" + route + "); " + what;
  }
  // A caller that sent a lease token which no longer holds: say so, it is the likeliest mistake.
  if (who.lease_key.rfind(http::LeaseManager::kTokenKeyPrefix, 0) == 0 &&
      !leases.token_held_by(who.lease_key, now)) {
    message += ". The X-Tendril-Lease token sent is not a current lease's (it lapsed after " +
               std::to_string(leases.timeout().count() / 1000) +
               " s without use, was released or taken over); POST /api/v1/lease answers a new one";
  }
  ApiResult refused = ApiResult::error(409, "lease_held", message);
  if (!robot.empty() && leases.robots().size() > 1) refused.error_details = {{"robot", robot}};
  return refused;
}

std::optional<ApiResult> HttpServer::Impl::use_leases(const Identity& who, SteadyClock::time_point now,
                                                      const std::vector<std::string>& robots,
                                                      const std::string& what) {
  std::optional<ApiResult> refused;
  for (const auto& r : robots) {
    const auto* lease = leases.find(r);
    if (lease && lease->holds(who.lease_key, now)) {
      leases.find(r)->use(who.lease_key, now);
    } else if (!refused) {
      refused = lease_refusal(who, now, r, what);
    }
  }
  return refused;
}

json HttpServer::Impl::lease_description(const Identity& who, SteadyClock::time_point now,
                                         const std::vector<std::string>& robots,
                                         const std::string& lease_token) const {
  // A grant is the caller's even when it asked with a token that held nothing (then the new token is
  // its only key).
  const std::string key =
      lease_token.empty() ? who.lease_key : std::string(http::LeaseManager::kTokenKeyPrefix) + lease_token;
  bool held = false;
  bool mine = !robots.empty();
  std::string holder;  // another holder first: that is who the caller waits for
  std::string mine_label;
  double remaining = 0.0;  // of the caller's leases, the one that lapses first
  bool have_remaining = false;
  json per_robot = json::object();
  for (const auto& r : robots) {
    const auto status = leases.find(r)->status(key, now);
    const double left = static_cast<double>(status.remaining.count()) / 1000.0;
    per_robot[r] = {{"held", status.held},
                    {"holder", status.held ? json(status.holder_label) : json(nullptr)},
                    {"mine", status.yours},
                    {"expires_s", left}};
    held = held || status.held;
    mine = mine && status.yours;
    if (status.held && !status.yours && holder.empty()) holder = status.holder_label;
    if (status.yours) {
      mine_label = status.holder_label;
      if (!have_remaining || left < remaining) remaining = left;
      have_remaining = true;
    }
  }
  if (holder.empty()) holder = mine_label;
  // "held/holder/mine/expires_s" is the contract; "yours/expires_in_s/you" stay for older clients.
  // With several robots, "robots" has each robot's lease and "mine" means every one of them.
  json description = {{"held", held},     {"holder", held ? json(holder) : json(nullptr)},
                      {"mine", mine},     {"expires_s", remaining},
                      {"yours", mine},    {"expires_in_s", remaining},
                      {"you", who.label}, {"robots", std::move(per_robot)}};
  // Only the answer that grants the lease carries its token (a secret of the holder).
  if (!lease_token.empty()) description["lease_token"] = lease_token;
  return description;
}

ApiResult HttpServer::Impl::lease_action(const std::string& action, const Identity& who,
                                         const std::string& takeover_token, const std::string& robot) {
  std::vector<std::string> targets = leases.robots();
  if (!robot.empty()) {
    if (!leases.find(robot)) return unknown_robot_result(robot);
    targets = {robot};
  }
  const auto now = SteadyClock::now();
  if (action == "status") return ApiResult::success(lease_description(who, now, targets));
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role", "viewers cannot take or release the operator lease");
  }
  // Taking or giving back several robots' leases is one step for every other lease action.
  std::lock_guard actions(lease_actions_mutex);
  const std::string route = lease_route(robot);
  if (action == "acquire") {
    // Robots whose lease someone else holds, and the caller's own token for the ones it takes.
    std::vector<std::string> others;
    std::vector<std::string> holders;
    bool fresh = false;
    for (const auto& r : targets) {
      const auto status = leases.find(r)->status(who.lease_key, now);
      if (status.held && !status.yours) {
        others.push_back(r);
        if (std::find(holders.begin(), holders.end(), status.holder_label) == holders.end())
          holders.push_back(status.holder_label);
      }
      fresh = fresh || !status.yours;
    }
    std::string holder_names;
    for (std::size_t i = 0; i < holders.size(); ++i) holder_names += (i > 0 ? " and " : "") + holders[i];
    const std::string token = leases.token_held_by(who.lease_key, now).value_or(random_hex(16));
    std::vector<std::string> previous_keys;
    if (!others.empty()) {
      if (takeover_token.empty()) {
        // Refused: offer a takeover, to be confirmed by POSTing the token back within 15 s.
        const std::string offer = random_hex(16);
        for (const auto& r : others) leases.find(r)->issue_takeover_token(who.lease_key, offer, now);
        ApiResult refused = ApiResult::error(409, "lease_held",
                                             lease_phrase(robot.empty() ? others : targets) + " is held by " +
                                                 holder_names + "; to take it over, confirm with " + route +
                                                 " {\"takeover_token\": \"" + offer + "\"} within 15 s");
        refused.error_details = {{"holder", holders.front()}, {"takeover_token", offer}};
        if (leases.robots().size() > 1) refused.error_details["robots"] = others;
        return refused;
      }
      // Confirmation of a takeover. Never while a holder streams servo commands: the stream would
      // stop in mid-motion under someone else's control.
      for (const auto& r : others) {
        const auto held = leases.find(r)->status(who.lease_key, now);
        if (servo_streaming(r, held.generation, now)) {
          ApiResult refused =
              ApiResult::error(409, "servo_active",
                               held.holder_label + " is streaming servo commands" +
                                   (leases.robots().size() > 1 ? " to " + r : "") +
                                   "; the lease cannot be taken over while the robot is servoing. Ask them "
                                   "to stop, or retry when "
                                   "the stream has ended (the takeover token stays valid for 15 s)");
          refused.error_details = {{"holder", held.holder_label}};
          return refused;
        }
        if (!leases.find(r)->takeover_token_valid(who.lease_key, takeover_token, now)) {
          return ApiResult::error(409, "bad_takeover_token",
                                  "the takeover token is unknown, expired (it lasts 15 s) or was issued to "
                                  "another client; " +
                                      route + " without it to get a new one");
        }
      }
      for (const auto& r : others) {
        const auto takeover = leases.find(r)->take_over(who.lease_key, who.label, takeover_token, token, now);
        previous_keys.insert(previous_keys.end(), takeover.previous_keys.begin(),
                             takeover.previous_keys.end());
      }
    }
    std::string granted = token;
    for (const auto& r : targets) {
      if (std::find(others.begin(), others.end(), r) != others.end()) continue;
      if (const auto grant = leases.find(r)->acquire(who.lease_key, who.label, token, now))
        granted = grant->lease_token;
    }
    if (!others.empty()) {
      if (!previous_keys.empty()) {
        broadcast_status(fg::status(fg::StatusLevel::kWarning,
                                    lease_phrase(others) + " was taken over by " + who.label +
                                        "; your commands are refused until you take it back",
                                    "lease"),
                         previous_keys);
      }
      broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                  who.label + " took over " + lease_phrase(others) + " from " + holder_names,
                                  "lease"));
    } else if (fresh) {
      broadcast_status(
          fg::status(fg::StatusLevel::kInfo, who.label + " holds " + lease_phrase(targets), "lease"));
    }
    return ApiResult::success(lease_description(who, now, targets, granted));
  }
  if (action == "release") {
    std::vector<std::string> released;
    std::string other_holder;
    for (const auto& r : targets) {
      const auto status = leases.find(r)->status(who.lease_key, now);
      if (status.held && !status.yours && other_holder.empty()) other_holder = status.holder_label;
      if (status.yours && leases.find(r)->release(who.lease_key, now)) released.push_back(r);
    }
    if (released.empty() && !other_holder.empty()) {
      return ApiResult::error(409, "lease_held",
                              lease_phrase(targets) + " is held by " + other_holder + ", not you");
    }
    if (!released.empty()) {
      broadcast_status(
          fg::status(fg::StatusLevel::kInfo, who.label + " released " + lease_phrase(released), "lease"));
    }
    return ApiResult::success(lease_description(who, now, targets));
  }
  return ApiResult::error(400, "bad_action", "lease action must be \"acquire\", \"release\" or \"status\"");
}

void HttpServer::Impl::connection_closed(const Identity& who) {
  const auto now = SteadyClock::now();
  for (const auto& robot : leases.robots()) {
    auto* lease = leases.find(robot);
    // The holder's console went away: the robot holds now, and a reconnect must command afresh.
    if (lease->holds(who.lease_key, now)) api.operator_lost(robot);
    // A lease bound to this connection has no one left who could use it: free it at once rather than
    // leave it to a dead connection until it lapses.
    if (who.connection_bound && lease->release_bound_to(who.lease_key, now)) {
      broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                  who.label + " closed its connection; " + lease_phrase({robot}) + " is free",
                                  "lease"));
    }
  }
}

ApiResult HttpServer::Impl::set_parameters(const json& parameters, const Identity& who) {
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators set parameters");
  }
  const auto now = SteadyClock::now();
  // A robot's parameters ("/<robot>/...") need that robot's lease; any other needs one of the caller's.
  std::vector<std::string> robots;
  bool other = false;
  if (parameters.is_array()) {
    for (const auto& p : parameters) {
      const std::string name = p.is_object() ? p.value("name", std::string()) : std::string();
      const auto slash = name.find('/', 1);
      const std::string robot = name.size() > 1 && name[0] == '/' && slash != std::string::npos
                                    ? name.substr(1, slash - 1)
                                    : std::string();
      if (!robot.empty() && leases.find(robot)) {
        if (std::find(robots.begin(), robots.end(), robot) == robots.end()) robots.push_back(robot);
      } else {
        other = true;
      }
    }
  }
  if (auto refused = use_leases(who, now, robots, "setting its parameters needs it")) return *refused;
  if ((other || robots.empty()) && !leases.token_held_by(who.lease_key, now))
    return lease_refusal(who, now, {}, "setting parameters needs it");
  ApiResult result;
  try {
    result = api.set_parameters(parameters);
  } catch (const std::exception& e) {
    return ApiResult::error(500, "internal_error", e.what());
  }
  if (result.ok()) {
    publish_parameter_updates(result.body);
    std::string names;
    for (const auto& p : result.body) {
      names += (names.empty() ? "" : ", ") + p.value("name", std::string()) + " = " +
               dump(p.value("value", json()));
    }
    broadcast_status(fg::status(fg::StatusLevel::kInfo, who.label + " set " + names, "parameters"));
  }
  return result;
}

ApiResult HttpServer::command(const std::string& robot, const std::string& command, const json& body,
                              const std::string& lease_token, const std::string& client) {
  Impl& s = *impl_;
  // The caller is an operator whose only claim to the lease is the token in its sample, like a REST
  // caller sending X-Tendril-Lease; without a token, a key no lease can be bound to.
  Identity who;
  who.role = Role::kOperator;
  who.lease_key = lease_token.empty() ? std::string("none:") + client
                                      : std::string(http::LeaseManager::kTokenKeyPrefix) + lease_token;
  who.label = client;
  if (!s.api.has_robot(robot)) return unknown_robot_result(robot);
  const auto& core = core_robot_commands();
  if (const auto it = core.find(command); it != core.end()) return s.execute(it->second, robot, body, who);
  for (const auto& info : s.api.robot_commands(robot)) {
    if (info.name == command) return s.execute(CommandRef(Command::kRobotCommand, command), robot, body, who);
  }
  return ApiResult::error(404, "not_found", "robot '" + robot + "' has no command '" + command + "'");
}

void HttpServer::add_metrics_source(std::function<std::string()> source) {
  Impl& s = *impl_;
  std::lock_guard lifecycle(s.lifecycle_mutex);
  if (s.running)
    throw HttpServerError("add_metrics_source: the server is already running; add sources before start()");
  s.metrics_sources.push_back(std::move(source));
}

}  // namespace tendril::server
