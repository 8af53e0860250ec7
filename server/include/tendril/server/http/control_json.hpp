// JsonControlApi: the JSON face of RobotService for the HTTP/WebSocket front end. Requests are parsed
// and checked for shape here and become typed calls; typed results and errors become the API's JSON
// bodies and status codes. Each robot type's RobotApiExtension adds its fields, commands and topics.
// The topics' messages (joint states, operating state, scene, diagnostics, safety events) are built
// here too, with change detection so the publisher sends only what changed.
#pragma once

#include <functional>
#include <map>
#include <mutex>
#include <string>

#include "tendril/server/control_api.hpp"
#include "tendril/server/robot_api_extension.hpp"
#include "tendril/server/robot_service.hpp"

namespace tendril::server {

// HTTP status for a typed error (400, 403, 404, 409, 422, 500, 503).
int http_status(ErrorKind kind) noexcept;
ApiResult to_api_result(const ServiceError& error);

class JsonControlApi final : public ControlApi {
 public:
  using ExtensionLookup = std::function<RobotApiExtension*(const std::string& robot)>;
  using SchemaLookup = std::function<std::optional<nlohmann::json>(const std::string& robot)>;
  JsonControlApi(RobotService& service, ExtensionLookup extensions, SchemaLookup schemas = {});

  nlohmann::json robots() const override;
  bool has_robot(const std::string& robot) const override;
  ApiResult measured_js(const std::string& robot) const override;
  ApiResult setpoint_js(const std::string& robot) const override;
  ApiResult measured_cp(const std::string& robot) const override;
  ApiResult measured_cv(const std::string& robot) const override;
  ApiResult measured_cf(const std::string& robot) const override;
  ApiResult robot_schema(const std::string& robot) const override;
  ApiResult shape(const std::string& robot) const override;
  ApiResult operating_state(const std::string& robot) const override;
  ApiResult state_command(const std::string& robot, const nlohmann::json& body) override;
  ApiResult mode(const std::string& robot, const nlohmann::json& body) override;
  ApiResult move_jp(const std::string& robot, const nlohmann::json& body) override;
  ApiResult servo_jv(const std::string& robot, const nlohmann::json& body) override;
  ApiResult move_cp(const std::string& robot, const nlohmann::json& body) override;
  ApiResult servo_cp(const std::string& robot, const nlohmann::json& body) override;
  ApiResult servo_cv(const std::string& robot, const nlohmann::json& body) override;
  std::vector<RobotCommandInfo> robot_commands(const std::string& robot) const override;
  ApiResult robot_command(const std::string& robot, const std::string& name,
                          const nlohmann::json& body) override;
  ApiResult estop() override;
  ApiResult estop_from(const std::string& actor) override;
  ApiResult estop_reset() override;
  nlohmann::json faults(std::size_t max_events = 200) const override;
  std::string metrics() const override;
  std::vector<std::string> topics() const override;
  std::optional<TopicInfo> topic_schema(const std::string& topic) const override;
  std::optional<nlohmann::json> topic_message(const std::string& topic, std::uint64_t since_version,
                                              std::uint64_t& version) const override;
  void operator_lost(const std::string& robot) override;
  ApiResult load_path(const std::string& robot, const nlohmann::json& plan,
                      const std::string& plan_id) override;
  ApiResult path_step(const std::string& robot, const nlohmann::json& body) override;
  ApiResult path_following(const std::string& robot) const override;
  nlohmann::json parameters() const override;
  ApiResult set_parameters(const nlohmann::json& parameters) override;

  // The operating_state JSON as GET /robots/{r}/operating_state answers it (for extensions' topics).
  nlohmann::json operating_state_json(const std::string& robot) const;

 private:
  RobotApiExtension* extension(const std::string& robot) const;
  // Change detection per topic: a new version when `key` differs from the last one.
  std::uint64_t topic_version(const std::string& topic, const std::string& key) const;
  // A scene topic's change key: changes when the scene differs visibly from the last one that changed it.
  std::string visible_scene_key(const std::string& topic, nlohmann::json scene) const;

  RobotService& service_;
  ExtensionLookup extensions_;
  SchemaLookup schemas_;
  mutable std::mutex topic_mutex_;
  mutable std::map<std::string, std::pair<std::string, std::uint64_t>> topic_cache_;
  mutable std::map<std::string, std::pair<nlohmann::json, std::uint64_t>> scene_reference_;
};

}  // namespace tendril::server
