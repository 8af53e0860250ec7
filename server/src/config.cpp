#include "tendril/server/config.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include "tendril/server/config_reader.hpp"
#include "tendril/server/config_schema.hpp"

namespace tendril::server {
namespace {

using detail::Reader;

}  // namespace

nlohmann::json read_json_file(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw ConfigError(file.string() + ": cannot open the file (does it exist and is it readable?)");
  std::stringstream buffer;
  buffer << in.rdbuf();
  try {
    return nlohmann::json::parse(buffer.str());
  } catch (const nlohmann::json::parse_error& e) {
    throw ConfigError(file.string() + ": not valid JSON: " + e.what());
  }
}

namespace {

bool is_identifier(const std::string& s) {
  if (s.empty() || s.size() > 64) return false;
  for (char c : s)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-')) return false;
  return true;
}

}  // namespace

RobotConfig parse_robot_config(const nlohmann::json& j, const std::filesystem::path& file) {
  // The core keys against the core schema; the robot type's own top-level sections are checked by the
  // runtime against the merged schema (config_schema.hpp).
  {
    nlohmann::json schema = core_robot_schema();
    schema.erase("additionalProperties");
    if (auto why = schema_violation(schema, j)) throw ConfigError(file.string() + ": " + *why);
  }
  Reader r(j, file.string(), "");
  RobotConfig rc;
  rc.file = file;
  rc.document = j;
  rc.name = r.string("name");
  if (!is_identifier(rc.name))
    r.fail("name", "letters, digits, '_' or '-' (it appears in URLs)", r.raw("name"));
  rc.kind = r.string("kind");
  rc.description = r.string_or("description", "");
  if (r.has("control_rate_hz")) rc.control_rate_hz = r.positive("control_rate_hz");
  rc.command_timeout_ms = static_cast<int>(r.integer_in_or("command_timeout_ms", 10, 10'000, 150));
  if (r.has("max_consecutive_overruns"))
    throw ConfigError(file.string() +
                      ": max_consecutive_overruns: no longer used; remove it. A robot now faults only when "
                      "the control loop loses more than max_lost_control_ms while it moves (README, "
                      "\"Control-loop timing\")");
  rc.max_lost_control_ms = static_cast<int>(r.integer_in_or("max_lost_control_ms", 1, 10'000, 0));
  rc.enable_timeout_ms = static_cast<int>(r.integer_in_or("enable_timeout_ms", 10, 60'000, 1000));

  std::set<std::string> bus_names;
  if (r.has("buses")) {
    const auto& buses = r.array("buses", false);
    for (std::size_t i = 0; i < buses.size(); ++i) {
      Reader b = r.element("buses", i);
      BusConfig bc;
      bc.name = b.string("name");
      if (!bus_names.insert(bc.name).second) b.fail("name", "a bus name not used before", b.raw("name"));
      bc.interface = b.string("interface");
      bc.bitrate = static_cast<std::uint32_t>(b.integer_in_or("bitrate", 10'000, 1'000'000, 1'000'000));
      bc.sync_period_us = static_cast<int>(b.integer_in_or("sync_period_us", 250, 100'000, 1000));
      bc.max_load = b.number_or("max_load", 0.7);
      if (!(bc.max_load > 0 && bc.max_load <= 1))
        b.fail("max_load", "a fraction in (0, 1]", b.raw("max_load"));
      bc.heartbeat_period_ms = static_cast<int>(b.integer_in_or("heartbeat_period_ms", 1, 10'000, 20));
      bc.drive_heartbeat_period_ms =
          static_cast<int>(b.integer_in_or("drive_heartbeat_period_ms", 1, 10'000, 20));
      bc.drive_heartbeat_timeout_ms = static_cast<int>(
          b.integer_in_or("drive_heartbeat_timeout_ms", 2, 60'000, 5L * bc.drive_heartbeat_period_ms));
      bc.master_heartbeat_timeout_ms = static_cast<int>(
          b.integer_in_or("master_heartbeat_timeout_ms", 2, 60'000, 5L * bc.heartbeat_period_ms));
      if (bc.drive_heartbeat_timeout_ms <= bc.drive_heartbeat_period_ms)
        b.fail("drive_heartbeat_timeout_ms",
               "more than drive_heartbeat_period_ms (" + std::to_string(bc.drive_heartbeat_period_ms) + ")",
               bc.drive_heartbeat_timeout_ms);
      if (bc.master_heartbeat_timeout_ms <= bc.heartbeat_period_ms)
        b.fail("master_heartbeat_timeout_ms",
               "more than heartbeat_period_ms (" + std::to_string(bc.heartbeat_period_ms) + ")",
               bc.master_heartbeat_timeout_ms);
      rc.buses.push_back(bc);
    }
  }

  const auto& joints = r.array("joints", true);
  std::set<std::string> joint_names;
  std::set<std::pair<std::string, int>> node_ids;
  std::vector<safety::JointLimit> limits;
  for (std::size_t i = 0; i < joints.size(); ++i) {
    Reader jr = r.element("joints", i);
    JointConfig jc;
    auto& limit = jc.limit;
    limit.name = jr.string("name");
    if (!joint_names.insert(limit.name).second)
      jr.fail("name", "a joint name not used before", jr.raw("name"));
    limit.unit = jr.string("unit");
    limit.lower = jr.number("lower");
    limit.upper = jr.number("upper");
    if (!(limit.upper > limit.lower))
      jr.fail("upper", "a number greater than lower (" + nlohmann::json(limit.lower).dump() + ")",
              jr.raw("upper"));
    limit.soft_margin = jr.non_negative_or("soft_margin", 0.0);
    if (2 * limit.soft_margin >= limit.upper - limit.lower)
      jr.fail("soft_margin", "less than half the range upper - lower", jr.raw("soft_margin"));
    limit.max_velocity = jr.positive("max_velocity");
    limit.max_acceleration = jr.positive("max_acceleration");
    limit.max_tracking_error = jr.positive_or("max_tracking_error", (limit.upper - limit.lower) / 10.0);
    jc.initial_position = jr.number_or("initial_position", std::clamp(0.0, limit.lower, limit.upper));
    if (jc.initial_position < limit.lower || jc.initial_position > limit.upper)
      jr.fail("initial_position", "a position within [lower, upper]", jr.raw("initial_position"));
    if (jr.has("simulation")) jc.simulation_preset = jr.child("simulation").string("preset");
    if (jr.has("drive")) {
      Reader d = jr.child("drive");
      DriveConfig drive;
      drive.bus = d.string("bus");
      if (!bus_names.count(drive.bus))
        d.fail("bus", "the name of a bus listed under \"buses\"", d.raw("bus"));
      drive.node_id = static_cast<int>(d.integer_in("node_id", 1, 126));
      if (!node_ids.insert({drive.bus, drive.node_id}).second)
        d.fail("node_id", "a node id not used by another joint on bus " + drive.bus, d.raw("node_id"));
      drive.counts_per_unit = d.positive("counts_per_unit");
      drive.offset_counts =
          static_cast<std::int32_t>(d.integer_in_or("offset_counts", -(1L << 30), 1L << 30, 0));
      // Positions must fit the 32-bit CiA 402 target with room to spare.
      const double max_counts =
          std::max(std::abs(limit.lower), std::abs(limit.upper)) * drive.counts_per_unit;
      if (max_counts > 2.0e9)
        d.fail("counts_per_unit", "a resolution whose limits fit in 32-bit counts", d.raw("counts_per_unit"));
      jc.drive = drive;
    }
    limits.push_back(limit);
    rc.joints.push_back(std::move(jc));
  }
  const bool some_drives =
      std::any_of(rc.joints.begin(), rc.joints.end(), [](const auto& jc) { return jc.drive; });
  const bool all_drives =
      std::all_of(rc.joints.begin(), rc.joints.end(), [](const auto& jc) { return jc.drive; });
  if (some_drives && !all_drives)
    r.fail("joints", "a drive for every joint or for none (then the robot type provides the joints)",
           nullptr);
  // The one limit validator: the safety library's.
  try {
    safety::LimitSet check(limits);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file.string() + ": joints: " + e.what());
  }
  static const std::set<std::string> core_keys = {"name",
                                                  "kind",
                                                  "description",
                                                  "control_rate_hz",
                                                  "command_timeout_ms",
                                                  "max_lost_control_ms",
                                                  "enable_timeout_ms",
                                                  "joints",
                                                  "buses"};
  for (const auto& [key, value] : j.items())
    if (!core_keys.count(key)) rc.settings[key] = value;
  return rc;
}

RobotConfig load_robot_config(const std::filesystem::path& file) {
  return parse_robot_config(read_json_file(file), file);
}

ServerConfig load_server_config(const std::filesystem::path& file) {
  const auto j = read_json_file(file);
  if (auto why = schema_violation(server_file_schema(), j)) throw ConfigError(file.string() + ": " + *why);
  Reader r(j, file.string(), "");
  ServerConfig sc;
  sc.file = file;
  const auto dir = file.parent_path();
  auto resolve = [&](const std::string& p) {
    std::filesystem::path path(p);
    return path.is_absolute() ? path : (dir / path).lexically_normal();
  };
  if (r.has("listen")) {
    const std::string listen = r.string("listen");
    auto colon = listen.rfind(':');
    if (colon == std::string::npos || colon == 0)
      r.fail("listen", "HOST:PORT, e.g. 127.0.0.1:8080", r.raw("listen"));
    sc.host = listen.substr(0, colon);
    try {
      int port = std::stoi(listen.substr(colon + 1));
      if (port < 0 || port > 65535) throw std::out_of_range("port");
      sc.port = static_cast<unsigned short>(port);
    } catch (const std::exception&) {
      r.fail("listen", "HOST:PORT with a port from 0 to 65535", r.raw("listen"));
    }
  }
  sc.token = r.has("token") ? r.string("token") : "";
  if (r.has("allowed_origins")) {
    const auto& origins = r.array("allowed_origins", false);
    for (std::size_t i = 0; i < origins.size(); ++i) {
      if (!origins[i].is_string())
        r.fail("allowed_origins[" + std::to_string(i) + "]", "a string", origins[i]);
      sc.allowed_origins.push_back(origins[i].get<std::string>());
    }
  }
  sc.web_root = resolve(r.string_or("web_root", "../web"));
  sc.vendor_root = resolve(r.string_or("vendor_root", "../node_modules"));
  sc.openapi_file = resolve(r.string_or("openapi", "../server/openapi/openapi.json"));
  if (r.has("tls")) {
    // Both or neither: a certificate without its key (or the reverse) is a mistake, not plain HTTP.
    const auto& tls = r.raw("tls");
    if (!tls.is_object() || !tls.contains("certificate") || !tls.contains("private_key") ||
        !tls["certificate"].is_string() || !tls["private_key"].is_string() ||
        tls["certificate"].get<std::string>().empty() || tls["private_key"].get<std::string>().empty())
      r.fail("tls", "an object {\"certificate\": \"PEM file\", \"private_key\": \"PEM file\"}", tls);
    sc.tls_certificate = resolve(tls["certificate"].get<std::string>());
    sc.tls_private_key = resolve(tls["private_key"].get<std::string>());
  }
  sc.control_rate_hz = r.positive_or("control_rate_hz", 1000.0);
  if (sc.control_rate_hz > 10'000) r.fail("control_rate_hz", "at most 10000", r.raw("control_rate_hz"));
  sc.publish_rate_hz = r.positive_or("publish_rate_hz", 50.0);
  if (sc.publish_rate_hz > 1000) r.fail("publish_rate_hz", "at most 1000", r.raw("publish_rate_hz"));
  sc.realtime_priority = r.boolean_or("realtime_priority", true);
  if (r.has("imaging")) {
    r.child("imaging");  // must be an object; its keys are checked by parse_imaging_config
    sc.imaging = r.raw("imaging");
  }
  if (r.has("recording")) {
    r.child("recording");  // must be an object; its keys are checked by parse_recording_config
    sc.recording = r.raw("recording");
  }
  if (r.has("scene")) {
    r.child("scene");  // must be an object; its keys are checked by load_scene_vessel
    sc.scene = r.raw("scene");
  }
  const auto& robots = r.array("robots", true);
  std::set<std::string> names;
  for (std::size_t i = 0; i < robots.size(); ++i) {
    if (!robots[i].is_string())
      r.fail("robots[" + std::to_string(i) + "]", "a path to a robot file", robots[i]);
    auto path = resolve(robots[i].get<std::string>());
    sc.robot_files.push_back(path);
    sc.robots.push_back(load_robot_config(path));
    if (!names.insert(sc.robots.back().name).second)
      throw ConfigError(path.string() + ": name: robot name '" + sc.robots.back().name +
                        "' is already used by another robot file");
  }
  return sc;
}

}  // namespace tendril::server
