// The variable-diameter multi-backbone continuum robot (MBCR, Abah 2022, ch. 2) as a robot type
// ("mbcr_vd"): three segments on twelve push-pull backbones, spacer disks that are angulated scissor
// linkages (ASL), so the robot's diameter is a seventh joint. The kinematics, statics and redundancy
// resolution are the library's (teleop/variable_diameter_*.hpp); this plug-in puts them on the control
// thread.
//
// Joints (mm, in the robot file's order): backbones 1 and 2 of segments 1, 2, 3 (backbones 3 and 4 of a
// segment are their mirror images, q₃ = −q₁, q₄ = −q₂, and are driven with them) and the diameter joint
// a, the linkages' inner radius, shared by every disk. They are CiA 402 drives on the robot's CAN bus
// (the core builds them from the file); on a virtual bus they are SIMULATED lead-screw axes.
//
// Modes: the core's joint mode, and "task": CRTK servo_cv and move_cp of the tip, resolved on the
// control thread by the library's closed-loop resolved rates plus gradient projection — the diameter
// moves in the null space of the task to lower ‖τ̃_s‖ within the joint limits and the disk-interference
// limit (variable diameter), or is held (fixed diameter, the dissertation's baseline). The command
// `trajectory` runs the dissertation's circle (§2.7.2) as the task reference, so its result shows live.
//
// How the task mode moves the robot: the controller keeps the configuration ψ_s and a of the setpoint
// (a kinematic reference), steps it with the library and writes q_des = q̃(ψ_s, a); the core's joint
// loop makes the drives follow, so its limit clamp, tracking-error fault and e-stop apply unchanged.
//
// Threads: the control thread runs MbcrController and publishes MbcrSnapshot; network threads read
// the immutable model and settings and the published snapshot (mbcr_vd_api.cpp).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/server/robot_type.hpp"
#include "tendril/teleop/variable_diameter_robot.hpp"
#include "tendril/teleop/variable_diameter_simulation.hpp"

namespace tendril::server {

class MbcrRobot;

inline constexpr std::size_t kMbcrJoints = 7;
inline constexpr std::size_t kMbcrBackbones = 12;
inline constexpr ModeId kTaskMode = kFirstPluginMode;

// PluginCommand::id of the type's commands.
enum class MbcrCommand : std::uint16_t { servo_cv, move_cp, circle_start, circle_stop, diameter };

// What the task-space controller is doing.
enum class MbcrMotion : std::uint8_t { none, servo_cv, move_cp, approach, circle };
const char* to_string(MbcrMotion motion) noexcept;

struct MbcrSettings {
  teleop::VariableDiameterRobotParameters parameters;  // backbone limits from the file's joints
  teleop::CircleTrajectoryParameters circle;           // payload = the tip load below
  teleop::Wrench payload = teleop::Wrench::Zero();     // tip wrench the actuation forces carry
  double max_linear_speed = 30.0;  // mm/s: servo_cv is capped to it, move_cp plans with it
  double max_angular_speed = 0.3;  // rad/s
  double goal_tolerance_mm = 1.0;
  double goal_tolerance_rad = 0.01;
  bool variable_diameter = true;  // the task mode's redundancy resolution at start
  double approach_speed = 20.0;   // mm/s of the fastest joint on the way to the circle's start
};

// Parses the robot file's "mbcr" section and checks it against the joints (throws ConfigError naming
// the file and the key).
MbcrSettings parse_mbcr_settings(const RobotConfig& config);

// q̃ → (ψ_s, a): per segment Θ·cos δ = q₁/r and Θ·sin δ = −q₂/r (2.19). (Θ, δ) and (−Θ, δ + π) are the
// same shape; the sign of Θ follows `previous` so that the reference does not flip. A straight segment
// keeps previous's δ. Allocation-free.
teleop::StackConfiguration configuration_from_joints(const teleop::VariableDiameterRobot& model,
                                                     const double* q,
                                                     const teleop::StackConfiguration& previous) noexcept;

// What the control thread publishes for the API (trivially copyable).
struct MbcrSnapshot {
  std::uint64_t tick = 0;
  std::array<double, 6> configuration{};  // ψ_s of the setpoint
  double diameter_joint = 0.0;            // a (mm)
  double outer_diameter = 0.0;            // 2·b(r(a)) (mm): the robot's diameter
  MbcrMotion motion = MbcrMotion::none;
  bool variable_diameter = true;  // the current task motion's (or the next one's) resolution
  // Actuation at the setpoint under the payload (N), every 10th tick.
  std::array<double, kMbcrBackbones> backbone_forces{};
  double diameter_force = 0.0;
  double force_norm = 0.0;      // ‖τ̃_s‖
  double force_gradient = 0.0;  // ∂‖τ̃_s‖/∂a of the last step (N/mm)
  double tracking_error = 0.0;  // mm, last step
  teleop::DiameterLimits limits{};
  double interference_margin = 0.0;  // min over segments of b_lim − b (mm); +inf when all are straight
  bool interference_unavoidable = false;
  bool diameter_at_limit = false;     // a within 0.01 mm of a limit
  bool backbone_limited = false;      // the last task step stopped at a backbone limit
  bool interference_limited = false;  // the last task step stopped before unavoidable interference
  // The reference circle: progress, and the RMS of ‖τ̃_s‖ over its samples so far and of the last runs.
  std::uint32_t circle_index = 0;  // samples taken in the current run
  std::uint32_t circle_samples = 0;
  double circle_sample_force = 0.0;  // ‖τ̃_s‖ of the sample circle_index − 1 (as the library records it)
  double circle_rms = 0.0;
  std::uint32_t circle_unavoidable_steps = 0;
  double last_rms_variable = -1.0;  // −1: no run yet
  double last_rms_fixed = -1.0;
  double motion_duration = 0.0;  // s of the current move_cp / approach + circle
};

class MbcrController final : public RobotController {
 public:
  explicit MbcrController(MbcrRobot& robot);
  void control(ControlContext& ctx) noexcept override;
  void apply(ControlContext& ctx, const PluginCommand& command) noexcept override;
  void reset(ControlContext& ctx) noexcept override;
  void operator_lost(ControlContext& ctx) noexcept override;
  bool moving(const ControlContext& ctx) const noexcept override;
  void publish(const ControlContext& ctx) noexcept override;

 private:
  void stop(ControlContext& ctx) noexcept;
  void sync_from_setpoint(const ControlContext& ctx) noexcept;
  // Steps the state towards (target, twist); the step is kept only when the backbones stay within their
  // limits and (guard) no unavoidable interference is entered with the bend growing. Writes q_des.
  bool task_step(ControlContext& ctx, const Eigen::Isometry3d& target, const teleop::StackTwist& twist,
                 bool guard) noexcept;
  void write_setpoint(ControlContext& ctx, const teleop::StackJoints& before) noexcept;

  MbcrRobot& robot_;
  teleop::VariableDiameterData data_;
  teleop::VariableDiameterData probe_;
  teleop::VariableDiameterState state_{};
  teleop::VariableDiameterStepReport report_{};
  MbcrMotion motion_ = MbcrMotion::none;
  bool variable_ = true;         // the task mode's choice (diameter command)
  bool motion_variable_ = true;  // the running motion's
  // servo_cv
  teleop::StackTwist twist_ = teleop::StackTwist::Zero();
  Eigen::Isometry3d target_ = Eigen::Isometry3d::Identity();
  double last_stream_ = 0.0;
  // move_cp: quintic along the line and the rotation
  Eigen::Isometry3d move_start_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d move_goal_ = Eigen::Isometry3d::Identity();
  Eigen::AngleAxisd move_rotation_{};
  double move_t0_ = 0.0, move_duration_ = 0.0;
  // approach to the circle's start (ψ and a interpolated with a quintic)
  teleop::StackConfiguration approach_from_ = teleop::StackConfiguration::Zero();
  double approach_a_from_ = 0.0, approach_a_to_ = 0.0;
  double approach_t0_ = 0.0, approach_duration_ = 0.0;
  // the circle
  std::uint32_t circle_index_ = 0, circle_samples_ = 0, circle_unavoidable_ = 0;
  double circle_sum_sq_ = 0.0, circle_sample_force_ = 0.0;
  double last_rms_variable_ = -1.0, last_rms_fixed_ = -1.0;
  // published values
  teleop::StackActuation actuation_ = teleop::StackActuation::Zero();
  double force_norm_ = 0.0;
  bool backbone_limited_ = false, interference_limited_ = false;
  std::uint64_t ticks_ = 0;
};

// The backbone's shape for display: points along every segment's constant-curvature arc (mm).
class MbcrDisplayModel final : public RobotKinematics {
 public:
  MbcrDisplayModel(const teleop::VariableDiameterRobot& model, std::string frame)
      : model_(model), frame_(std::move(frame)) {}
  std::string frame() const override { return frame_; }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override;
  Pose tip(std::span<const double> q) const override;

 private:
  const teleop::VariableDiameterRobot& model_;
  std::string frame_;
};

class MbcrRobot final : public RobotPlugin {
 public:
  // Parses the settings, builds the model and finds the circle's start (hook branch). Throws ConfigError.
  MbcrRobot(const RobotConfig& config, RobotAssembly& assembly);
  ~MbcrRobot() override;

  const RobotKinematics& kinematics() const override { return display_; }
  std::vector<ModeInfo> modes() const override;
  RobotController& controller() override { return controller_; }
  bool cartesian() const override { return true; }
  Result<std::pair<PluginCommand, double>> cartesian_command(CartesianKind kind, const CartesianPose& pose,
                                                             const CartesianTwist& twist,
                                                             const OperatingStateView& state) const override;
  std::unique_ptr<RobotApiExtension> api(RobotService& service,
                                         std::function<bool(const PluginCommand&)> post) override;

  const RobotConfig& config() const noexcept { return config_; }
  const MbcrSettings& settings() const noexcept { return settings_; }
  const teleop::VariableDiameterRobot& model() const noexcept { return model_; }
  MbcrSnapshot snapshot() const noexcept { return published_.load(); }
  // The circle's start configuration (hook branch, Abah 2022, §2.7.2) and its approach time from the
  // setpoint.
  const teleop::StackConfiguration& circle_start() const noexcept { return circle_start_; }
  double approach_duration(const MbcrSnapshot& from, double a_to) const noexcept;

 private:
  friend class MbcrController;
  RobotConfig config_;
  MbcrSettings settings_;
  teleop::VariableDiameterRobot model_;
  MbcrDisplayModel display_;
  teleop::StackConfiguration circle_start_ = teleop::StackConfiguration::Zero();
  MbcrController controller_{*this};
  hardware::LatestValue<MbcrSnapshot> published_;
};

std::unique_ptr<RobotApiExtension> make_mbcr_api(MbcrRobot& robot, RobotService& service,
                                                 std::function<bool(const PluginCommand&)> post);

}  // namespace tendril::server
