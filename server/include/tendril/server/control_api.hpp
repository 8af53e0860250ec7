// ControlApi: the JSON face of the robots that the HTTP/WebSocket front end talks to. Thread-safe;
// called from the network threads. Implemented by JsonControlApi (http/control_json.hpp) over the
// typed RobotService and the robot types' API extensions; tests of the front end use a double.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/server/topic_source.hpp"

namespace tendril::server {

// The API's error shape: {"error":{"code":..., "message":...}} with an HTTP status.
struct ApiResult {
  int status = 200;     // 200, 202, 400, 404, 409, 422, ...
  std::string code;     // snake_case error code; empty on success
  std::string message;  // for a person; empty on success
  nlohmann::json body;  // success body (ignored on error)
  // Extra members of the error object next to code and message (e.g. the lease "holder" and
  // "takeover_token"); null when there are none.
  nlohmann::json error_details;

  bool ok() const noexcept { return status < 400; }
  static ApiResult success(nlohmann::json body, int status = 200) {
    return {status, {}, {}, std::move(body), nullptr};
  }
  static ApiResult error(int status, std::string code, std::string message) {
    return {status, std::move(code), std::move(message), nullptr, nullptr};
  }
  nlohmann::json error_json() const {
    nlohmann::json error = {{"code", code}, {"message", message}};
    if (error_details.is_object()) {
      for (const auto& [key, value] : error_details.items()) {
        if (key != "code" && key != "message") error[key] = value;
      }
    }
    return {{"error", std::move(error)}};
  }
};

// A robot type's own command, as the front end offers it.
struct RobotCommandInfo {
  std::string name;            // POST /api/v1/robots/{robot}/<name>; Foxglove service "<name>"
  nlohmann::json body_schema;  // JSON Schema of the body (the service's request, with "robot" added)
  bool streamable = false;     // also a client channel "/{robot}/<name>" (clientPublish)
  // The body field that says a stream moves the robot (e.g. a held "deadman"); a live stream with it
  // true cannot be taken over. Empty: the command does not stream motion.
  std::string motion_flag;
  std::string description;
};

class ControlApi {
 public:
  virtual ~ControlApi() = default;

  // GET /robots: [{"name","kind","joints":[{"name","unit","lower","upper","max_velocity"}],"modes":[...]}]
  virtual nlohmann::json robots() const = 0;
  virtual bool has_robot(const std::string& robot) const = 0;
  // GET endpoints; 404 for an unknown robot.
  virtual ApiResult measured_js(const std::string& robot) const = 0;
  virtual ApiResult setpoint_js(const std::string& robot) const = 0;
  virtual ApiResult measured_cp(const std::string& robot) const = 0;
  // Cartesian velocity and force (CRTK measured_cv, measured_cf) for robot types that measure them.
  virtual ApiResult measured_cv(const std::string& robot) const {
    return not_supported(robot, "measured_cv");
  }
  virtual ApiResult measured_cf(const std::string& robot) const {
    return not_supported(robot, "measured_cf");
  }
  // The robot file's JSON Schema (core keys and the robot type's own sections).
  virtual ApiResult robot_schema(const std::string& robot) const { return not_supported(robot, "schema"); }
  virtual ApiResult shape(const std::string& robot) const = 0;
  virtual ApiResult operating_state(const std::string& robot) const = 0;

  // Commands. The caller has already checked the token, the role and the lease.
  // `body` is the parsed JSON request body; the implementation checks shape, sizes, finiteness
  // and limits and answers 400/422/409 with the API's snake_case error codes.
  virtual ApiResult state_command(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult mode(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult move_jp(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult servo_jv(const std::string& robot, const nlohmann::json& body) = 0;
  // Cartesian commands (CRTK move_cp, servo_cp, servo_cv) for robot types that take them.
  virtual ApiResult move_cp(const std::string& robot, const nlohmann::json& body) {
    (void)body;
    return not_supported(robot, "move_cp");
  }
  virtual ApiResult servo_cp(const std::string& robot, const nlohmann::json& body) {
    (void)body;
    return not_supported(robot, "servo_cp");
  }
  virtual ApiResult servo_cv(const std::string& robot, const nlohmann::json& body) {
    (void)body;
    return not_supported(robot, "servo_cv");
  }
  // The robot type's own commands (REST POST /robots/{robot}/<name>, Foxglove service <name>, client
  // channel /{robot}/<name> when streamable).
  virtual std::vector<RobotCommandInfo> robot_commands(const std::string& robot) const {
    (void)robot;
    return {};
  }
  virtual ApiResult robot_command(const std::string& robot, const std::string& name,
                                  const nlohmann::json& body) {
    (void)body;
    return ApiResult::error(404, "not_found", "robot '" + robot + "' has no command '" + name + "'");
  }
  virtual ApiResult estop() = 0;
  // The e-stop pressed by `actor` (the session or client and its role, e.g. "session:3 (operator)"):
  // the safety event names them. Implementations without an event log just stop.
  virtual ApiResult estop_from(const std::string& actor) {
    (void)actor;
    return estop();
  }
  virtual ApiResult estop_reset() = 0;

  // GET /faults: recent faults and safety events, newest first.
  virtual nlohmann::json faults(std::size_t max_events = 200) const = 0;
  // Prometheus text for the control side (loop, bus, drives); the front end appends its own.
  virtual std::string metrics() const = 0;

  // Streams for the WebSocket: one JSON message per topic, built from the latest state snapshot.
  // Topics: "/{robot}/joint_states", "/{robot}/operating_state", "/safety/events", "/{robot}/scene".
  virtual std::vector<std::string> topics() const = 0;
  // The schema of a topic when it is not one of the front end's known ones (a robot type's own).
  virtual std::optional<TopicInfo> topic_schema(const std::string& topic) const {
    (void)topic;
    return std::nullopt;
  }
  // The message for `topic` if it changed since `since_version`; sets `version`.
  virtual std::optional<nlohmann::json> topic_message(const std::string& topic, std::uint64_t since_version,
                                                      std::uint64_t& version) const = 0;
  // Called when the connection of the holder of `robot`'s lease goes away while it was streaming servo
  // commands: that robot holds (servo stops at once rather than waiting for the command timeout).
  virtual void operator_lost(const std::string& robot) = 0;

  // Path following (runtime mode "path_following"): a plan is loaded, then played back one insertion
  // step at a time with joint-space moves. `plan` = {"steps":[{"q":[…], "backbone":[[x,y,z],…]?},…],
  // "vessel_path":[[x,y,z],…]?}; every step is checked against the joint limits (422 names the step).
  // `plan_id` names the plan job it came from (empty for an inline plan). 409 while moving.
  virtual ApiResult load_path(const std::string& robot, const nlohmann::json& plan,
                              const std::string& plan_id) {
    (void)plan;
    (void)plan_id;
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no path following");
  }
  // {"step": k} or {"advance": 1 | -1}: moves to that step (202 {"step","duration_s"}); needs the
  // robot enabled, holding and in path_following mode.
  virtual ApiResult path_step(const std::string& robot, const nlohmann::json& body) {
    (void)body;
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no path following");
  }
  // {"loaded","steps","step","target","moving","mode","plan"}.
  virtual ApiResult path_following(const std::string& robot) const {
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' has no path following");
  }

  // Run-time parameters (Foxglove "parameters" capability), e.g. "/srmc/insertion/upper",
  // "/srmc/insertion/max_velocity", "/srmc/servo_timeout_s": [{"name","value","type"}], every one
  // readable. Writable ones may only be set within the configured (safe) range: tightening, or going
  // back to the configured value, never beyond it.
  virtual nlohmann::json parameters() const { return nlohmann::json::array(); }
  // `parameters` = [{"name","value"}] (value null/absent = back to the configured value). All or
  // nothing: 404 unknown_parameter, 403 read_only_parameter, 400 bad_parameter, 422 out_of_range,
  // 409 not_holding. Success body: the new values of the parameters set, as parameters() lists them.
  // The caller has already checked the role and the lease.
  virtual ApiResult set_parameters(const nlohmann::json& parameters) {
    (void)parameters;
    return ApiResult::error(501, "not_implemented", "this server has no writable parameters");
  }

 protected:
  static ApiResult not_supported(const std::string& robot, const std::string& what) {
    return ApiResult::error(422, "not_supported", "robot '" + robot + "' does not support " + what);
  }
};

}  // namespace tendril::server
