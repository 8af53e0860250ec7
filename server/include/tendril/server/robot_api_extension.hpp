// RobotApiExtension: a robot type's part of the network API, at the edge (JSON in, JSON out, with the
// API's error shape). The JSON layer over RobotService (http/control_json.hpp) asks each robot's
// extension for the fields, commands, topics and routes its type adds; the core API knows none of them.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"

namespace tendril::server {

class RobotApiExtension {
 public:
  virtual ~RobotApiExtension() = default;
  // The type's own fields of GET /robots, of operating_state, and its scene entities.
  virtual void describe(nlohmann::json& robot) const { (void)robot; }
  virtual void state(nlohmann::json& operating_state) const { (void)operating_state; }
  virtual void scene(nlohmann::json& entities) const { (void)entities; }
  // The type's commands; command() gets the parsed JSON body (the caller checked role and lease).
  virtual std::vector<RobotCommandInfo> commands() const { return {}; }
  // A plan offered to path following (the request's JSON, or a plan job's result), before its steps are
  // checked: the type's refusal, or nullopt to go on (a catheter refuses a plan made for another design).
  virtual std::optional<ApiResult> refuse_plan(const nlohmann::json& plan) const {
    (void)plan;
    return std::nullopt;
  }
  virtual ApiResult command(const std::string& name, const nlohmann::json& body) {
    (void)body;
    return ApiResult::error(404, "not_found", "no command " + name);
  }
  // Fields of operating_state that change with every sensor reading, not only with the state (dotted
  // paths, e.g. "joystick.axes"): the /{robot}/operating_state topic leaves them out, so it changes
  // only when the state does, and the whole state goes out on /{robot}/<topic> at rate_hz instead.
  struct LiveState {
    std::string topic;        // leaf under /{robot}/, named by the plug-in
    std::string schema_name;  // the plug-in's own schema name (tendril.<Kind>State)
    double rate_hz = 10.0;
    std::vector<std::string> fields;
  };
  virtual std::optional<LiveState> live_state() const { return std::nullopt; }
};

}  // namespace tendril::server
