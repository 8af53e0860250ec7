// ControlApi: what the HTTP/WebSocket front end may ask of the robots. Thread-safe; called from
// the network threads. Implemented by RobotRuntime, which validates every command against the
// immutable robot model and hands it to the real-time thread through a lock-free mailbox.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace tendril::server {

// Mirrors the API.md error shape: {"error":{"code":..., "message":...}} with an HTTP status.
struct ApiResult {
  int status = 200;     // 200, 202, 400, 404, 409, 422, ...
  std::string code;     // snake_case error code; empty on success
  std::string message;  // for a person; empty on success
  nlohmann::json body;  // success body (ignored on error)

  bool ok() const noexcept { return status < 400; }
  static ApiResult success(nlohmann::json body, int status = 200) {
    return {status, {}, {}, std::move(body)};
  }
  static ApiResult error(int status, std::string code, std::string message) {
    return {status, std::move(code), std::move(message), nullptr};
  }
  nlohmann::json error_json() const { return {{"error", {{"code", code}, {"message", message}}}}; }
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
  virtual ApiResult shape(const std::string& robot) const = 0;
  virtual ApiResult operating_state(const std::string& robot) const = 0;

  // Commands. The caller has already checked the token, the role and the lease.
  // `body` is the parsed JSON request body; the implementation checks shape, sizes, finiteness
  // and limits and answers 400/422/409 with API.md error codes.
  virtual ApiResult state_command(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult mode(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult move_jp(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult servo_jv(const std::string& robot, const nlohmann::json& body) = 0;
  virtual ApiResult estop() = 0;
  virtual ApiResult estop_reset() = 0;

  // GET /faults: recent faults and safety events, newest first.
  virtual nlohmann::json faults(std::size_t max_events = 200) const = 0;
  // Prometheus text for the control side (loop, bus, drives); the front end appends its own.
  virtual std::string metrics() const = 0;

  // Streams for the WebSocket: one JSON message per topic, built from the latest state snapshot.
  // Topics: "/{robot}/joint_states", "/{robot}/operating_state", "/safety/events", "/{robot}/scene".
  virtual std::vector<std::string> topics() const = 0;
  // The message for `topic` if it changed since `since_version`; sets `version`.
  virtual std::optional<nlohmann::json> topic_message(const std::string& topic, std::uint64_t since_version,
                                                      std::uint64_t& version) const = 0;
  // Called when the lease holder's connection goes away while it was streaming servo commands:
  // the robot holds (servo stops at once rather than waiting for the command timeout).
  virtual void operator_lost() = 0;
};

}  // namespace tendril::server
