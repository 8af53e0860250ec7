// The serial arm's part of the network API (network threads): its fields of /robots and of
// operating_state, and the /{robot}/arm topic with the values that change with every reading. The
// Cartesian commands themselves are the core's CRTK endpoints (move_cp, servo_cp, servo_cv, measured_*),
// which reach the type through RobotPlugin::cartesian_command. With an "ultrasound" section the arm adds
// the command sweep {"action": "plan|preview|pre_position|start|pause|abort"} and its live state goes
// out on /{robot}/sweep (with the arm's fields) instead of /{robot}/arm.
#include <cstdio>
#include <exception>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

json vec3(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

class SerialArmApi final : public RobotApiExtension {
 public:
  SerialArmApi(SerialArm& robot, RobotService& service, std::function<bool(const PluginCommand&)> post)
      : robot_(robot), service_(service), post_(std::move(post)) {}

  void describe(json& out) const override {
    const auto& s = robot_.settings();
    out["arm"] = {
        {"model", s.model},
        {"simulated", true},
        {"link", "SIMULATED arm at the joint interface (a real UR5: RTDE over Ethernet, not implemented)"},
        {"units",
         {{"position", "mm"}, {"linear_velocity", "mm/s"}, {"angular_velocity", "rad/s"}, {"force", "N"}}},
        {"tool_offset_mm", vec3(s.parameters.tool.translation())},
        {"cartesian",
         {{"max_linear_speed_mm_s", s.cartesian.max_linear_speed},
          {"max_angular_speed_rad_s", s.cartesian.max_angular_speed},
          {"max_linear_acceleration_mm_s2", s.cartesian.max_linear_acceleration},
          {"max_angular_acceleration_rad_s2", s.cartesian.max_angular_acceleration},
          {"servo_cp_max_step_mm", s.servo_cp_max_step_mm},
          {"servo_cp_max_step_rad", s.servo_cp_max_step_rad}}},
        {"workspace_mm", {{"min", vec3(s.workspace_min)}, {"max", vec3(s.workspace_max)}}},
        {"force",
         {{"stale_ms", s.force_stale_s * 1e3},
          {"max_contact_force_n", s.max_contact_force_n},
          {"resume_contact_force_n", s.resume_contact_force_n},
          {"retract_speed_mm_s", s.retract_speed_mm_s}}}};
    if (const auto& u = robot_.ultrasound()) {
      const auto& l = u->limb;
      out["ultrasound"] = {
          {"via_points", u->via_points},
          {"force_target_n", u->force.contact_force},
          {"gate",
           {{"position_mm", u->gate.position_setpoint},
            {"angle_rad", u->gate.orientation_setpoint},
            {"force_tolerance_n", u->gate.force_tolerance},
            {"hold_ms", u->gate.hold_time * 1e3}}},
          {"caps",
           {{"linear_mm_s", s.cartesian.max_linear_speed}, {"angular_rad_s", s.cartesian.max_angular_speed}}},
          {"approach_height_mm", u->approach_height},
          {"acquire_ms", u->acquire_time * 1e3},
          {"retract", {{"speed_mm_s", u->retract_speed}, {"distance_mm", u->retract_distance}}},
          {"compensation_hz", l.tracker_rate},
          {"tracker_latency_ms", l.tracker_latency * 1e3},
          {"tracker_noise_mm", l.tracker_noise},
          {"tracker_filter_hz", u->tracker_filter_hz},
          {"limb",
           {{"rest_position_mm", vec3(l.rest_pose.translation())},
            {"period_s", l.period},
            {"stiffness_n_per_mm", l.stiffness},
            {"artery_radius_mm", l.artery_radius}}},
          {"frames",
           "world = the arm's base frame (us_arm_base); the limb frame (tissue) has z out of the skin, x "
           "along "
           "the limb"},
          {"simulated", true}};
    }
    if (const auto* runner = robot_.calibrations()) {
      json required = json::array();
      for (const auto& k : runner->store().kinds())
        if (k.required) required.push_back(k.kind);
      out["calibrations"] = {{"kinds", runner->kinds()},
                             {"required", std::move(required)},
                             {"store", runner->store().directory().string()},
                             {"problems", runner->store().problems()}};
    }
  }

  std::vector<RobotCommandInfo> commands() const override {
    if (!robot_.ultrasound()) return {};
    std::vector<RobotCommandInfo> out;
    if (const auto* runner = robot_.calibrations())
      out.push_back(
          {"calibrate",
           {{"type", "object"},
            {"properties", {{"kind", {{"enum", runner->kinds()}}}}},
            {"required", {"kind"}}},
           false,
           "",
           "runs a calibration routine of the kind (robot: the arm moves through 12 poses near where "
           "it is, in cartesian mode; progress and result in operating_state.calibration)"});
    out.push_back(
        {"sweep",
         {{"type", "object"},
          {"properties",
           {{"action", {{"enum", {"plan", "preview", "pre_position", "start", "pause", "abort"}}}}}},
          {"required", {"action"}}},
         false,
         "",
         "the ultrasound sweep: plan (ICP of the CT to the skin, Algorithms 1-2), preview (the via-point "
         "poses), pre_position (above via-point 1), start, pause (stay in contact), abort (retract and "
         "hold)"});
    return out;
  }

  ApiResult calibrate(const json& body) {
    auto* runner = robot_.calibrations();
    const std::string& robot = robot_.config().name;
    std::string kinds;
    for (const auto& k : runner->kinds()) kinds += (kinds.empty() ? "" : ", ") + k;
    if (!body.is_object() || !body.contains("kind") || !body["kind"].is_string())
      return ApiResult::error(400, "bad_request", "calibrate: expected {\"kind\": one of " + kinds + "}");
    const std::string kind = body["kind"].get<std::string>();
    if (!runner->has(kind))
      return ApiResult::error(400, "bad_request",
                              "calibrate: unknown kind '" + kind + "'; robot '" + robot + "' has " + kinds);
    const auto state = service_.operating_state(robot);
    if (!state) return ApiResult::error(404, "not_found", state.error().message);
    if (auto refusal = runner->run(kind, *state)) return ApiResult::error(409, "conflict", *refusal);
    return ApiResult::success({{"kind", kind}, {"started", true}}, 202);
  }

  ApiResult command(const std::string& name, const json& body) override {
    if (name == "calibrate" && robot_.calibrations()) return calibrate(body);
    if (name != "sweep" || !robot_.ultrasound())
      return ApiResult::error(404, "not_found", "no command " + name);
    if (!body.is_object() || !body.contains("action") || !body["action"].is_string())
      return ApiResult::error(
          400, "bad_request",
          "sweep: expected {\"action\": one of plan, preview, pre_position, start, pause, "
          "abort}");
    const auto action = sweep_action(body["action"].get<std::string>());
    if (!action)
      return ApiResult::error(400, "bad_request",
                              "sweep: unknown action '" + body["action"].get<std::string>() +
                                  "'; expected plan, preview, pre_position, start, pause or abort");
    const std::string& robot = robot_.config().name;
    const SweepSnapshot s = robot_.sweep_snapshot();
    const SweepPhase phase = s.phase;
    const bool running = phase == SweepPhase::pre_positioning || phase == SweepPhase::ready ||
                         phase == SweepPhase::approaching || phase == SweepPhase::acquiring ||
                         phase == SweepPhase::moving || phase == SweepPhase::paused;
    auto conflict = [](std::string message) { return ApiResult::error(409, "conflict", std::move(message)); };
    switch (*action) {
      case SweepAction::plan: {
        if (auto why = missing_calibrations()) return conflict(*why);
        if (running)
          return conflict("sweep: cannot plan while a sweep is " + std::string(to_string(phase)) +
                          "; abort it first (POST /api/v1/robots/" + robot +
                          "/sweep {\"action\":\"abort\"})");
        try {
          auto plan = std::make_shared<SweepPlan>(make_sweep_plan(*robot_.limb(), *robot_.ultrasound()));
          if (auto why = outside_workspace(*plan)) return ApiResult::error(422, "out_of_workspace", *why);
          json answer = plan_json(*plan, true);
          robot_.set_sweep_plan(std::move(plan));
          PluginCommand c;
          c.id = static_cast<std::uint16_t>(ArmCommand::sweep_load);
          if (!post_(c)) return busy();
          return ApiResult::success(std::move(answer));
        } catch (const std::exception& e) {
          return ApiResult::error(422, "planning_failed", std::string("sweep: planning failed: ") + e.what());
        }
      }
      case SweepAction::preview: {
        const auto plan = robot_.sweep_plan();
        if (!plan)
          return conflict("sweep: nothing to preview: plan first (POST /api/v1/robots/" + robot +
                          "/sweep {\"action\":\"plan\"})");
        return ApiResult::success(plan_json(*plan, false));
      }
      default:
        break;
    }
    const auto state = service_.operating_state(robot);
    if (!state) return ApiResult::error(404, "not_found", state.error().message);
    const bool moving_action = *action == SweepAction::pre_position || *action == SweepAction::start;
    if (state->mode != "sweep")
      return conflict("sweep: robot '" + robot + "' is in " + state->mode +
                      " mode; switch to sweep mode (POST /api/v1/robots/" + robot +
                      "/mode {\"mode\": \"sweep\"}) first");
    if (moving_action && state->state != safety::OperatingState::kEnabled)
      return conflict("sweep: robot '" + robot + "' is " + std::string(safety::to_string(state->state)) +
                      "; enable it (or resume it) first");
    if (moving_action && !state->drives_ready)
      return conflict("sweep: robot '" + robot +
                      "' is ENABLED but its drives are not ready yet; try again in a moment");
    switch (*action) {
      case SweepAction::pre_position:
        if (phase == SweepPhase::idle)
          return conflict("sweep: no plan yet: plan first (POST /api/v1/robots/" + robot +
                          "/sweep {\"action\":\"plan\"})");
        if (running)
          return conflict("sweep: the sweep is " + std::string(to_string(phase)) +
                          "; abort it before pre-positioning again");
        break;
      case SweepAction::start:
        if (phase == SweepPhase::idle)
          return conflict("sweep: cannot start: there is no plan; plan, then pre_position, then start");
        if (phase == SweepPhase::planned || phase == SweepPhase::done || phase == SweepPhase::aborted)
          return conflict("sweep: cannot start from " + std::string(to_string(phase)) +
                          ": pre_position first (the probe goes above via-point 1), then start");
        if (phase == SweepPhase::pre_positioning)
          return conflict(
              "sweep: cannot start yet: the probe is still pre-positioning; start once the phase "
              "is ready");
        if (phase != SweepPhase::ready && phase != SweepPhase::paused)
          return conflict("sweep: the sweep is already " + std::string(to_string(phase)));
        break;
      case SweepAction::pause:
        if (!running || phase == SweepPhase::paused)
          return conflict("sweep: nothing to pause: the sweep is " + std::string(to_string(phase)));
        break;
      case SweepAction::abort:
        if (!running)
          return conflict("sweep: nothing to abort: the sweep is " + std::string(to_string(phase)));
        break;
      default:
        break;
    }
    if (*action == SweepAction::pre_position || *action == SweepAction::start)
      if (auto why = missing_calibrations()) return conflict(*why);
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(ArmCommand::sweep_action);
    c.count = 1;
    c.values[0] = static_cast<double>(static_cast<int>(*action));
    if (!post_(c)) return busy();
    return ApiResult::success({{"action", to_string(*action)}, {"phase", to_string(phase)}}, 202);
  }

  void state(json& out) const override {
    const auto s = robot_.snapshot();
    const auto& settings = robot_.settings();
    const Eigen::Vector3d f(s.force_n[0], s.force_n[1], s.force_n[2]);
    json arm = {{"motion", to_string(s.motion)},
                {"goal", nullptr},
                {"twist_limited", s.twist_limited},
                {"workspace_limited", s.workspace_limited},
                {"force_n", s.force_valid ? vec3(f) : json(nullptr)},
                {"contact_force_n", s.force_valid ? json(f.norm()) : json(nullptr)},
                {"force_fresh", s.force_fresh},
                {"force_hold", s.force_hold},
                {"retracting", s.retracting}};
    if (s.motion == ArmMotion::move_cp || s.motion == ArmMotion::servo_cp)
      arm["goal"] = {{"position", {s.goal[0], s.goal[1], s.goal[2]}},
                     {"orientation", {s.goal[3], s.goal[4], s.goal[5], s.goal[6]}}};
    const auto truth = robot_.simulated_force_sensor().truth();
    arm["simulation"] = {{"in_contact", truth.in_contact}, {"penetration_mm", truth.penetration}};
    out["arm"] = std::move(arm);
    if (const auto* runner = robot_.calibrations()) out["calibration"] = runner->state_json();
    if (const auto& u = robot_.ultrasound()) {
      out["sweep"] = sweep_json(robot_.sweep_snapshot());
      out["sweep"]["force_target_n"] = u->force.contact_force;
    }
    if (s.force_hold && out.contains("hold") && out["hold"].is_object()) {
      char next[160];
      std::snprintf(
          next, sizeof next,
          s.retracting
              ? "the tool is retracting along the contact force at %.0f mm/s; resume once under %.2f N"
              : "the retraction ended (%.0f mm/s); resume once the contact force is under %.2f N",
          settings.retract_speed_mm_s, settings.resume_contact_force_n);
      out["hold"]["next"] = next;
    }
  }

  std::optional<LiveState> live_state() const override {
    if (robot_.ultrasound())
      // The sweep's phase, gate and force change every cycle: /{robot}/sweep at 20 Hz carries them with
      // the arm's live fields.
      return LiveState{"sweep",
                       "tendril.UltrasoundSweepState",
                       20.0,
                       {"sweep", "calibration", "arm.force_n", "arm.contact_force_n", "arm.force_fresh",
                        "arm.simulation", "arm.twist_limited", "arm.workspace_limited"}};
    // The force and the simulated contact change with every reading: they go out on /{robot}/arm at
    // 10 Hz, so /{robot}/operating_state changes only with the state.
    return LiveState{"arm",
                     "tendril.ArmState",
                     10.0,
                     {"arm.force_n", "arm.contact_force_n", "arm.force_fresh", "arm.simulation",
                      "arm.twist_limited", "arm.workspace_limited"}};
  }

 private:
  // No sweep without a valid calibration of every required kind; the sentence names them
  // and the requests that make them.
  std::optional<std::string> missing_calibrations() const {
    const auto* runner = robot_.calibrations();
    if (!runner) return std::nullopt;
    const auto missing = runner->store().missing_required();
    if (missing.empty()) return std::nullopt;
    std::string what, how;
    for (const auto& k : missing) {
      what += (what.empty() ? "" : ", ") + k.kind;
      how += (how.empty() ? "" : ", then ") + k.command;
    }
    return "sweep: no valid " + what + " calibration; run " + how + " first";
  }

  // A plan whose via-points (or the pre-position above the first) leave the arm's workspace box at
  // the limb's rest pose would stall at the box: refused with the first offender, before anything moves.
  std::optional<std::string> outside_workspace(const SweepPlan& plan) const {
    const auto& s = robot_.settings();
    const auto& u = *robot_.ultrasound();
    const Eigen::Isometry3d rest = u.limb.rest_pose;
    for (std::size_t i = 0; i < plan.via_points.size(); ++i) {
      const Eigen::Isometry3d world = rest * plan.via_points[i];
      std::vector<std::pair<Eigen::Vector3d, const char*>> points = {{world.translation(), "via-point"}};
      if (i == 0)
        points.emplace_back(world.translation() - u.approach_height * world.linear().col(2),
                            "pre-position above via-point");
      for (const auto& [p, what] : points)
        if ((p.array() < s.workspace_min.array()).any() || (p.array() > s.workspace_max.array()).any()) {
          char buf[256];
          std::snprintf(
              buf, sizeof buf,
              "sweep: the %s %zu at (%.1f, %.1f, %.1f) mm is outside the arm's workspace box "
              "(x %.0f..%.0f, y %.0f..%.0f, z %.0f..%.0f mm); move the limb or widen arm.workspace_mm",
              what, i + 1, p.x(), p.y(), p.z(), s.workspace_min.x(), s.workspace_max.x(), s.workspace_min.y(),
              s.workspace_max.y(), s.workspace_min.z(), s.workspace_max.z());
          return std::string(buf);
        }
    }
    return std::nullopt;
  }

  static ApiResult busy() {
    return ApiResult::error(503, "busy", "sweep: the control thread's mailbox is full; try again");
  }

  static json pose_json(const Eigen::Isometry3d& pose) {
    const Eigen::Quaterniond q(pose.linear());
    return {{"position", vec3(pose.translation())}, {"orientation", {q.x(), q.y(), q.z(), q.w()}}};
  }

  json plan_json(const SweepPlan& plan, bool with_clouds) const {
    const LimbPoseSample limb = robot_.limb()->tracked();
    const Eigen::Isometry3d world_T_limb = to_isometry(limb.pose);
    json via = json::array();
    for (std::size_t i = 0; i < plan.via_points.size(); ++i)
      via.push_back({{"index", i},
                     {"limb", pose_json(plan.via_points[i])},
                     {"world", pose_json(world_T_limb * plan.via_points[i])}});
    json centroids = json::array();
    for (const auto& c : plan.centroids) centroids.push_back(vec3(c));
    json out = {{"via_points", std::move(via)},
                {"centroids_limb_mm", std::move(centroids)},
                {"registration",
                 {{"icp_rms_mm", plan.icp_rms},
                  {"icp_iterations", plan.icp_iterations},
                  {"error_mm", plan.registration_error},
                  {"error_across_limb_mm", plan.registration_error_across},
                  {"ct_to_limb", pose_json(plan.ct_to_limb)}}},
                {"planning_time_s", plan.planning_time},
                {"frames",
                 "limb: the tissue frame (moves with the limb); world: the arm's base frame, at the "
                 "limb's latest tracked pose"}};
    if (with_clouds) out["skin_points"] = plan.skin.size();
    return out;
  }

  static json sweep_json(const SweepSnapshot& s) {
    return {{"phase", to_string(s.phase)},
            {"via_point", s.via_point},
            {"via_points", s.via_points},
            {"progress", s.progress},
            {"force_n", s.force_n},
            {"in_contact", s.in_contact},
            {"retracting", s.retracting},
            {"gate",
             {{"position_error_mm", s.position_error_mm},
              {"angle_error_rad", s.angle_error_rad},
              {"force_ok", s.force_ok},
              {"open", s.gate_open}}},
            {"limb_offset_mm", {s.limb_offset_mm[0], s.limb_offset_mm[1], s.limb_offset_mm[2]}},
            {"slices", s.slices},
            {"message", std::string(s.message)}};
  }

  SerialArm& robot_;
  RobotService& service_;
  std::function<bool(const PluginCommand&)> post_;
};

}  // namespace

std::unique_ptr<RobotApiExtension> make_serial_arm_api(SerialArm& robot, RobotService& service,
                                                       std::function<bool(const PluginCommand&)> post) {
  return std::make_unique<SerialArmApi>(robot, service, std::move(post));
}

}  // namespace tendril::server
