// DdsBridge: tendrild's DDS participant (Cyclone DDS C API). It publishes every robot's joint states,
// operating state, tip pose and backbone shape, the safety events and the maps it is given, and takes
// servo_jv, move_jp and state_command
// samples as commands. dds/README.md lists the topics, types and QoS.
//
// Threads: one publisher thread reads the runtime's snapshots (the RobotService read-outs the
// WebSocket's messages are made from) at publish_rate_hz; one command thread waits on the command
// readers. Neither is the control thread, and neither waits for it: a command goes through the same
// lock-free mailbox as a REST command.
//
// Commands go through the same path as REST (the CommandGate, in tendrild HttpServer::command): the
// lease token in the sample, the robot, the sizes, finiteness and limits, then the safety
// supervisor in the control loop. A sample that fails is refused, answered on
// rt/<robot>/command_result with the status and code its REST twin would get, and counted by
// status in tendril_dds_commands_total. A writer that sends more than command_rate_hz (burst
// command_burst) is refused with 429 rate_limited before anything else is checked, like a WebSocket
// client over its rate; samples a flood overwrote in the reader's history before the bridge took them
// are counted from the gaps in the writer's request_id (tendril_dds_commands_lost_total).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"
#include "tendril/server/robot_service.hpp"

namespace tendril::dds {

// A static map published once on rt/maps/<name> as sensor_msgs/PointCloud2 (x, y, z float32, metres).
struct PointMap {
  std::string name;      // the topic leaf: "vessel" -> rt/maps/vessel
  std::string frame_id;  // e.g. "world"
  std::vector<Eigen::Vector3f> points_mm;
};

struct DdsOptions {
  std::uint32_t domain = 0;     // DDS domain id (0-232; ROS 2's ROS_DOMAIN_ID means the same)
  double publish_rate_hz = 50;  // state topics and safety events; > 0
  // Per writer (DDS publication): a token bucket, at the WebSocket's client rate (ws_client_rate_hz)
  // but a smaller burst: a DDS writer outruns the bridge at once, and the reader keeps only the newest
  // 64 samples, so a burst of 400 would never be reached by a flood, only by a stream of stale ones.
  double command_rate_hz = 200;
  double command_burst = 50;
  std::vector<PointMap> maps;  // written at start(), transient-local: late subscribers get them too
  std::function<void(const std::string&)> log;  // set-up and contained errors; null = standard error
};

// Set-up failure (bad domain, Cyclone DDS could not create an entity); the message says which.
class DdsError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The server's command path: (robot, command, REST body, lease token, client label) -> the answer.
using CommandGate = std::function<server::ApiResult(
    const std::string& robot, const std::string& command, const nlohmann::json& body,
    const std::string& lease_token, const std::string& client)>;

class DdsBridge {
 public:
  // Creates the participant, topics, writers and readers for every robot of `robots`. Throws DdsError.
  DdsBridge(const server::RobotService& robots, CommandGate gate, DdsOptions options);
  ~DdsBridge();
  DdsBridge(const DdsBridge&) = delete;
  DdsBridge& operator=(const DdsBridge&) = delete;

  void start();  // the publisher and command threads
  void stop();   // joins them; safe to call twice. The destructor also deletes the participant.

  // One publisher pass (what the publisher thread does at each tick); for tests that step time.
  void publish_once();
  // Prometheus text: samples published per topic kind, commands by status, refused by reason.
  std::string metrics() const;
  std::uint32_t domain() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::dds
