// The mbcr_vd's part of the network API (network threads): its fields of /robots and operating_state,
// the /{robot}/actuation topic (diameter and actuation forces, 20 Hz), and its commands `trajectory`
// (the dissertation's circle) and `diameter` (variable or fixed for the task mode). servo_cv and move_cp are
// the core's CRTK endpoints, which reach the type through RobotPlugin::cartesian_command.
#include <cmath>
#include <utility>

#include "mbcr_vd/mbcr_vd_robot.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

json finite_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

class MbcrApi final : public RobotApiExtension {
 public:
  MbcrApi(MbcrRobot& robot, RobotService& service, std::function<bool(const PluginCommand&)> post)
      : robot_(robot), service_(service), post_(std::move(post)) {}

  void describe(json& out) const override {
    const auto& s = robot_.settings();
    const auto& p = s.parameters;
    const auto& l = robot_.model().linkage();
    const auto& c = s.circle;
    out["mbcr"] = {
        {"model",
         "three-segment multi-backbone continuum robot with scissor-linkage disks (Abah 2022, ch. 2)"},
        {"simulated", true},
        {"drives", "CiA 402 lead-screw axes on the robot's CAN bus; SIMULATED on a virtual bus"},
        {"units",
         {{"joints", "mm"},
          {"position", "mm"},
          {"linear_velocity", "mm/s"},
          {"angular_velocity", "rad/s"},
          {"force", "N"}}},
        {"joints",
         "backbones 1 and 2 of segments 1, 2, 3 (3 and 4 are their mirror images), then the diameter joint a "
         "(the linkages' inner radius)"},
        {"linkage",
         {{"rhombus_count", p.linkage.rhombus_count},
          {"arm_length_mm", p.linkage.inner_arm_length},
          {"hinge_diameter_mm", p.linkage.hinge_diameter},
          {"inner_radius_mm", {l.inner_radius_min(), l.inner_radius_max()}},
          {"outer_diameter_mm", {2.0 * l.outer_radius_min(), 2.0 * l.outer_radius_max()}}}},
        {"segments",
         {{"count", 3},
          {"length_mm", p.disks.segment_length},
          {"disk_count", p.disks.disk_count},
          {"disk_height_mm", p.disks.disk_height}}},
        {"backbone", {{"diameter_mm", p.backbone_diameter}, {"youngs_modulus_mpa", p.youngs_modulus}}},
        {"backbone_limits_mm", {p.backbone_lower, p.backbone_upper}},
        {"redundancy",
         {{"force_weight", p.redundancy.force_weight},
          {"limit_weight", p.redundancy.limit_weight},
          {"step_gain", p.redundancy.step_gain},
          {"max_diameter_rate_mm_s", p.redundancy.max_diameter_rate}}},
        {"payload_n", {s.payload[0], s.payload[1], s.payload[2]}},
        {"task",
         {{"max_linear_speed_mm_s", s.max_linear_speed},
          {"max_angular_speed_rad_s", s.max_angular_speed},
          {"goal_tolerance_mm", s.goal_tolerance_mm}}},
        {"trajectories",
         {{"seed_circle",
           {{"centre_mm", {c.centre.x(), c.centre.y(), c.centre.z()}},
            {"radius_mm", c.radius},
            {"period_s", c.period},
            {"branch", "hook"},
            {"approach_speed_mm_s", s.approach_speed}}}}}};
  }

  void state(json& out) const override {
    const auto s = robot_.snapshot();
    const auto& p = robot_.settings().parameters;
    json forces = json::array();
    for (double f : s.backbone_forces) forces.push_back(f);
    json limits_active = json::array();
    if (s.diameter_joint <= s.limits.lower + 0.01) limits_active.push_back("diameter_lower");
    if (s.diameter_joint >= s.limits.upper - 0.01)
      limits_active.push_back(s.limits.upper < robot_.model().linkage().inner_radius_max() - 0.01
                                  ? "interference"
                                  : "diameter_upper");
    if (s.interference_unavoidable) limits_active.push_back("interference_unavoidable");
    if (s.backbone_limited) limits_active.push_back("backbone");
    if (s.interference_limited) limits_active.push_back("interference_stop");
    json trajectory = nullptr;
    if (s.motion == MbcrMotion::approach || s.motion == MbcrMotion::circle)
      trajectory = {{"name", "seed_circle"},
                    {"phase", to_string(s.motion)},
                    {"diameter", s.variable_diameter ? "variable" : "fixed"}};
    out["mbcr"] = {
        {"motion", to_string(s.motion)},
        {"diameter", s.variable_diameter ? "variable" : "fixed"},
        {"trajectory", trajectory},
        {"actuation",
         {{"diameter_mm", s.outer_diameter},
          {"inner_radius_mm", s.diameter_joint},
          {"inner_radius_limits_mm", {s.limits.lower, s.limits.upper}},
          {"backbone_forces_n", forces},
          {"diameter_force_n", s.diameter_force},
          {"force_norm_n", s.force_norm},
          {"rms_force_n", s.circle_samples > 0 ? json(s.circle_rms) : json(nullptr)},
          {"interference_margin", finite_or_null(s.interference_margin)},
          {"limits_active", limits_active},
          {"null_space_gain", p.redundancy.step_gain},
          {"force_gradient_n_per_mm", s.force_gradient},
          {"tracking_error_mm", s.tracking_error},
          {"circle",
           {{"samples", s.circle_samples},
            {"unavoidable_interference_steps", s.circle_unavoidable_steps},
            {"last_rms_variable_n", s.last_rms_variable >= 0.0 ? json(s.last_rms_variable) : json(nullptr)},
            {"last_rms_fixed_n", s.last_rms_fixed >= 0.0 ? json(s.last_rms_fixed) : json(nullptr)}}}}}};
  }

  std::vector<RobotCommandInfo> commands() const override {
    return {
        {"trajectory",
         {{"type", "object"},
          {"properties",
           {{"action", {{"enum", {"start", "stop"}}}},
            {"name", {{"enum", {"seed_circle"}}}},
            {"diameter", {{"enum", {"variable", "fixed"}}}}}},
          {"required", {"action"}}},
         false,
         "",
         "task mode: start (moves to the circle's start, then runs the circle of Abah 2022, §2.7.2, with "
         "the "
         "diameter variable or fixed) or stop the seed_circle trajectory"},
        {"diameter",
         {{"type", "object"},
          {"properties", {{"mode", {{"enum", {"variable", "fixed"}}}}}},
          {"required", {"mode"}}},
         false,
         "",
         "the task mode's redundancy resolution: variable (gradient projection lowers the actuation forces) "
         "or "
         "fixed (the diameter is held)"},
    };
  }

  ApiResult command(const std::string& name, const json& body) override {
    if (name == "trajectory") return trajectory(body);
    if (name == "diameter") return diameter(body);
    return ApiResult::error(404, "not_found", "no command " + name);
  }

  std::optional<LiveState> live_state() const override {
    // The diameter and forces change every tick while the robot moves: they go out on
    // /{robot}/actuation at 20 Hz, so /{robot}/operating_state changes only with the state.
    return LiveState{"actuation", "tendril.VariableDiameterState", 20.0, {"mbcr.actuation"}};
  }

 private:
  static std::optional<bool> diameter_choice(const json& body, const char* key, ApiResult& error) {
    if (!body.contains(key)) return std::nullopt;
    const auto& v = body[key];
    if (v != "variable" && v != "fixed") {
      error = ApiResult::error(400, "bad_request", std::string(key) + " must be \"variable\" or \"fixed\"");
      return std::nullopt;
    }
    return v == "variable";
  }

  ApiResult trajectory(const json& body) {
    const std::string& robot = robot_.config().name;
    if (!body.is_object() || !body.contains("action") || !body["action"].is_string())
      return ApiResult::error(400, "bad_request",
                              "expected {\"action\": \"start\" | \"stop\", \"name\": \"seed_circle\", "
                              "\"diameter\": \"variable\" | \"fixed\"}");
    const std::string action = body["action"].get<std::string>();
    if (action != "start" && action != "stop")
      return ApiResult::error(400, "bad_request",
                              "action must be \"start\" or \"stop\", got \"" + action + "\"");
    if (body.contains("name") && body["name"] != "seed_circle")
      return ApiResult::error(400, "bad_request",
                              "unknown trajectory " + body["name"].dump() + "; robot '" + robot +
                                  "' knows \"seed_circle\" (Abah 2022, §2.7.2)");
    ApiResult bad;
    const auto choice = diameter_choice(body, "diameter", bad);
    if (!bad.ok()) return bad;
    PluginCommand c;
    if (action == "stop") {
      c.id = static_cast<std::uint16_t>(MbcrCommand::circle_stop);
      if (!post_(c)) return busy();
      return ApiResult::success({{"accepted", true}}, 202);
    }
    auto state = service_.operating_state(robot);
    if (!state) return ApiResult::error(404, "not_found", "no robot '" + robot + "'");
    if (state->mode != "task")
      return ApiResult::error(409, "wrong_mode",
                              "robot '" + robot + "' is in " + state->mode +
                                  " mode; switch to task mode (POST /api/v1/robots/" + robot +
                                  "/mode {\"mode\": \"task\"}) to run a trajectory");
    if (state->state != safety::OperatingState::kEnabled || !state->drives_ready)
      return ApiResult::error(409, "not_enabled",
                              "robot '" + robot + "' must be enabled to run a trajectory");
    const bool variable = choice.value_or(robot_.snapshot().variable_diameter);
    c.id = static_cast<std::uint16_t>(MbcrCommand::circle_start);
    c.flag = variable ? 1 : 0;
    const double a_min = robot_.model().linkage().inner_radius_min();
    const double approach = robot_.approach_duration(
        robot_.snapshot(), variable ? a_min + robot_.settings().circle.start_offset : a_min);
    if (!post_(c)) return busy();
    return ApiResult::success({{"accepted", true},
                               {"name", "seed_circle"},
                               {"diameter", variable ? "variable" : "fixed"},
                               {"approach_s", approach},
                               {"duration_s", approach + robot_.settings().circle.period}},
                              202);
  }

  ApiResult diameter(const json& body) {
    ApiResult bad;
    if (!body.is_object() || !body.contains("mode"))
      return ApiResult::error(400, "bad_request", "expected {\"mode\": \"variable\" | \"fixed\"}");
    const auto choice = diameter_choice(body, "mode", bad);
    if (!bad.ok()) return bad;
    PluginCommand c;
    c.id = static_cast<std::uint16_t>(MbcrCommand::diameter);
    c.flag = *choice ? 1 : 0;
    if (!post_(c)) return busy();
    return ApiResult::success({{"accepted", true}, {"diameter", *choice ? "variable" : "fixed"}}, 202);
  }

  static ApiResult busy() {
    return ApiResult::error(503, "busy", "the control thread's command mailbox is full; try again");
  }

  MbcrRobot& robot_;
  RobotService& service_;
  std::function<bool(const PluginCommand&)> post_;
};

}  // namespace

std::unique_ptr<RobotApiExtension> make_mbcr_api(MbcrRobot& robot, RobotService& service,
                                                 std::function<bool(const PluginCommand&)> post) {
  return std::make_unique<MbcrApi>(robot, service, std::move(post));
}

}  // namespace tendril::server
