// The Foxglove services that mirror the REST commands, with their JSON schemas.
#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;

namespace {

json service_schema(const json& properties, const std::vector<std::string>& required) {
  return {{"type", "object"}, {"properties", properties}, {"required", required}};
}

}  // namespace

const std::vector<ServiceDef>& service_definitions() {
  static const std::vector<ServiceDef> services = {
      {1, "state_command", Command::kStateCommand, true},
      {2, "mode", Command::kMode, true},
      {3, "move_jp", Command::kMoveJp, true},
      {4, "servo_jv", Command::kServoJv, true},
      {5, "estop", Command::kEstop, false},
      {6, "estop_reset", Command::kEstopReset, false},
      {7, "lease", std::nullopt, false},
      {8, "move_configuration", Command::kMoveConfiguration, true},
      {9, "joystick", Command::kJoystick, true},
  };
  return services;
}

std::vector<fg::Service> service_list() {
  const json robot = {{"type", "string"}};
  const json numbers = {{"type", "array"}, {"items", {{"type", "number"}}}};
  const json response = {
      {"type", "object"},
      {"properties",
       {{"status", {{"type", "integer"}}},
        {"body", json::object()},
        {"error",
         {{"type", "object"},
          {"properties", {{"code", {{"type", "string"}}}, {"message", {{"type", "string"}}}}}}}}}};
  std::vector<fg::Service> services;
  for (const auto& def : service_definitions()) {
    json request;
    const std::string name = def.name;
    if (name == "state_command") {
      request = service_schema({{"robot", robot}, {"command", {{"type", "string"}}}}, {"robot", "command"});
    } else if (name == "mode") {
      request = service_schema({{"robot", robot}, {"mode", {{"type", "string"}}}}, {"robot", "mode"});
    } else if (name == "move_jp") {
      request = service_schema({{"robot", robot}, {"goal", numbers}}, {"robot", "goal"});
    } else if (name == "servo_jv") {
      request = service_schema({{"robot", robot}, {"velocity", numbers}}, {"robot", "velocity"});
    } else if (name == "move_configuration") {
      request = service_schema({{"robot", robot},
                                {"goal",
                                 {{"type", "object"},
                                  {"properties",
                                   {{"insertion", {{"type", "number"}}},
                                    {"roll", {{"type", "number"}}},
                                    {"theta_proximal", {{"type", "number"}}},
                                    {"theta_distal", {{"type", "number"}}}}}}}},
                               {"robot", "goal"});
    } else if (name == "joystick") {
      request = service_schema({{"robot", robot}, {"axes", numbers}, {"deadman", {{"type", "boolean"}}}},
                               {"robot", "axes", "deadman"});
    } else if (name == "lease") {
      request =
          service_schema({{"action", {{"type", "string"}, {"enum", {"acquire", "release", "status"}}}}}, {});
    } else {
      request = service_schema(json::object(), {});
    }
    services.push_back({def.id, name, "tendril/" + name, dump(request), dump(response)});
  }
  return services;
}

}  // namespace tendril::server
