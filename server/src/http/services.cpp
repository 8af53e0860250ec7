// The Foxglove services that mirror the REST commands, with their JSON schemas: the core ones, then one
// per command the robot types add (a command several robots share is one service; "robot" picks).
#include <set>

#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;

namespace {

json service_schema(const json& properties, const std::vector<std::string>& required) {
  return {{"type", "object"}, {"properties", properties}, {"required", required}};
}

}  // namespace

const std::map<std::string, Command>& core_robot_commands() {
  static const std::map<std::string, Command> commands = {{"state_command", Command::kStateCommand},
                                                          {"mode", Command::kMode},
                                                          {"move_jp", Command::kMoveJp},
                                                          {"servo_jv", Command::kServoJv},
                                                          {"move_cp", Command::kMoveCp},
                                                          {"servo_cp", Command::kServoCp},
                                                          {"servo_cv", Command::kServoCv}};
  return commands;
}

std::vector<ServiceDef> service_definitions(const ControlApi& api) {
  const json robot = {{"type", "string"}};
  const json numbers = {{"type", "array"}, {"items", {{"type", "number"}}}};
  const json point = {{"type", "array"}, {"items", {{"type", "number"}}}, {"minItems", 3}, {"maxItems", 3}};
  const json quaternion = {
      {"type", "array"}, {"items", {{"type", "number"}}}, {"minItems", 4}, {"maxItems", 4}};
  std::vector<ServiceDef> defs = {
      {1, "state_command", CommandRef(Command::kStateCommand), true,
       service_schema({{"robot", robot}, {"command", {{"type", "string"}}}}, {"robot", "command"})},
      {2, "mode", CommandRef(Command::kMode), true,
       service_schema({{"robot", robot}, {"mode", {{"type", "string"}}}}, {"robot", "mode"})},
      {3, "move_jp", CommandRef(Command::kMoveJp), true,
       service_schema({{"robot", robot}, {"goal", numbers}}, {"robot", "goal"})},
      {4, "servo_jv", CommandRef(Command::kServoJv), true,
       service_schema({{"robot", robot}, {"velocity", numbers}}, {"robot", "velocity"})},
      {5, "estop", CommandRef(Command::kEstop), false, service_schema(json::object(), {})},
      {6, "estop_reset", CommandRef(Command::kEstopReset), false, service_schema(json::object(), {})},
      {7, "lease", std::nullopt, false,
       service_schema({{"action", {{"type", "string"}, {"enum", {"acquire", "release", "status"}}}},
                       {"robot", robot},
                       {"takeover_token", {{"type", "string"}}}},
                      {})},
      {8, "move_cp", CommandRef(Command::kMoveCp), true,
       service_schema({{"robot", robot}, {"position", point}, {"orientation", quaternion}},
                      {"robot", "position", "orientation"})},
      {9, "servo_cp", CommandRef(Command::kServoCp), true,
       service_schema({{"robot", robot}, {"position", point}, {"orientation", quaternion}},
                      {"robot", "position", "orientation"})},
      {10, "servo_cv", CommandRef(Command::kServoCv), true,
       service_schema({{"robot", robot}, {"linear", point}, {"angular", point}},
                      {"robot", "linear", "angular"})},
  };
  // The robot types' own commands, once per name.
  std::set<std::string> seen;
  for (const auto& d : defs) seen.insert(d.name);
  std::uint32_t next_id = 100;
  try {
    for (const auto& r : api.robots()) {
      const std::string name = r.value("name", std::string());
      for (const auto& c : api.robot_commands(name)) {
        if (!seen.insert(c.name).second) continue;
        json schema = c.body_schema.is_object() ? c.body_schema : service_schema(json::object(), {});
        schema["properties"]["robot"] = robot;
        auto required = schema.value("required", json::array());
        required.push_back("robot");
        schema["required"] = required;
        defs.push_back({next_id++, c.name, CommandRef(Command::kRobotCommand, c.name), true, schema});
      }
    }
  } catch (const std::exception&) {
    // The robots could not be listed now: the core services remain; GET /robots shows the failure.
  }
  return defs;
}

std::vector<fg::Service> service_list(const std::vector<ServiceDef>& definitions) {
  const json response = {
      {"type", "object"},
      {"properties",
       {{"status", {{"type", "integer"}}},
        {"body", json::object()},
        {"error",
         {{"type", "object"},
          {"properties", {{"code", {{"type", "string"}}}, {"message", {{"type", "string"}}}}}}}}}};
  std::vector<fg::Service> services;
  services.reserve(definitions.size());
  for (const auto& def : definitions)
    services.push_back({def.id, def.name, "tendril/" + def.name, dump(def.request_schema), dump(response)});
  return services;
}

}  // namespace tendril::server
