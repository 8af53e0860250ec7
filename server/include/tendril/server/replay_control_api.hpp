// ReplayControlApi: the ControlApi of a server that replays a recording (tendrild --replay). It
// describes the configured robots as the live server does (GET /robots, their schemas, commands and
// parameters, read from a RobotRuntime that is built but never started: no bus is opened for traffic,
// no drive is configured, no thread runs), and drives none of them: every command answers 409
// replay_mode (the front end refuses them before the lease, this is the second line), the state getters
// answer 409 replay_mode pointing at the replayed topics, and it publishes no topic of its own (the
// SessionReplay source publishes the recorded ones).
#pragma once

#include "tendril/server/control_api.hpp"

namespace tendril::server {

class ReplayControlApi final : public ControlApi {
 public:
  // `description` answers the read-only questions about the robots; it must outlive this.
  explicit ReplayControlApi(const ControlApi& description) : description_(description) {}

  nlohmann::json robots() const override { return description_.robots(); }
  bool has_robot(const std::string& robot) const override { return description_.has_robot(robot); }
  ApiResult robot_schema(const std::string& robot) const override { return description_.robot_schema(robot); }
  std::vector<RobotCommandInfo> robot_commands(const std::string& robot) const override {
    return description_.robot_commands(robot);
  }
  nlohmann::json parameters() const override { return description_.parameters(); }

  ApiResult measured_js(const std::string& robot) const override { return state(robot); }
  ApiResult setpoint_js(const std::string& robot) const override { return state(robot); }
  ApiResult measured_cp(const std::string& robot) const override { return state(robot); }
  ApiResult measured_cv(const std::string& robot) const override { return state(robot); }
  ApiResult measured_cf(const std::string& robot) const override { return state(robot); }
  ApiResult shape(const std::string& robot) const override { return state(robot); }
  ApiResult operating_state(const std::string& robot) const override { return state(robot); }
  ApiResult path_following(const std::string& robot) const override { return state(robot); }

  ApiResult state_command(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult mode(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult move_jp(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult servo_jv(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult move_cp(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult servo_cp(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult servo_cv(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult robot_command(const std::string&, const std::string&, const nlohmann::json&) override {
    return refused();
  }
  ApiResult estop() override { return refused(); }
  ApiResult estop_reset() override { return refused(); }
  ApiResult load_path(const std::string&, const nlohmann::json&, const std::string&) override {
    return refused();
  }
  ApiResult path_step(const std::string&, const nlohmann::json&) override { return refused(); }
  ApiResult set_parameters(const nlohmann::json&) override { return refused(); }

  // The recorded safety events are on the replayed /safety/events topic; this server has none.
  nlohmann::json faults(std::size_t) const override { return nlohmann::json::array(); }
  std::string metrics() const override {
    return "# HELP tendril_replay_mode 1: this server replays a recording and drives no robot.\n"
           "# TYPE tendril_replay_mode gauge\ntendril_replay_mode 1\n";
  }
  std::vector<std::string> topics() const override { return {}; }
  std::optional<nlohmann::json> topic_message(const std::string&, std::uint64_t,
                                              std::uint64_t&) const override {
    return std::nullopt;
  }
  void operator_lost(const std::string&) override {}

  static ApiResult refused() {
    return ApiResult::error(
        409, "replay_mode",
        "this server is replaying a recording (tendrild --replay): it drives no robot, so "
        "it takes no commands");
  }

 private:
  ApiResult state(const std::string& robot) const {
    if (!description_.has_robot(robot)) {
      return ApiResult::error(404, "unknown_robot", "no robot '" + robot + "' on this server");
    }
    return ApiResult::error(409, "replay_mode",
                            "this server is replaying a recording: robot '" + robot +
                                "' is not running; its recorded state is on the replayed topics (/" + robot +
                                "/joint_states, /" + robot + "/operating_state, …)");
  }

  const ControlApi& description_;
};

}  // namespace tendril::server
