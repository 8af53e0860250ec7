// Fuzz target: the bodies of every robot's commands, as the REST layer hands them over (a parsed JSON
// object) — the core's (state_command, mode, move_jp, servo_jv, move_cp, servo_cp, servo_cv,
// path_step) and each plug-in's own (GET /robots "commands") — against one stepped runtime with every
// shipped robot kind. An input is up to eight lines "<robot><command><JSON body>": the first byte picks
// the robot, the second the command, the rest is the body. After each line the runtime runs one control
// cycle, so what was accepted also reaches the control thread.
// Invariants: a refusal carries a code and a sentence; nothing throws out of the API; every setpoint stays
// finite and inside its joint's limits, whatever was asked.
// The runtime lives for the whole fuzzing run (building one per input would be all the fuzzer does), so
// an input's effect can depend on the ones before it: a crash is reproduced with the inputs libFuzzer
// saved before it (-runs over the corpus directory), not always with the one file alone.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <unistd.h>

#include "tendril/server/config.hpp"
#include "tendril/server/http/control_json.hpp"
#include "tendril/server/http/request_codec.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"

namespace {

using namespace tendril::server;
using nlohmann::json;

struct World {
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  std::vector<std::string> robots;
  std::vector<json> joints;  // per robot: GET /robots "joints"
};

bool within_limits(World& w, bool fail);

// The arm's calibrate command writes calibration files (teleop/ultrasound_arm/README.md): into a folder
// of this run's own, removed at exit, unless the caller chose TENDRIL_STATE_DIR; never ~/.local/state.
void use_own_state_dir() {
  const char* chosen = std::getenv("TENDRIL_STATE_DIR");
  if (chosen != nullptr && *chosen != '\0') return;
  static std::string dir = (std::filesystem::temp_directory_path() / "tendril-fuzz-state.XXXXXX").string();
  if (::mkdtemp(dir.data()) == nullptr) std::abort();
  ::setenv("TENDRIL_STATE_DIR", dir.c_str(), 1);
  std::atexit([] {
    std::error_code ignored;
    std::filesystem::remove_all(dir, ignored);
  });
}

World& world() {
  static World w = [] {
    use_own_state_dir();
    const std::filesystem::path dir = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";
    std::vector<RobotConfig> robots;
    for (const char* file : {"srmc.json", "sdu_continuum.json", "mbcr_vd.json", "us_arm.json"})
      robots.push_back(load_robot_config(dir / file));
    RuntimeOptions options;
    options.stepped = true;
    options.control_rate_hz = 1000;
    World out;
    out.runtime = std::make_unique<RobotRuntime>(std::move(robots), options, builtin_robot_types());
    auto* runtime = out.runtime.get();
    out.api = std::make_unique<JsonControlApi>(
        *runtime, [runtime](const std::string& robot) { return runtime->api_extension(robot); });
    runtime->start();
    for (const auto& r : out.api->robots()) {
      out.robots.push_back(r.at("name").get<std::string>());
      out.joints.push_back(r.at("joints"));
    }
    // As tendrild serves: after the drives came up and reported (the positions before their first
    // report are the start-up zeros, outside the mbcr diameter joint's limits).
    for (int i = 0; i < 5000 && !within_limits(out, false); ++i) out.runtime->step();
    if (!within_limits(out, false)) std::abort();
    return out;
  }();
  return w;
}

const char* const kCoreCommands[] = {"state_command", "mode",     "move_jp",  "servo_jv",
                                     "move_cp",       "servo_cp", "servo_cv", "path_step"};
constexpr std::size_t kCore = sizeof(kCoreCommands) / sizeof(kCoreCommands[0]);

ApiResult call(JsonControlApi& api, const std::string& robot, std::string_view command, const json& body) {
  if (command == "state_command") return api.state_command(robot, body);
  if (command == "mode") return api.mode(robot, body);
  if (command == "move_jp") return api.move_jp(robot, body);
  if (command == "servo_jv") return api.servo_jv(robot, body);
  if (command == "move_cp") return api.move_cp(robot, body);
  if (command == "servo_cp") return api.servo_cp(robot, body);
  if (command == "servo_cv") return api.servo_cv(robot, body);
  if (command == "path_step") return api.path_step(robot, body);
  return api.robot_command(robot, std::string(command), body);
}

// Every robot's setpoints finite and inside its joints' limits; `fail` aborts at the first that is not.
bool within_limits(World& w, bool fail) {
  for (std::size_t r = 0; r < w.robots.size(); ++r) {
    const auto sp = w.api->setpoint_js(w.robots[r]);
    if (!sp.ok()) std::abort();
    const auto& position = sp.body.at("position");
    const auto& joints = w.joints[r];
    if (position.size() != joints.size()) std::abort();
    for (std::size_t j = 0; j < position.size(); ++j) {
      const double p = position[j].get<double>();
      const double lower = joints[j].at("lower").get<double>();
      const double upper = joints[j].at("upper").get<double>();
      const double slack = 1e-6 * std::max(1.0, upper - lower);
      if (std::isfinite(p) && p >= lower - slack && p <= upper + slack) continue;
      if (!fail) return false;
      std::fprintf(stderr, "robot '%s' joint %zu: setpoint %g outside [%g, %g]\n", w.robots[r].c_str(), j, p,
                   lower, upper);
      std::abort();
    }
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  auto& w = world();
  std::string_view input(reinterpret_cast<const char*>(data), size);
  for (int line = 0; line < 8 && input.size() >= 2; ++line) {
    const auto end = input.find('\n');
    const std::string_view text = input.substr(0, end);
    input = end == std::string_view::npos ? std::string_view{} : input.substr(end + 1);
    if (text.size() < 2) continue;
    const std::string& robot = w.robots[static_cast<std::uint8_t>(text[0]) % w.robots.size()];
    const auto extra = w.api->robot_commands(robot);
    const std::size_t pick = static_cast<std::uint8_t>(text[1]) % (kCore + extra.size());
    const std::string command = pick < kCore ? kCoreCommands[pick] : extra[pick - kCore].name;
    const auto body = http::parse_json_body(text.substr(2), 64 * 1024);
    if (!body.ok()) continue;  // refused by the REST layer before any robot sees it (fuzz_rest_body)
    const auto result = call(*w.api, robot, command, body.body);
    if (result.status < 200 || result.status > 599) std::abort();
    if (!result.ok() && (result.code.empty() || result.message.empty())) std::abort();
    w.runtime->step();
    within_limits(w, true);
  }
  return 0;
}
