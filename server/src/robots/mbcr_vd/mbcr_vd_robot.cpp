// The mbcr_vd robot type and the building of one robot: settings, model, the circle's start, the display
// model, and the network-thread side of its CRTK commands (checks and the move_cp goal's inverse
// kinematics). The control cycle is in mbcr_vd_controller.cpp, the API in mbcr_vd_api.cpp.
#include "mbcr_vd/mbcr_vd_robot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <stdexcept>
#include <utility>

#include "mbcr_vd/mbcr_vd_schema.hpp"
#include "tendril/server/config_reader.hpp"
#include "tendril/server/robot_api_extension.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {

namespace {

using detail::Reader;
using detail::vector3;

class MbcrType final : public RobotType {
 public:
  std::string kind() const override { return "mbcr_vd"; }
  std::string description() const override {
    return "variable-diameter multi-backbone continuum robot (Abah 2022, ch. 2): three segments, "
           "scissor-linkage "
           "disks, task-space control with gradient-projection redundancy resolution";
  }
  nlohmann::json settings_schema() const override {
    static const nlohmann::json schema = nlohmann::json::parse(schema_files::k_mbcr_vd);
    return schema;
  }
  std::unique_ptr<RobotPlugin> create(const RobotConfig& config, RobotAssembly& assembly) const override {
    return std::make_unique<MbcrRobot>(config, assembly);
  }
};

std::string format(const char* fmt, double a, double b = 0.0, double c = 0.0) {
  char buf[128];
  std::snprintf(buf, sizeof buf, fmt, a, b, c);
  return buf;
}

// How far the diameter joint's soft range may reach past the linkage's own [a_min, a_max]: the core's
// clamp must never stop a at a_min (the fixed-diameter baseline sits there), and a joint range much
// wider than the linkage would let joint mode ask for a diameter the disks cannot take.
constexpr double kDiameterRangeSlack = 0.05;  // mm

}  // namespace

void register_mbcr_vd(RobotTypes& types) { types.add(std::make_unique<MbcrType>()); }

const char* to_string(MbcrMotion motion) noexcept {
  switch (motion) {
    case MbcrMotion::none:
      return "none";
    case MbcrMotion::servo_cv:
      return "servo_cv";
    case MbcrMotion::move_cp:
      return "move_cp";
    case MbcrMotion::approach:
      return "approach";
    case MbcrMotion::circle:
      return "circle";
  }
  return "none";
}

MbcrSettings parse_mbcr_settings(const RobotConfig& rc) {
  const std::string file = rc.file.string();
  MbcrSettings s;
  if (rc.joints.size() != kMbcrJoints)
    throw ConfigError(file +
                      ": joints: expected 7 joints for a mbcr_vd (backbones 1 and 2 of segments 1-3, "
                      "then the diameter joint), got " +
                      std::to_string(rc.joints.size()));
  for (std::size_t i = 0; i < rc.joints.size(); ++i)
    if (rc.joints[i].unit() != "mm")
      throw ConfigError(file + ": joints[" + std::to_string(i) + "].unit: expected \"mm\", got \"" +
                        rc.joints[i].unit() + "\"");
  const nlohmann::json empty = nlohmann::json::object();
  const auto it = rc.settings.find("mbcr");
  const Reader m(it != rc.settings.end() ? *it : empty, file, "mbcr");
  auto& p = s.parameters;
  if (m.has("linkage")) {
    const Reader l = m.child("linkage");
    p.linkage.rhombus_count =
        static_cast<int>(l.integer_in_or("rhombus_count", 3, 64, p.linkage.rhombus_count));
    p.linkage.inner_arm_length = l.positive_or("arm_length_mm", p.linkage.inner_arm_length);
    p.linkage.outer_arm_length = p.linkage.inner_arm_length;  // l₂ = l₁, the dissertation's design rule
    p.linkage.hinge_diameter = l.positive_or("hinge_diameter_mm", p.linkage.hinge_diameter);
  }
  if (m.has("segments")) {
    const Reader g = m.child("segments");
    p.disks.segment_length = g.positive_or("length_mm", p.disks.segment_length);
    p.disks.disk_count = static_cast<int>(g.integer_in_or("disk_count", 2, 1000, p.disks.disk_count));
    p.disks.disk_height = g.positive_or("disk_height_mm", p.disks.disk_height);
  }
  if (m.has("backbone")) {
    const Reader b = m.child("backbone");
    p.backbone_diameter = b.positive_or("diameter_mm", p.backbone_diameter);
    p.youngs_modulus = b.positive_or("youngs_modulus_mpa", p.youngs_modulus);
  }
  if (m.has("redundancy")) {
    const Reader r = m.child("redundancy");
    p.redundancy.force_weight = r.non_negative_or("force_weight", p.redundancy.force_weight);
    p.redundancy.limit_weight = r.non_negative_or("limit_weight", p.redundancy.limit_weight);
    p.redundancy.step_gain = r.non_negative_or("step_gain", p.redundancy.step_gain);
    p.redundancy.max_diameter_rate = r.positive_or("max_diameter_rate_mm_s", p.redundancy.max_diameter_rate);
  }
  s.payload.head<3>() = vector3(m, "payload_n", Eigen::Vector3d(0.0, 0.0, -19.62));
  if (m.has("task")) {
    const Reader t = m.child("task");
    s.max_linear_speed = t.positive_or("max_linear_speed_mm_s", s.max_linear_speed);
    s.max_angular_speed = t.positive_or("max_angular_speed_rad_s", s.max_angular_speed);
    s.goal_tolerance_mm = t.positive_or("goal_tolerance_mm", s.goal_tolerance_mm);
    const std::string d = t.string_or("diameter", "variable");
    if (d != "variable" && d != "fixed") t.fail("diameter", "\"variable\" or \"fixed\"", t.raw("diameter"));
    s.variable_diameter = d == "variable";
  }
  if (m.has("circle")) {
    const Reader c = m.child("circle");
    s.circle.centre = vector3(c, "centre_mm", s.circle.centre);
    s.circle.radius = c.positive_or("radius_mm", s.circle.radius);
    s.circle.period = c.positive_or("period_s", s.circle.period);
    s.approach_speed = c.positive_or("approach_speed_mm_s", s.approach_speed);
  }
  s.circle.payload = s.payload;
  s.circle.dt = 1.0 / rc.control_rate_hz.value_or(1000.0);  // the controller steps at its own period

  // The backbones' limits are the file's soft limits (the tightest of the six): the redundancy
  // resolution keeps them where the core's clamp would, and never makes it act.
  p.backbone_lower = -1e300;
  p.backbone_upper = 1e300;
  for (std::size_t i = 0; i + 1 < kMbcrJoints; ++i) {
    const auto& j = rc.joints[i].limit;
    p.backbone_lower = std::max(p.backbone_lower, j.lower + j.soft_margin);
    p.backbone_upper = std::min(p.backbone_upper, j.upper - j.soft_margin);
  }
  return s;
}

teleop::StackConfiguration configuration_from_joints(const teleop::VariableDiameterRobot& model,
                                                     const double* q,
                                                     const teleop::StackConfiguration& previous) noexcept {
  teleop::StackConfiguration psi = previous;
  const double r = model.linkage().configuration_radius(q[6]);
  if (!std::isfinite(r) || r <= 0.0) return psi;
  for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k) {
    const double q1 = q[2 * k], q2 = q[2 * k + 1];
    const double magnitude = std::hypot(q1, q2) / r;
    if (magnitude < 1e-12) {
      psi[2 * k] = teleop::kStraightTangentAngle;
      continue;
    }
    // Θ·cos δ = q₁/r, Θ·sin δ = −q₂/r: with Θ = −m, δ = atan2(q₂, −q₁); with Θ = +m, δ = atan2(−q₂, q₁).
    const bool negative = previous[2 * k] - teleop::kStraightTangentAngle <= 0.0;
    psi[2 * k] = teleop::kStraightTangentAngle + (negative ? -magnitude : magnitude);
    psi[2 * k + 1] = negative ? std::atan2(q2, -q1) : std::atan2(-q2, q1);
  }
  return psi;
}

// ---- the display model ------------------------------------------------------------------------------

namespace {
constexpr int kDisplayPointsPerSegment = 12;
}

std::vector<Eigen::Vector3d> MbcrDisplayModel::shape(std::span<const double> q) const {
  std::vector<Eigen::Vector3d> points;
  if (q.size() != kMbcrJoints) return points;
  teleop::StackConfiguration straight;
  straight << teleop::kStraightTangentAngle, 0.0, teleop::kStraightTangentAngle, 0.0,
      teleop::kStraightTangentAngle, 0.0;
  const auto psi = configuration_from_joints(model_, q.data(), straight);
  const double length = model_.parameters().disks.segment_length;
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  points.push_back(base.translation());
  for (Eigen::Index k = 0; k < teleop::kVariableDiameterSegments; ++k) {
    const double bend = psi[2 * k] - teleop::kStraightTangentAngle;
    for (int i = 1; i <= kDisplayPointsPerSegment; ++i) {
      const double s = length * i / kDisplayPointsPerSegment;
      // A constant-curvature arc: the point at arc length s is the end of a segment of length s bent by
      // the same fraction.
      const teleop::SegmentConfiguration partial(teleop::kStraightTangentAngle + bend * s / length,
                                                 psi[2 * k + 1]);
      points.push_back((base * teleop::segment_end_pose(partial, s)).translation());
    }
    base = base * teleop::segment_end_pose(teleop::SegmentConfiguration(psi[2 * k], psi[2 * k + 1]), length);
  }
  return points;
}

Pose MbcrDisplayModel::tip(std::span<const double> q) const {
  Pose p;
  if (q.size() != kMbcrJoints) return p;
  teleop::StackConfiguration straight;
  straight << teleop::kStraightTangentAngle, 0.0, teleop::kStraightTangentAngle, 0.0,
      teleop::kStraightTangentAngle, 0.0;
  const auto psi = configuration_from_joints(model_, q.data(), straight);
  auto data = model_.make_data();
  const Eigen::Isometry3d tip = model_.tip_pose(psi, data);
  p.position = tip.translation();
  p.orientation = Eigen::Quaterniond(tip.linear());
  return p;
}

// ---- the robot --------------------------------------------------------------------------------------

MbcrRobot::MbcrRobot(const RobotConfig& rc, RobotAssembly& assembly)
    : config_(rc),
      settings_(parse_mbcr_settings(rc)),
      model_([&] {
        try {
          return teleop::VariableDiameterRobot(settings_.parameters);
        } catch (const std::invalid_argument& e) {
          throw ConfigError(rc.file.string() + ": mbcr: " + e.what());
        }
      }()),
      display_(model_, rc.name + "_base") {
  const std::string file = rc.file.string();
  (void)assembly;  // the joints are the core's CiA 402 drives (SIMULATED on a virtual bus)
  const auto& a = rc.joints[6].limit;
  const double a_min = model_.linkage().inner_radius_min(), a_max = model_.linkage().inner_radius_max();
  const double lo = a.lower + a.soft_margin, hi = a.upper - a.soft_margin;
  if (lo > a_min || lo < a_min - kDiameterRangeSlack || hi < a_max || hi > a_max + kDiameterRangeSlack)
    throw ConfigError(file +
                      ": joints[6]: expected the diameter joint's soft range (lower + soft_margin, upper - "
                      "soft_margin) to contain the linkage's range " +
                      format("[%.3f, %.3f] mm", a_min, a_max) + " and reach at most 0.05 mm past it, got " +
                      format("[%.3f, %.3f] mm", lo, hi));
  if (!(settings_.parameters.backbone_lower < 0.0 && settings_.parameters.backbone_upper > 0.0))
    throw ConfigError(file +
                      ": joints: expected the backbones' soft limits to contain 0 (the straight robot)");
  // The dissertation's circle starts on the hook branch (teleop/mbcr_vd/README.md: the branch whose diameter
  // history is the dissertation's).
  circle_start_ = teleop::circle_start_configuration(model_, settings_.circle, teleop::CircleBranch::kHook);
  auto data = model_.make_data();
  const double miss = (model_.tip_pose(circle_start_, data).translation() -
                       teleop::circle_pose(settings_.circle, 0.0).translation())
                          .norm();
  if (miss > settings_.goal_tolerance_mm)
    throw ConfigError(file + ": mbcr.circle: the circle's start is out of the robot's reach (" +
                      format("%.1f mm", miss) + " away at best)");
  MbcrSnapshot initial;
  initial.diameter_joint = rc.joints[6].initial_position;
  initial.variable_diameter = settings_.variable_diameter;
  for (std::size_t k = 0; k < 3; ++k) initial.configuration[2 * k] = teleop::kStraightTangentAngle;
  published_.store(initial);
}

MbcrRobot::~MbcrRobot() = default;

std::vector<ModeInfo> MbcrRobot::modes() const {
  return {{"task",
           "CRTK servo_cv and move_cp of the tip; the diameter moves in the task's null space to lower the "
           "actuation forces (gradient projection, Abah 2022, §2.7.1) or is held (fixed), and the trajectory "
           "command runs the circle of Abah 2022, §2.7.2"}};
}

double MbcrRobot::approach_duration(const MbcrSnapshot& from, double a_to) const noexcept {
  teleop::StackConfiguration psi;
  for (int i = 0; i < 6; ++i) psi[i] = from.configuration[static_cast<std::size_t>(i)];
  const auto q0 = model_.joints(psi, from.diameter_joint);
  const auto q1 = model_.joints(circle_start_, a_to);
  // A quintic's peak speed is 1.875 times its mean: the fastest joint stays at the approach speed.
  const double largest = (q1 - q0).cwiseAbs().maxCoeff();
  return std::max(1.0, 1.875 * largest / settings_.approach_speed);
}

Result<std::pair<PluginCommand, double>> MbcrRobot::cartesian_command(CartesianKind kind,
                                                                      const CartesianPose& pose,
                                                                      const CartesianTwist& twist,
                                                                      const OperatingStateView& state) const {
  static const char* names[] = {"move_cp", "servo_cp", "servo_cv"};
  const char* name = names[static_cast<int>(kind)];
  const std::string& robot = config_.name;
  if (kind == CartesianKind::servo_cp)
    return ServiceError{ErrorKind::invalid, "not_supported",
                        "servo_cp: robot '" + robot + "' (mbcr_vd) takes servo_cv and move_cp in task mode"};
  if (state.mode != "task")
    return ServiceError{ErrorKind::conflict, "wrong_mode",
                        "robot '" + robot + "' is in " + state.mode +
                            " mode; switch to task mode (POST /api/v1/robots/" + robot +
                            "/mode {\"mode\": \"task\"}) for " + name};
  PluginCommand c;
  if (kind == CartesianKind::servo_cv) {
    if (!twist.linear.allFinite() || !twist.angular.allFinite())
      return ServiceError{ErrorKind::invalid, "bad_twist", "servo_cv: the twist must be finite"};
    c.id = static_cast<std::uint16_t>(MbcrCommand::servo_cv);
    c.count = 6;
    // Over the caps: scaled down as a whole, so the direction stays the operator's.
    double scale = 1.0;
    const double v = twist.linear.norm(), w = twist.angular.norm();
    if (v > settings_.max_linear_speed) scale = std::min(scale, settings_.max_linear_speed / v);
    if (w > settings_.max_angular_speed) scale = std::min(scale, settings_.max_angular_speed / w);
    for (Eigen::Index i = 0; i < 3; ++i) {
      c.values[static_cast<std::size_t>(i)] = scale * twist.linear[i];
      c.values[static_cast<std::size_t>(i) + 3] = scale * twist.angular[i];
    }
    c.flag = scale < 1.0 ? 1 : 0;
    return std::pair{c, 0.0};
  }
  const Eigen::Vector3d& p = pose.position;
  if (!p.allFinite() || !pose.orientation.coeffs().allFinite() || pose.orientation.norm() < 1e-6)
    return ServiceError{ErrorKind::invalid, "bad_pose",
                        "move_cp: the pose must be finite with a non-zero quaternion"};
  Eigen::Isometry3d goal = Eigen::Isometry3d::Identity();
  goal.translation() = p;
  goal.linear() = pose.orientation.normalized().toRotationMatrix();
  const double reach = 3.0 * settings_.parameters.disks.segment_length;
  if (p.norm() > reach)
    return ServiceError{ErrorKind::invalid, "unreachable",
                        "move_cp: the goal " + format("(%.1f, %.1f, %.1f) mm", p.x(), p.y(), p.z()) +
                            " is farther from the base than the robot's length " + format("%.0f mm", reach)};
  // The goal's inverse kinematics from the setpoint's configuration: a goal the model cannot reach,
  // or reaches only with a backbone outside its limits or disks that must touch, is refused.
  const auto s = published_.load();
  teleop::StackConfiguration psi;
  for (int i = 0; i < 6; ++i) psi[i] = s.configuration[static_cast<std::size_t>(i)];
  auto data = model_.make_data();
  const Eigen::Isometry3d start = model_.tip_pose(psi, data);
  const double miss = teleop::solve_tip_pose(model_, goal, psi);
  model_.tip_pose(psi, data);
  const double angle = Eigen::AngleAxisd(data.frames[3].linear().transpose() * goal.linear()).angle();
  if (!(miss <= settings_.goal_tolerance_mm) || !(angle <= settings_.goal_tolerance_rad))
    return ServiceError{ErrorKind::invalid, "unreachable",
                        "move_cp: the robot cannot reach the goal: the nearest pose the model finds is " +
                            format("%.1f mm and %.3f rad from it", miss, angle)};
  const auto q = model_.joints(psi, s.diameter_joint);
  const auto& p_lim = settings_.parameters;
  for (int i = 0; i < 6; ++i)
    if (q[i] < p_lim.backbone_lower || q[i] > p_lim.backbone_upper)
      return ServiceError{
          ErrorKind::invalid, "out_of_limits",
          "move_cp: at the goal joint '" + config_.joints[static_cast<std::size_t>(i)].name() +
              "' would be at " +
              format("%.1f mm, outside [%.1f, %.1f] mm", q[i], p_lim.backbone_lower, p_lim.backbone_upper)};
  if (model_.diameter_limits(psi).interference_unavoidable)
    return ServiceError{
        ErrorKind::invalid, "interference",
        "move_cp: at the goal the segments bend so far that neighbouring disks touch at every "
        "diameter; choose a goal with less bending"};
  // Duration: a quintic along the line and the rotation, peak speeds within the caps.
  const double distance = (p - start.translation()).norm();
  const double turn = Eigen::AngleAxisd(start.linear().transpose() * goal.linear()).angle();
  const double duration = std::max(
      {0.5, 1.875 * distance / settings_.max_linear_speed, 1.875 * turn / settings_.max_angular_speed});
  const Eigen::Quaterniond o(goal.linear());
  c.id = static_cast<std::uint16_t>(MbcrCommand::move_cp);
  c.values = {p.x(), p.y(), p.z(), o.x(), o.y(), o.z(), o.w(), duration};
  c.count = 8;
  return std::pair{c, duration};
}

std::unique_ptr<RobotApiExtension> MbcrRobot::api(RobotService& service,
                                                  std::function<bool(const PluginCommand&)> post) {
  return make_mbcr_api(*this, service, std::move(post));
}

}  // namespace tendril::server
