// Server and robot configuration: JSON files validated at start-up. Every error names the file,
// the key and what was expected, because a lab engineer editing JSON by hand reads it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/safety/limit_set.hpp"

namespace tendril::server {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A CiA 402 drive on a CANopen bus.
struct DriveConfig {
  std::string bus;
  int node_id = 0;
  double counts_per_unit = 1000.0;
  std::int32_t offset_counts = 0;
};

struct JointConfig {
  // Name, unit and every limit: the one joint-limit type, owned by safety (LimitSet checks it).
  safety::JointLimit limit;
  double initial_position = 0.0;  // where the simulated load starts
  // The simulated drive used when the joint's bus is virtual: a preset of the robot type (e.g. the
  // catheter's lead screws) or "generic".
  std::string simulation_preset = "generic";
  // The drive; absent when the robot type provides the joint itself (an arm controller, a simulator
  // at the joint interface).
  std::optional<DriveConfig> drive;
  const std::string& name() const noexcept { return limit.name; }
  const std::string& unit() const noexcept { return limit.unit; }
};

struct BusConfig {
  std::string name;
  std::string interface;  // "virtual" (simulated drives) or a SocketCAN interface such as "can0"
  std::uint32_t bitrate = 1'000'000;
  int sync_period_us = 1000;
  double max_load = 0.7;
  int heartbeat_period_ms = 20;
  int drive_heartbeat_timeout_ms = 100;
  int drive_heartbeat_period_ms = 20;
  int master_heartbeat_timeout_ms = 100;
  bool operator==(const BusConfig&) const = default;
};

struct RobotConfig {
  std::filesystem::path file;
  std::string name;
  std::string kind;
  std::string description;
  std::optional<double> control_rate_hz;  // must equal the server's when given
  int command_timeout_ms = 150;
  // Lost control time tolerated while the robot moves (ms); 0 = derived, see
  // safety::lost_control_bound (half the shorter of command_timeout_ms and the drives' heartbeat
  // consumer time master_heartbeat_timeout_ms). A set value may only be tighter.
  int max_lost_control_ms = 0;
  int enable_timeout_ms = 1000;
  std::vector<JointConfig> joints;
  std::vector<BusConfig> buses;
  // The robot type's own sections (every top-level key the core does not read), checked against the
  // type's schema and read by the type.
  nlohmann::json settings = nlohmann::json::object();
  nlohmann::json document;  // the whole file, for the check against the type's merged schema
  std::filesystem::path directory() const { return file.parent_path(); }
};

struct ServerConfig {
  std::filesystem::path file;
  std::string host = "127.0.0.1";
  unsigned short port = 8080;
  std::string token;  // empty: generated at start-up
  std::vector<std::string> allowed_origins;
  std::filesystem::path web_root;
  std::filesystem::path vendor_root;   // node_modules, for three.js
  std::filesystem::path openapi_file;  // served at GET /api/v1/openapi.json
  // HTTPS/WSS on the same port when both are set ("tls": {"certificate", "private_key"}, PEM files).
  std::filesystem::path tls_certificate, tls_private_key;
  double control_rate_hz = 1000.0;
  double publish_rate_hz = 50.0;
  bool realtime_priority = true;  // ask for SCHED_FIFO + mlockall; runs without if refused
  std::vector<std::filesystem::path> robot_files;
  std::vector<RobotConfig> robots;
  nlohmann::json imaging;    // the "imaging" object (null if absent); read by parse_imaging_config
  nlohmann::json scene;      // the "scene" object (null if absent); read by load_scene_vessel
  nlohmann::json recording;  // the "recording" object (null if absent); read by parse_recording_config
};

// Parses a robot file's core keys (the robot type's sections are kept in RobotConfig::settings and
// checked by the runtime against the type's schema). Throws ConfigError("config/robots/srmc.json:
// joints[2].upper: expected a number greater than lower (-6), got -8").
RobotConfig load_robot_config(const std::filesystem::path& file);
RobotConfig parse_robot_config(const nlohmann::json& j, const std::filesystem::path& file);
nlohmann::json read_json_file(const std::filesystem::path& file);

// Parses the server file and every robot file it names (relative to the server file's folder).
ServerConfig load_server_config(const std::filesystem::path& file);

}  // namespace tendril::server
