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
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators command");
  }
  const bool needs_robot = command.kind != Command::kEstopReset;
  if (needs_robot && !api.has_robot(robot)) return unknown_robot_result(robot);
  const auto now = SteadyClock::now();
  const auto generation = lease.use(who.lease_key, now);
  if (!generation) return lease_refusal(who, now, "commands need the lease");
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
        if (result.ok()) note_servo(*generation, SteadyClock::now());
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
              note_servo(*generation, SteadyClock::now());
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

ApiResult HttpServer::Impl::lease_refusal(const Identity& who, SteadyClock::time_point now,
                                          const std::string& what) const {
  // `what` says what needed the lease, e.g. "commands need the lease".
  const auto status = lease.status(who.lease_key, now);
  std::string message;
  if (status.held) {
    message = "the operator lease is held by " + status.holder_label + "; " + what + " (POST /api/v1/lease)";
  } else {
    message = "take the operator lease first (POST /api/v1/lease)";
  }
  // A caller that sent a lease token which no longer holds: say so, it is the likeliest mistake.
  if (who.lease_key.rfind(http::LeaseManager::kTokenKeyPrefix, 0) == 0) {
    message += ". The X-Tendril-Lease token sent is not the current lease's (it lapsed after " +
               std::to_string(lease.timeout().count() / 1000) +
               " s without use, was released or taken over); POST /api/v1/lease answers a new one";
  }
  return ApiResult::error(409, "lease_held", message);
}

json HttpServer::Impl::lease_description(const Identity& who, SteadyClock::time_point now,
                                         const std::string& lease_token) const {
  // A grant is the caller's even when it asked with a token that held nothing (then the new token is
  // its only key).
  const auto status = lease.status(
      lease_token.empty() ? who.lease_key : std::string(http::LeaseManager::kTokenKeyPrefix) + lease_token,
      now);
  const double remaining = static_cast<double>(status.remaining.count()) / 1000.0;
  // "held/holder/mine/expires_s" is the contract; "yours/expires_in_s/you" stay for older clients.
  json description = {
      {"held", status.held},   {"holder", status.held ? json(status.holder_label) : json(nullptr)},
      {"mine", status.yours},  {"expires_s", remaining},
      {"yours", status.yours}, {"expires_in_s", remaining},
      {"you", who.label}};
  // Only the answer that grants the lease carries its token (a secret of the holder).
  if (!lease_token.empty()) description["lease_token"] = lease_token;
  return description;
}

ApiResult HttpServer::Impl::lease_action(const std::string& action, const Identity& who,
                                         const std::string& takeover_token) {
  const auto now = SteadyClock::now();
  if (action == "status") return ApiResult::success(lease_description(who, now));
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role", "viewers cannot take or release the operator lease");
  }
  if (action == "acquire") {
    const auto before = lease.status(who.lease_key, now);
    if (const auto grant = lease.acquire(who.lease_key, who.label, random_hex(16), now)) {
      if (!before.yours) {
        broadcast_status(
            fg::status(fg::StatusLevel::kInfo, who.label + " holds the operator lease", "lease"));
      }
      return ApiResult::success(lease_description(who, now, grant->lease_token));
    }
    const auto held = lease.status(who.lease_key, now);
    if (!takeover_token.empty()) {
      // Confirmation of a takeover. Never while the holder streams servo commands: the stream would
      // stop in mid-motion under someone else's control.
      if (held.held && servo_streaming(held.generation, now)) {
        ApiResult refused = ApiResult::error(
            409, "servo_active",
            held.holder_label +
                " is streaming servo commands; the lease cannot be taken over while the robot is servoing. "
                "Ask them to stop, or retry when the stream has ended (the takeover token stays valid for "
                "15 s)");
        refused.error_details = {{"holder", held.holder_label}};
        return refused;
      }
      const auto takeover = lease.take_over(who.lease_key, who.label, takeover_token, random_hex(16), now);
      if (takeover.result == http::LeaseManager::TakeoverResult::kBadToken) {
        return ApiResult::error(409, "bad_takeover_token",
                                "the takeover token is unknown, expired (it lasts 15 s) or was issued to "
                                "another client; POST /api/v1/lease without it to get a new one");
      }
      if (!takeover.previous_keys.empty()) {
        broadcast_status(fg::status(fg::StatusLevel::kWarning,
                                    "the operator lease was taken over by " + who.label +
                                        "; your commands are refused until you take it back",
                                    "lease"),
                         takeover.previous_keys);
      }
      broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                  who.label + " took over the operator lease from " + held.holder_label,
                                  "lease"));
      return ApiResult::success(lease_description(who, now, takeover.grant.lease_token));
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

void HttpServer::Impl::connection_closed(const Identity& who) {
  const auto now = SteadyClock::now();
  // The holder's console went away: the robot holds now, and a reconnect must command afresh.
  if (lease.holds(who.lease_key, now)) api.operator_lost();
  // A lease bound to this connection has no one left who could use it: free it at once rather than
  // leave it to a dead connection until it lapses.
  if (who.connection_bound && lease.release_bound_to(who.lease_key, now)) {
    broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                who.label + " closed its connection; the operator lease is free", "lease"));
  }
}

ApiResult HttpServer::Impl::set_parameters(const json& parameters, const Identity& who) {
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators set parameters");
  }
  const auto now = SteadyClock::now();
  if (!lease.use(who.lease_key, now)) return lease_refusal(who, now, "setting parameters needs the lease");
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
