// The JSON face of a runtime, assembled as tendrild does it (JsonControlApi over the typed service and
// each robot type's API extension), for tests that drive the runtime through the API's own codec.
#pragma once

#include <memory>

#include "steerable_catheter/catheter_robot.hpp"
#include "tendril/server/http/control_json.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {

inline std::unique_ptr<JsonControlApi> json_api(RobotRuntime& runtime) {
  return std::make_unique<JsonControlApi>(
      runtime, [&runtime](const std::string& robot) { return runtime.api_extension(robot); });
}

// The steerable catheter robot `robot` of a runtime (its simulated ADC nodes, for tests).
inline SteerableCatheter& catheter(RobotRuntime& runtime, const std::string& robot = "srmc") {
  auto* plugin = dynamic_cast<SteerableCatheter*>(runtime.plugin(robot));
  if (!plugin) throw std::logic_error("robot '" + robot + "' is not a steerable catheter");
  return *plugin;
}

}  // namespace tendril::server
