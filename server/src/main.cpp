// tendrild: the tendril teleoperation server. Loads the configuration, boots the drives (simulated
// by default), runs the control loop and serves the console and the API until SIGINT/SIGTERM, then
// disables every drive before it exits.
#include <pthread.h>
#include <signal.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tendril/dds/dds_bridge.hpp"
#include "tendril/drivers/canopen/master.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/config_schema.hpp"
#include "tendril/server/http/control_json.hpp"
#include "tendril/server/http/http_server.hpp"
#include "tendril/server/imaged_robot.hpp"
#include "tendril/server/imaging_worker.hpp"
#include "tendril/server/planning_api.hpp"
#include "tendril/server/replay_control_api.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"
#include "tendril/server/session_recording.hpp"
#include "tendril/server/session_replay.hpp"
#include "tendril/server/version.hpp"

namespace {

constexpr const char* kUsage = R"(usage: tendrild [options]

Runs the tendril teleoperation server: real-time control of the configured robots over CANopen
(simulated drives on a virtual bus unless a robot file names a SocketCAN interface), the browser
console and the REST/WebSocket API.

options:
  --config FILE        server configuration (default: config/server.json in the current folder,
                       else the one in the source tree); it lists the robot files to load
  --listen HOST:PORT   address to serve on (default from the config: 127.0.0.1:8080); binding to
                       anything but loopback exposes the robots to the network: do it on purpose
  --token TOKEN        access token for the console and the API (default: $TENDRIL_TOKEN, else
                       the config's "token", else a random one printed in the console URL)
  --allowed-origin O   also accept browser connections from origin O (repeatable), e.g. when
                       serving behind a proxy or from a container; default: the server's own
  --no-realtime        do not ask for SCHED_FIFO / mlockall for the control thread
  --simulated-time     run the robots in simulated time: the SIMULATED devices, buses and control loop
                       are stepped one period at a time, at real-time pace while the machine keeps up;
                       a stall of the machine slips simulated time instead of losing control time, so
                       it can neither fault nor hold a robot. For tests of the logic on a busy machine;
                       refused unless every device is SIMULATED (every bus "virtual"). GET /robots
                       says so in each robot's description, /metrics in tendril_simulated_time
  --no-dds             do not join DDS (default: tendrild is a DDS participant publishing rt/<robot>/...
                       topics and taking commands; README, "DDS")
  --dds-domain N       DDS domain id, 0 to 232 (default 0, as ROS 2's ROS_DOMAIN_ID); Cyclone DDS reads
                       its network settings from $CYCLONEDDS_URI
  --replay PATH        replay a recording (an MCAP file, or a folder of them) through the same
                       WebSocket topics instead of running the robots: no robot is driven (every
                       command answers 409 replay_mode), no bus, DDS, imaging or recording runs;
                       GET/PUT /api/v1/replay play, pause, seek and change the rate
  --version            print the version and exit
  --help               print this help and exit

environment:
  TENDRIL_TOKEN        access token (overridden by --token)

On start it prints one line with the console URL:
  tendril console: http://127.0.0.1:8080/?token=...
SIGINT or SIGTERM disables the drives cleanly and exits.
)";

std::string random_token() {
  std::ifstream urandom("/dev/urandom", std::ios::binary);
  unsigned char bytes[24];
  if (!urandom.read(reinterpret_cast<char*>(bytes), sizeof bytes))
    throw std::runtime_error("cannot read /dev/urandom to make an access token; pass --token");
  std::ostringstream out;
  for (unsigned char b : bytes) out << std::hex << std::setw(2) << std::setfill('0') << static_cast<int>(b);
  return out.str();
}

std::filesystem::path default_config() {
  if (std::filesystem::exists("config/server.json")) return "config/server.json";
  return std::filesystem::path(TENDRIL_SOURCE_DIR) / "config" / "server.json";
}

[[noreturn]] void usage_error(const std::string& message) {
  std::cerr << "tendrild: " << message << "\n(see tendrild --help)\n";
  std::exit(2);
}

// The front end's options from the server file and the command line (live and replay alike).
tendril::server::HttpOptions http_options(const tendril::server::ServerConfig& config,
                                          const std::string& token,
                                          const std::vector<std::string>& extra_origins) {
  tendril::server::HttpOptions ho;
  ho.host = config.host;
  ho.port = config.port;
  ho.token = token;
  ho.allowed_origins = config.allowed_origins;
  ho.allowed_origins.insert(ho.allowed_origins.end(), extra_origins.begin(), extra_origins.end());
  ho.web_root = config.web_root.string();
  ho.static_mounts["/vendor/three/"] = (config.vendor_root / "three").string();
  ho.publish_rate_hz = config.publish_rate_hz;
  ho.openapi_file = config.openapi_file.string();
  if (!std::filesystem::exists(config.openapi_file)) {
    const auto in_source = std::filesystem::path(TENDRIL_SOURCE_DIR) / "server" / "openapi" / "openapi.json";
    ho.openapi_file = std::filesystem::exists(in_source) ? in_source.string() : std::string();
    if (ho.openapi_file.empty())
      std::cerr << "tendrild: no OpenAPI document at " << config.openapi_file.string()
                << "; GET /api/v1/openapi.json will answer 404" << std::endl;
  }
  ho.tls_certificate_file = config.tls_certificate.string();
  ho.tls_private_key_file = config.tls_private_key.string();
  return ho;
}

// The control thread's real-time scheduling, as GET /api/v1/health reports it: asked for, granted
// (with its SCHED_FIFO priority), or why not.
nlohmann::json control_realtime(const tendril::server::LoopStatistics& ls, bool simulated_time) {
  std::string reason;
  if (!ls.realtime_requested)
    reason = simulated_time ? "simulated time: the loop is paced at normal priority by design"
                            : "not asked for (realtime_priority false, or --no-realtime)";
  else if (!ls.realtime_scheduling)
    reason = std::strerror(ls.realtime_error);
  return {{"requested", ls.realtime_requested},
          {"granted", ls.realtime_scheduling},
          {"priority", ls.realtime_scheduling ? ls.realtime_priority : 0},
          {"memory_locked", ls.memory_locked},
          {"reason", reason}};
}

// The same at start-up, for whoever reads the log (a container's log included).
void log_control_realtime(const nlohmann::json& rt) {
  if (rt["granted"].get<bool>()) {
    std::cerr << "tendrild: control loop at real-time priority (SCHED_FIFO " << rt["priority"].get<int>()
              << (rt["memory_locked"].get<bool>() ? ", memory locked)" : ", memory NOT locked)") << std::endl;
  } else if (rt["requested"].get<bool>()) {
    std::cerr << "tendrild: WARNING: the control loop was refused real-time priority ("
              << rt["reason"].get<std::string>()
              << "): it runs at normal priority, so other load on this computer can delay its cycles. "
                 "A container needs CAP_SYS_NICE and a real-time budget from its host (docker/README.md, "
                 "\"Real-time priority\")."
              << std::endl;
  } else {
    std::cerr << "tendrild: control loop at normal priority: " << rt["reason"].get<std::string>()
              << std::endl;
  }
}

void print_console_url(const tendril::server::ServerConfig& config, const tendril::server::HttpServer& http,
                       const std::string& token) {
  std::string shown_host = config.host == "0.0.0.0" || config.host == "::" ? "127.0.0.1" : config.host;
  if (shown_host.find(':') != std::string::npos) shown_host = "[" + shown_host + "]";
  std::cout << "tendril console: " << (http.tls() ? "https://" : "http://") << shown_host << ":"
            << http.port() << "/?token=" << token << std::endl;
}

// How long a stop may take after SIGINT/SIGTERM before the process ends regardless (the drives are
// disabled first, so what is cut short is the rest: a recording's footer, a job, a client's upload).
constexpr std::chrono::seconds kShutdownBound{5};

void start_shutdown_watchdog() {
  std::thread([] {
    std::this_thread::sleep_for(kShutdownBound);
    std::cerr << "tendrild: still stopping " << kShutdownBound.count()
              << " s after the signal (a thread is still busy, e.g. with a client's upload); the drives were "
                 "disabled first; exiting now"
              << std::endl;
    std::_Exit(5);
  }).detach();
}

// tendrild --replay: the robots are described (built from their files, never started: every bus is
// treated as virtual, so no SocketCAN interface is even opened) and the recording is published through
// the WebSocket. Returns the exit code.
int run_replay(tendril::server::ServerConfig config, const std::string& token,
               const std::vector<std::string>& extra_origins, const std::filesystem::path& replay_path,
               sigset_t& stop_signals) {
  using namespace tendril::server;
  for (auto& rc : config.robots)
    for (auto& bus : rc.buses) bus.interface = "virtual";
  RuntimeOptions ro;
  ro.control_rate_hz = config.control_rate_hz;
  ro.realtime_priority = false;
  RobotRuntime runtime(config.robots, ro, builtin_robot_types());  // never started
  std::map<std::string, nlohmann::json> schemas;
  for (const auto& rc : config.robots)
    if (const auto* type = builtin_robot_types().find(rc.kind))
      schemas[rc.name] = robot_schema(type->settings_schema(), rc.kind);
  JsonControlApi description(
      runtime, [&runtime](const std::string& robot) { return runtime.api_extension(robot); },
      [&schemas](const std::string& robot) -> std::optional<nlohmann::json> {
        const auto it = schemas.find(robot);
        if (it == schemas.end()) return std::nullopt;
        return it->second;
      });
  ReplayControlApi api(description);
  std::shared_ptr<SessionReplay> replay;
  try {
    ReplayOptions options;
    options.log = [](std::string_view line) { std::cerr << "tendrild: replay: " << line << std::endl; };
    replay = std::make_shared<SessionReplay>(replay_path, std::move(options));
  } catch (const tendril::record::McapError& e) {
    std::cerr << "tendrild: cannot replay " << replay_path.string() << ": " << e.what() << "\n";
    return 2;
  }
  HttpOptions ho = http_options(config, token, extra_origins);
  ho.topic_sources.push_back(replay);
  ho.replay = replay;
  // The console asks GET /api/v1/replay only where the server says it replays.
  ho.health_details = {{"mode", "replay"},
                       {"control_realtime",
                        {{"requested", false},
                         {"granted", false},
                         {"priority", 0},
                         {"memory_locked", false},
                         {"reason", "replay: no robot is driven, so no control loop runs"}}}};
  HttpServer http(api, ho);
  http.start();
  replay->start();
  std::cerr << "tendrild: replay mode: no robot is driven and every command is refused (409 replay_mode); "
               "GET/PUT /api/v1/replay control the playback"
            << std::endl;
  print_console_url(config, http, token);
  int signal_number = 0;
  sigwait(&stop_signals, &signal_number);
  std::cerr << "tendrild: " << (signal_number == SIGINT ? "SIGINT" : "SIGTERM")
            << " received: stopping the replay" << std::endl;
  start_shutdown_watchdog();
  http.stop();
  replay->stop();
  std::cerr << "tendrild: replay stopped after " << replay->status().messages_sent << " messages"
            << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace tendril::server;
  std::filesystem::path config_file;
  std::string listen, token;
  bool no_realtime = false;
  bool simulated_time = false;
  bool dds_enabled = true;
  std::uint32_t dds_domain = 0;
  std::vector<std::string> extra_origins;
  std::filesystem::path replay_path;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&](const char* name) -> std::string {
      if (i + 1 >= argc) usage_error(std::string(name) + " needs a value");
      return argv[++i];
    };
    if (arg == "--help" || arg == "-h") {
      std::cout << kUsage;
      return 0;
    } else if (arg == "--version") {
      std::cout << "tendrild " << version() << "\n";
      return 0;
    } else if (arg == "--config") {
      config_file = value("--config");
    } else if (arg == "--listen") {
      listen = value("--listen");
    } else if (arg == "--token") {
      token = value("--token");
    } else if (arg == "--allowed-origin") {
      extra_origins.push_back(value("--allowed-origin"));
    } else if (arg == "--no-realtime") {
      no_realtime = true;
    } else if (arg == "--simulated-time") {
      simulated_time = true;
    } else if (arg == "--replay") {
      replay_path = value("--replay");
      if (replay_path.empty()) usage_error("--replay expects an MCAP file or a folder of them");
    } else if (arg == "--no-dds") {
      dds_enabled = false;
    } else if (arg == "--dds-domain") {
      const std::string text = value("--dds-domain");
      std::size_t used = 0;
      unsigned long domain = 233;
      try {
        domain = std::stoul(text, &used);
      } catch (const std::exception&) {
      }
      if (text.empty() || used != text.size() || text[0] == '-' || domain > 232)
        usage_error("--dds-domain expects a DDS domain id from 0 to 232, got '" + text + "'");
      dds_domain = static_cast<std::uint32_t>(domain);
    } else {
      usage_error("unknown option '" + arg + "'");
    }
  }

  // Block the stop signals before any thread starts, so that only the main thread takes them.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  try {
    if (config_file.empty()) config_file = default_config();
    ServerConfig config = load_server_config(config_file);
    if (!listen.empty()) {
      auto colon = listen.rfind(':');
      int port = -1;
      try {
        if (colon != std::string::npos) port = std::stoi(listen.substr(colon + 1));
      } catch (const std::exception&) {
      }
      if (colon == std::string::npos || colon == 0 || port < 0 || port > 65535)
        usage_error("--listen expects HOST:PORT, e.g. 127.0.0.1:8080, got '" + listen + "'");
      config.host = listen.substr(0, colon);
      config.port = static_cast<unsigned short>(port);
    }
    if (token.empty()) {
      if (const char* env = std::getenv("TENDRIL_TOKEN"); env && *env) token = env;
    }
    if (token.empty()) token = config.token;
    if (token.empty()) token = random_token();
    if (!replay_path.empty() && simulated_time)
      usage_error("--simulated-time runs robots; a replay (--replay) drives none");
    if (!replay_path.empty())
      return run_replay(std::move(config), token, extra_origins, replay_path, stop_signals);

    // One world: the scene's vessel is what the robots touch, the fluoroscope images and the 3D view
    // shows, placed at the vessel entry of the scene's robot.
    const SceneVessel scene = load_scene_vessel(config.scene, config.imaging, config.file);
    RuntimeOptions ro;
    ro.control_rate_hz = config.control_rate_hz;
    ro.realtime_priority = config.realtime_priority && !no_realtime;
    ro.scene_vessel = scene.branches;
    ro.simulated_time = simulated_time;
    if (simulated_time)
      std::cerr
          << "tendrild: SIMULATED TIME (--simulated-time): devices and control loop stepped one period at "
             "a time; a stall of this machine slips simulated time and is never lost control time. Not "
             "a real-time run."
          << std::endl;
    const RobotTypes& types = builtin_robot_types();
    RobotRuntime runtime(config.robots, ro, types);
    std::string scene_robot = scene.robot;
    if (!scene_robot.empty() && !runtime.has_robot(scene_robot))
      throw ConfigError(config.file.string() + ": scene.robot: expected one of the server's robots, got \"" +
                        scene_robot + "\"");
    for (const auto& rc : config.robots) {
      if (scene_robot.empty() && runtime.vessel_entry(rc.name)) scene_robot = rc.name;
    }
    const auto entry = scene_robot.empty() ? std::nullopt : runtime.vessel_entry(scene_robot);
    // Every branch moves with the first (the one entered): a vessel tree stays one rigid body.
    std::vector<tendril::teleop::CenterlinePolyline> placed_vessel = scene.branches;
    if (entry && !scene.branches.empty()) {
      const auto placement = tendril::teleop::placement_at_entry(scene.branches.front(), *entry);
      for (auto& branch : placed_vessel) branch = tendril::teleop::transformed(branch, placement);
    }
    runtime.start();
    const nlohmann::json realtime = control_realtime(runtime.loop_statistics(), simulated_time);
    log_control_realtime(realtime);
    // The JSON face of the robots for the front end, with each robot type's part of the API and the
    // schema of each robot file.
    std::map<std::string, nlohmann::json> schemas;
    for (const auto& rc : config.robots)
      if (const auto* type = types.find(rc.kind))
        schemas[rc.name] = robot_schema(type->settings_schema(), rc.kind);
    JsonControlApi api(
        runtime, [&runtime](const std::string& robot) { return runtime.api_extension(robot); },
        [&schemas](const std::string& robot) -> std::optional<nlohmann::json> {
          const auto it = schemas.find(robot);
          if (it == schemas.end()) return std::nullopt;
          return it->second;
        });

    HttpOptions ho = http_options(config, token, extra_origins);
    ho.health_details = {{"mode", "live"}, {"control_realtime", realtime}};
    // Bi-plane imaging (simulated or from sources): its own threads read the runtime snapshot, never the
    // RT thread.
    std::shared_ptr<ImagingWorker> imaging;
    if (auto ic = parse_imaging_config(config.imaging, config.file); ic.enabled) {
      ic.vessels = vessel_tubes(placed_vessel);
      ic.vessel_source =
          scene.source + (entry ? ", its start at the vessel entry of robot '" + scene_robot + "'"
                                : std::string(", in its own frame (no robot has a vessel entry)"));
      const auto geometry = ic.fluoroscope.geometry;  // a copy: ic is moved below
      const double fps = ic.fps;
      const std::string vessel_source = ic.vessel_source;
      // The imaged robot: named in imaging.robot, else the only one (or the scene's) that enters a vessel
      // or uses the images (imaged_robot.hpp); never merely the first in the list.
      std::vector<std::string> robot_names;
      for (const auto& rc : config.robots) robot_names.push_back(rc.name);
      const std::string imaged =
          choose_imaged_robot(runtime, robot_names, ic.robot, scene_robot, config.file.string());
      auto backbone = backbone_from(runtime, imaged);
      ic.robot = imaged;  // whose lease the segmentation editor needs
      imaging = std::make_shared<ImagingWorker>(std::move(backbone), std::move(ic));
      std::cerr << "tendrild: imaging: bi-plane (/imaging/ap, /imaging/lateral) " << geometry.width << "x"
                << geometry.height << ", simulated planes at " << fps << " fps, imaging robot '" << imaged
                << "'; " << imaging->describe_sources() << "; vessel: " << vessel_source << std::endl;
      // Stale, dropped or ended images are the imaged robot's operator's concern: warnings in its log.
      imaging->set_warning_sink([&runtime, imaged](tendril::safety::FaultCode code, const std::string& text) {
        runtime.report_warning(imaged, code, text);
      });
      // Drawn over the images: the loaded plan's planned tips (in the world frame since load_path).
      imaging->set_plan_reader([&runtime, imaged](std::vector<Eigen::Vector3d>& out) {
        const auto path = runtime.path_following(imaged);
        if (!path || !path->loaded) return false;
        out = path->tips;
        return !out.empty();
      });
      // A robot type that closes a loop on the images (a catheter's image-guided mode) gets the tracked
      // tips, and a simulated plane images its simulated plant's true shape.
      if (auto* plugin = runtime.plugin(imaged)) imaging->set_image_feedback(plugin->image_feedback());
      ho.topic_sources.push_back(imaging);
      ho.imaging = imaging;
      imaging->start();
    }
    // The robot types' own topics (a continuum robot's map, an ultrasound arm's images).
    for (const auto& rc : config.robots)
      if (auto* plugin = runtime.plugin(rc.name))
        for (auto& source : plugin->topic_sources()) ho.topic_sources.push_back(std::move(source));
    // Jobs of the robot types (path plans, design optimisation, calibrations) run on their own worker
    // thread(s), never on the RT thread. The first type with a planning service provides it.
    std::unique_ptr<PlanningApi> planning;
    for (const auto& rc : config.robots) {
      if (planning) break;
      // Every robot is passed on, so that the service can say why it makes no plans for one.
      if (const auto* type = types.find(rc.kind)) planning = type->planning_service(config.robots);
    }
    ho.planning = planning.get();
    // The session recording: every published channel and every command, to rotating MCAP files.
    std::shared_ptr<SessionRecording> recording;
    if (const auto rc = parse_recording_config(config.recording, config.file); rc.enabled) {
      recording = std::make_shared<SessionRecording>(
          rc, [](std::string_view line) { std::cerr << "tendrild: recording: " << line << std::endl; });
      std::cerr << "tendrild: recording to " << rc.directory.string() << " ("
                << tendril::record::compression_name(rc.compression) << ", a new file every "
                << rc.max_file_bytes / (1024ULL * 1024ULL) << " MB or "
                << rc.max_file_duration_ns / 60'000'000'000ULL << " min; images "
                << (rc.images_always ? "always" : "while watched") << "; keeping "
                << (rc.keep_total_bytes > 0
                        ? std::to_string(rc.keep_total_bytes / (1024ULL * 1024ULL)) + " MB"
                        : std::string("any size"))
                << (rc.keep_age.count() > 0
                        ? " of files at most " + std::to_string(rc.keep_age.count() / 3600) + " h old"
                        : std::string(" of files of any age"))
                << ")" << std::endl;
      recording->start();
      ho.tap = recording;
    }
    HttpServer http(api, ho);
    // DDS: the robots' state on rt/<robot>/... topics and commands through the same checks as REST
    // (http.command). Its own threads; it never touches the control thread.
    std::unique_ptr<tendril::dds::DdsBridge> dds;
    // The state topics at the WebSocket's rate: the same snapshots, no more load on a test server.
    const double dds_rate_hz = config.publish_rate_hz > 0 ? config.publish_rate_hz : 50.0;
    if (dds_enabled) {
      tendril::dds::DdsOptions dopts;
      dopts.domain = dds_domain;
      dopts.publish_rate_hz = dds_rate_hz;
      // The maps the WebSocket serves, as sensor_msgs/PointCloud2 (rt/maps/vessel, world frame).
      if (imaging && !imaging->vessel_wall().empty())
        dopts.maps.push_back({"vessel", "world", imaging->vessel_wall()});
      try {
        dds = std::make_unique<tendril::dds::DdsBridge>(
            runtime,
            [&http](const std::string& robot, const std::string& command, const nlohmann::json& body,
                    const std::string& lease_token, const std::string& client) {
              return http.command(robot, command, body, lease_token, client);
            },
            dopts);
      } catch (const tendril::dds::DdsError& e) {
        throw std::runtime_error(std::string(e.what()) + "; start with --no-dds to run without DDS");
      }
      http.add_metrics_source([bridge = dds.get()] { return bridge->metrics(); });
    }
    http.start();
    if (dds) {
      dds->start();
      std::cerr << "tendrild: dds: domain " << dds->domain() << ", publishing rt/<robot>/joint_states, "
                << "operating_state, measured_cp and rt/safety/events at " << dds_rate_hz
                << " Hz; commands on rt/<robot>/servo_jv, move_jp, state_command" << std::endl;
    }

    print_console_url(config, http, token);

    int signal_number = 0;
    sigwait(&stop_signals, &signal_number);
    std::cerr << "tendrild: " << (signal_number == SIGINT ? "SIGINT" : "SIGTERM")
              << " received: disabling the drives, then stopping" << std::endl;
    // Whatever the other threads are doing (a client's upload being parsed), the process ends within
    // kShutdownBound; by then the drives were disabled first, below.
    start_shutdown_watchdog();
    // The drives first: the control loop stops and every device is deactivated (the drives disabled)
    // before anything waits for the network threads.
    runtime.stop();
    std::vector<std::string> still_on;
    const bool disabled = runtime.drives_disabled(&still_on);
    std::cerr << "tendrild: " << (disabled ? "drives disabled" : "drives stopped")
              << "; stopping the front end" << std::endl;
    if (dds) dds->stop();  // before the front end whose command path it uses
    http.stop();
    if (recording) {
      recording->stop();  // what is queued is written and the file gets its summary and footer
      const auto stats = recording->stats();
      std::cerr << "tendrild: recording: " << stats.written << " messages in " << stats.files << " file(s), "
                << stats.dropped << " dropped" << (stats.error.empty() ? "" : "; error: " + stats.error)
                << std::endl;
    }
    if (planning) planning->shutdown();
    if (imaging) imaging->stop();
    if (!disabled) {
      std::cerr << "tendrild: stopped, but these drives did not confirm they are disabled:";
      for (const auto& d : still_on) std::cerr << " " << d;
      std::cerr << " (they quick-stop by themselves when the master heartbeat ends)" << std::endl;
      return 1;
    }
    std::cerr << "tendrild: drives disabled, stopped cleanly" << std::endl;
    return 0;
  } catch (const ConfigError& e) {
    std::cerr << "tendrild: configuration error: " << e.what() << "\n";
    return 2;
  } catch (const tendril::canopen::CanopenError& e) {
    std::cerr << "tendrild: a drive did not come up: " << e.what() << "\n";
    return 3;
  } catch (const std::exception& e) {
    std::cerr << "tendrild: " << e.what() << "\n";
    return 1;
  }
}
