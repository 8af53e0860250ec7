// The serial arm's part of the network API (network threads): its fields of /robots and of
// operating_state, and the /{robot}/arm topic with the values that change with every reading. The
// Cartesian commands themselves are the core's CRTK endpoints (move_cp, servo_cp, servo_cv, measured_*),
// which reach the type through RobotPlugin::cartesian_command; the arm adds no commands of its own.
#include <cstdio>
#include <utility>

#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/server/robot_api_extension.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

json vec3(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

class SerialArmApi final : public RobotApiExtension {
 public:
  explicit SerialArmApi(SerialArm& robot) : robot_(robot) {}

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
    // The force and the simulated contact change with every reading: they go out on /{robot}/arm at
    // 10 Hz, so /{robot}/operating_state changes only with the state.
    return LiveState{"arm",
                     "tendril.ArmState",
                     10.0,
                     {"arm.force_n", "arm.contact_force_n", "arm.force_fresh", "arm.simulation",
                      "arm.twist_limited", "arm.workspace_limited"}};
  }

 private:
  SerialArm& robot_;
};

}  // namespace

std::unique_ptr<RobotApiExtension> make_serial_arm_api(SerialArm& robot) {
  return std::make_unique<SerialArmApi>(robot);
}

}  // namespace tendril::server
