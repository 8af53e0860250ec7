// The command preamble every robot command passes (role, robot, lease), the lease actions and
// run-time parameters. Shared by REST, Foxglove services and client-published streams.
#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;
using namespace tendril::server::http;

ApiResult HttpServer::Impl::execute(const CommandRef& command, const std::string& robot, const json& body,
                                    const Identity& who) {
  if (command.kind == Command::kEstop) {
    try {
      return api.estop_from(who.label + (who.role == Role::kViewer ? " (viewer)" : " (operator)"));
    } catch (const std::exception& e) {
      return ApiResult::error(500, "internal_error", e.what());
    }
  }
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role", "this session is a viewer (read-only); only operators command");
  }
  const bool needs_robot = command.kind != Command::kEstopReset;
  if (needs_robot && !api.has_robot(robot)) return unknown_robot_result(robot);
  const auto now = SteadyClock::now();
  if (!lease.use(who.lease_key, now)) {
    const auto status = lease.status(who.lease_key, now);
    return ApiResult::error(409, "lease_held",
                            status.held ? "the operator lease is held by " + status.holder_label +
                                              "; commands need the lease (POST /api/v1/lease)"
                                        : "take the operator lease first (POST /api/v1/lease)");
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
        if (result.ok()) note_servo(who.lease_key, SteadyClock::now());
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
            if (flag != body.end() && flag->is_boolean() && flag->get<bool>()) note_servo(who.lease_key, SteadyClock::now());
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

json HttpServer::Impl::lease_description(const Identity& who, SteadyClock::time_point now) const {
  const auto status = lease.status(who.lease_key, now);
  const double remaining = static_cast<double>(status.remaining.count()) / 1000.0;
  // "held/holder/mine/expires_s" is the contract; "yours/expires_in_s/you" stay for older clients.
  return {{"held", status.held},   {"holder", status.held ? json(status.holder_label) : json(nullptr)},
          {"mine", status.yours},  {"expires_s", remaining},
          {"yours", status.yours}, {"expires_in_s", remaining},
          {"you", who.label}};
}

ApiResult HttpServer::Impl::lease_action(const std::string& action, const Identity& who,
                                         const std::string& takeover_token) {
  const auto now = SteadyClock::now();
  if (action == "status") return ApiResult::success(lease_description(who, now));
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role", "viewers cannot take or release the operator lease");
  }
  if (action == "acquire") {
    const bool had_it = lease.status(who.lease_key, now).yours;
    if (lease.acquire(who.lease_key, who.label, now)) {
      if (!had_it) {
        broadcast_status(
            fg::status(fg::StatusLevel::kInfo, who.label + " holds the operator lease", "lease"));
      }
      return ApiResult::success(lease_description(who, now));
    }
    const auto held = lease.status(who.lease_key, now);
    const auto holder_key = lease.holder(now);
    if (!takeover_token.empty()) {
      // Confirmation of a takeover. Never while the holder streams servo commands: the stream would
      // stop in mid-motion under someone else's control.
      if (holder_key && servo_streaming(*holder_key, now)) {
        ApiResult refused = ApiResult::error(
            409, "servo_active",
            held.holder_label +
                " is streaming servo commands; the lease cannot be taken over while the robot is servoing. "
                "Ask them to stop, or retry when the stream has ended (the takeover token stays valid for "
                "15 s)");
        refused.error_details = {{"holder", held.holder_label}};
        return refused;
      }
      std::string previous_key;
      if (lease.take_over(who.lease_key, who.label, takeover_token, now, previous_key) ==
          LeaseManager::TakeoverResult::kBadToken) {
        return ApiResult::error(409, "bad_takeover_token",
                                "the takeover token is unknown, expired (it lasts 15 s) or was issued to "
                                "another client; POST /api/v1/lease without it to get a new one");
      }
      if (!previous_key.empty()) {
        broadcast_status(fg::status(fg::StatusLevel::kWarning,
                                    "the operator lease was taken over by " + who.label +
                                        "; your commands are refused until you take it back",
                                    "lease"),
                         previous_key);
      }
      broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                  who.label + " took over the operator lease from " + held.holder_label,
                                  "lease"));
      return ApiResult::success(lease_description(who, now));
    }
    // Refused: offer a takeover, to be confirmed by POSTing the token back within 15 s.
    const std::string token = random_hex(16);
    lease.issue_takeover_token(who.lease_key, token, now);
    ApiResult refused =
        ApiResult::error(409, "lease_held",
                         "the operator lease is held by " + held.holder_label +
                             "; to take it over, confirm with POST /api/v1/lease {\"takeover_token\": \"" +
                             token + "\"} within 15 s");
    refused.error_details = {{"holder", held.holder_label}, {"takeover_token", token}};
    return refused;
  }
  if (action == "release") {
    const auto status = lease.status(who.lease_key, now);
    if (status.held && !status.yours) {
      return ApiResult::error(409, "lease_held",
                              "the operator lease is held by " + status.holder_label + ", not you");
    }
    if (lease.release(who.lease_key, now)) {
      broadcast_status(
          fg::status(fg::StatusLevel::kInfo, who.label + " released the operator lease", "lease"));
    }
    return ApiResult::success(lease_description(who, now));
  }
  return ApiResult::error(400, "bad_action", "lease action must be \"acquire\", \"release\" or \"status\"");
}

ApiResult HttpServer::Impl::set_parameters(const json& parameters, const Identity& who) {
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators set parameters");
  }
  const auto now = SteadyClock::now();
  if (!lease.use(who.lease_key, now)) {
    const auto status = lease.status(who.lease_key, now);
    return ApiResult::error(409, "lease_held",
                            status.held ? "the operator lease is held by " + status.holder_label +
                                              "; setting parameters needs the lease"
                                        : "take the operator lease first (POST /api/v1/lease)");
  }
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
}  // namespace tendril::server
