// A six-joint serial arm (UR5 geometry, the ultrasound arm of Heunis et al. 2021) as a robot type
// ("serial_arm"): joint mode from the core (move_jp, servo_jv in rad), a "cartesian" mode with CRTK move_cp,
// servo_cp and servo_cv resolved through the damped inverse of Heunis et al. 2021, Appendix A
// (teleop::CartesianControl), the tool's measured_cp / measured_cv from the kinematics and measured_cf from a
// 3-axis force sensor, with the article's hard limits: contact force ≤ F_max, force data stale > 20 ms, a
// workspace box.
//
// Hardware: the joints are velocity-commanded through a hardware::JointInterface the type provides
// (RobotAssembly::provide_joints), the force sensor is a hardware::ForceSensor. A real UR5 is commanded
// over Ethernet with RTDE (Universal Robots' real-time data exchange), not CAN: its driver would sit at
// exactly these two interfaces. tendril has no RTDE driver yet, so a robot file must ask for the
// SIMULATED arm (sim::SimulatedVelocityArm), force sensor (sim::SimulatedForceSensor) and tissue
// (sim::ContactSurface) in its "arm.simulation" section; without it the file is refused.
//
// Units: joints in rad (rad/s, rad/s²) as the file's joints say; Cartesian positions in mm, twists in
// mm/s and rad/s, forces in N — the units of tendril's Cartesian API (measured_cp, move_cp) and of the
// teleop arm libraries. Nothing here is converted by the core.
//
// How the Cartesian modes move the arm: the controller integrates the joint setpoint q_des through the
// damped inverse (the Cartesian law runs on the setpoint, a kinematic reference), and the core's joint
// loop makes the velocity-commanded joints track that setpoint (velocity = q̇_des + k·(q_des − q)), so
// the core's tracking-error, limit clamping and stall policies apply to Cartesian motion unchanged.
//
// Threads: the control thread runs SerialArmController and publishes ArmSnapshot; network threads
// read the immutable model and settings and the published snapshot (serial_arm_api.cpp).
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "serial_arm/calibration_motion.hpp"
#include "serial_arm/calibration_runner.hpp"
#include "serial_arm/calibration_store.hpp"
#include "serial_arm/limb_simulation.hpp"
#include "serial_arm/ultrasound_calibrations.hpp"
#include "serial_arm/ultrasound_probe_state.hpp"
#include "serial_arm/ultrasound_sweep.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/hardware/sensor_interfaces.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/drivers/sim/simulated_force_sensor.hpp"
#include "tendril/drivers/sim/simulated_velocity_arm.hpp"
#include "tendril/server/robot_type.hpp"
#include "tendril/teleop/cartesian_control.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::server {

class SerialArm;

// The type's mode, after the core's joint (and path_following, which the arm does not offer).
inline constexpr ModeId kCartesianMode = kFirstPluginMode;
// The ultrasound sweep (robot files with an "ultrasound" section only).
inline constexpr ModeId kSweepMode = kFirstPluginMode + 1;

// PluginCommand::id of the Cartesian commands.
// sweep_load: the plan is in SerialArm's plan slot; sweep_action: values[0] is a SweepAction;
// calibration_start: the robot calibration's poses are in SerialArm's poses slot, values[0] is the run;
// calibration_abort: ends a running routine.
enum class ArmCommand : std::uint16_t {
  move_cp,
  servo_cp,
  servo_cv,
  sweep_load,
  sweep_action,
  calibration_start,
  calibration_abort
};

// What the Cartesian controller is doing.
enum class ArmMotion : std::uint8_t { none, move_cp, servo_cp, servo_cv };
const char* to_string(ArmMotion motion) noexcept;

struct ArmSettings {
  std::string model = "ur5";
  teleop::SerialArmParameters parameters;  // DH and tool from the model, limits from the file's joints
  teleop::CartesianLimits cartesian;   // the V_d of Heunis et al. 2021, Table 1, ω_d; move_cp accelerations
  teleop::TaskSpaceGains gains;        // the pose law of servo_cp and move_cp (A2–A9)
  double servo_cp_max_step_mm = 20.0;  // a servo_cp goal farther from the setpoint is refused
  double servo_cp_max_step_rad = 0.2;
  double goal_tolerance_mm = 1.0;  // move_cp: a dry run must end this close to the goal
  double goal_tolerance_rad = 0.01;
  Eigen::Vector3d workspace_min = Eigen::Vector3d::Constant(-1e9);  // mm, base frame
  Eigen::Vector3d workspace_max = Eigen::Vector3d::Constant(1e9);
  // Hard limits: force data stale > 20 ms, contact force > F_max (3 N) hold the arm; retraction at ≤ 10 mm/s:
  // the way out of a force hold retracts along the contact force at ≤ 10 mm/s.
  double force_stale_s = 0.020;
  double max_contact_force_n = 3.0;
  double resume_contact_force_n = 1.5;  // resume is allowed below this
  double retract_speed_mm_s = 10.0;
  double retract_max_mm = 30.0;  // a retraction that has not relieved the force by then stops
  // The SIMULATED hardware (required: there is no RTDE driver).
  sim::SimulatedVelocityArmParameters simulated_arm;
  sim::SimulatedForceSensorParameters simulated_sensor;
  std::optional<sim::ContactSurfaceParameters> surface;  // none: free space
};

// Parses the robot file's "arm" section and checks it against its joints (throws ConfigError naming the
// file and the key).
ArmSettings parse_arm_settings(const RobotConfig& config);

// What the control thread publishes every tick for the API (trivially copyable).
struct ArmSnapshot {
  std::uint64_t tick = 0;
  std::array<double, 6> setpoint{};  // q_des (rad)
  std::array<double, 3> force_n{};   // last valid reading, sensor (tool) frame
  bool force_valid = false;          // a reading has arrived
  bool force_fresh = false;          // and it is at most force_stale_s old
  double force_age_s = 0.0;
  ArmMotion motion = ArmMotion::none;
  std::array<double, 7> goal{};  // move_cp / servo_cp goal: x, y, z (mm), qx, qy, qz, qw
  bool twist_limited = false;    // the last Cartesian command was capped (speed or joint limits)
  bool workspace_limited = false;
  bool force_hold = false;  // held because the contact force exceeded F_max
  bool retracting = false;  // the way out of a force hold is running
};

// The type's part of the control cycle (control thread only).
class SerialArmController final : public RobotController {
 public:
  explicit SerialArmController(SerialArm& robot);
  void sense(ControlContext& ctx) noexcept override;
  void control(ControlContext& ctx) noexcept override;
  bool while_held(ControlContext& ctx) noexcept override;
  void apply(ControlContext& ctx, const PluginCommand& command) noexcept override;
  void delay(ControlContext& ctx, double lost) noexcept override;
  void reset(ControlContext& ctx) noexcept override;
  void state_command(ControlContext& ctx, safety::StateCommand command) noexcept override;
  void operator_lost(ControlContext& ctx) noexcept override;
  bool moving(const ControlContext& ctx) const noexcept override;
  bool hold_cleared(const ControlContext& ctx, char* why, std::size_t why_size) const noexcept override;
  void hold_ended(ControlContext& ctx) noexcept override;
  void publish(const ControlContext& ctx) noexcept override;

 private:
  // Integrates q_des by the joint velocities of `result` over one period, unless the tool would leave
  // the workspace box (then the setpoint stays).
  void integrate(ControlContext& ctx, const teleop::CartesianCommandResult& result) noexcept;
  void stop(ControlContext& ctx) noexcept;
  void sweep(ControlContext& ctx) noexcept;                        // mode sweep
  Eigen::Vector3d force_base(const ControlContext& ctx) noexcept;  // the reading in the base frame
  void calibrate(ControlContext& ctx) noexcept;                    // the robot calibration's motion
  // The tracked limb in the base frame: the tracker's limb pose in {G} through the calibrated H_B^G
  // (before any calibration the limb tracker's own base-frame pose).
  Eigen::Isometry3d limb_in_base(const LimbPoseSample& limb) const noexcept;

  SerialArm& robot_;
  teleop::SerialArmData data_;   // workspace of the setpoint's kinematics
  teleop::SerialArmData probe_;  // workspace of the workspace check and the force's frame
  teleop::ArmVector q_ = teleop::ArmVector::Zero();
  ArmMotion motion_ = ArmMotion::none;
  teleop::CartesianTrajectory trajectory_;
  double trajectory_delay_ = 0.0;  // s the move waited out in stalls
  Eigen::Isometry3d goal_ = Eigen::Isometry3d::Identity();
  teleop::Twist twist_ = teleop::Twist::Zero();
  double last_stream_ = 0.0;  // control time of the last servo_cp / servo_cv
  hardware::ForceReading force_{};
  bool force_fresh_ = false;
  double force_age_s_ = 0.0;
  bool twist_limited_ = false;
  bool workspace_limited_ = false;
  bool force_hold_ = false;
  bool retracting_ = false;
  double retracted_mm_ = 0.0;
  std::uint64_t ticks_ = 0;  // publish() calls: the probe state's tick
  // H_B^G of the calibration in use (calibration_load), and whether there is one.
  Eigen::Isometry3d global_T_base_ = Eigen::Isometry3d::Identity();
  bool base_calibrated_ = false;
  bool pairs_published_ = false;  // the calibration run's pairs are in SerialArm's slot
};

// The tool's kinematics for the API: pose, twist, and a polyline through the joint frames (mm).
class ArmDisplayModel final : public RobotKinematics {
 public:
  ArmDisplayModel(const teleop::SerialArmKinematics& model, std::string frame)
      : model_(model), frame_(std::move(frame)) {}
  std::string frame() const override { return frame_; }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override;
  Pose tip(std::span<const double> q) const override;

 private:
  const teleop::SerialArmKinematics& model_;
  std::string frame_;
};

class SerialArm final : public RobotPlugin {
 public:
  // Parses and checks the arm settings, builds the model, the controller and the SIMULATED arm, force
  // sensor and tissue. Throws ConfigError naming the file and the key.
  SerialArm(const RobotConfig& config, RobotAssembly& assembly);
  ~SerialArm() override;

  const RobotKinematics& kinematics() const override { return display_; }
  std::vector<ModeInfo> modes() const override;
  RobotController& controller() override { return controller_; }
  bool cartesian() const override { return true; }
  Result<std::pair<PluginCommand, double>> cartesian_command(CartesianKind kind, const CartesianPose& pose,
                                                             const CartesianTwist& twist,
                                                             const OperatingStateView& state) const override;
  std::optional<CartesianTwist> measured_cv(std::span<const double> q,
                                            std::span<const double> qd) const override;
  std::optional<Eigen::Vector3d> measured_cf() const override;
  std::optional<ServiceError> resume_refusal(const OperatingStateView& state) const override;
  std::unique_ptr<RobotApiExtension> api(RobotService& service,
                                         std::function<bool(const PluginCommand&)> post) override;
  // The ultrasound imaging and reconstruction topics (ultrasound_topics.hpp); none without "ultrasound".
  std::vector<std::shared_ptr<TopicSource>> topic_sources() override;

  // The ultrasound sweep (nullopt / null without the file's "ultrasound" section).
  const std::optional<UltrasoundSettings>& ultrasound() const noexcept { return ultrasound_; }
  const LimbSimulation* limb() const noexcept { return limb_.get(); }
  SweepSnapshot sweep_snapshot() const noexcept { return sweep_published_.load(); }
  // The latest plan (network threads; null before the first). Its via-points are in the limb frame.
  std::shared_ptr<const SweepPlan> sweep_plan() const {
    std::lock_guard lock(plan_mutex_);
    return plan_;
  }
  // Stores a new plan and hands its via-points to the control thread's slot (network thread).
  void set_sweep_plan(std::shared_ptr<const SweepPlan> plan);

  // The calibrations (null without the "ultrasound" section): the store, the routines and their state.
  // The "us" and "catheter" calibrations (ultrasound_calibrations.hpp); null without "ultrasound".
  const UltrasoundCalibrations* ultrasound_calibrations() const noexcept { return us_calibrations_.get(); }
  CalibrationRunner* calibrations() noexcept { return runner_.get(); }
  const CalibrationRunner* calibrations() const noexcept { return runner_.get(); }
  CalibrationSnapshot calibration_snapshot() const noexcept { return calibration_published_.load(); }
  // The SIMULATED optical tracker's settings (the true H_B^G and X); null without "ultrasound".
  const OpticalTrackerSettings* tracker_settings() const noexcept {
    return tracker_settings_ ? &*tracker_settings_ : nullptr;
  }
  // SIMULATED: hides the probe's marker from the tracker (its samples stop), for tests.
  void set_marker_hidden(bool hidden) noexcept { marker_hidden_.store(hidden); }
  // The robot calibration in use's H_B^G (any thread; nullopt before one).
  std::optional<Eigen::Isometry3d> calibrated_global_T_base() const noexcept {
    const auto b = base_calibration_.load();
    if (!b.valid) return std::nullopt;
    return to_isometry(b.global_T_base);
  }
  // Hands the robot calibration in use (its H_B^G) to the control thread's slot (network threads).
  void publish_calibration_in_use();

  const RobotConfig& config() const noexcept { return config_; }
  const ArmSettings& settings() const noexcept { return settings_; }
  const teleop::SerialArmKinematics& model() const noexcept { return model_; }
  ArmSnapshot snapshot() const noexcept { return published_.load(); }
  // The probe and limb poses of the latest control tick (any thread; a seqlock read, never a lock).
  UltrasoundProbeState probe_state() const noexcept { return to_state(probe_published_.load()); }
  // The SIMULATED devices (for tests and the API's ground truth).
  sim::SimulatedVelocityArm& simulated_arm() noexcept { return *arm_; }
  sim::SimulatedForceSensor& simulated_force_sensor() noexcept { return *sensor_; }
  sim::ContactSurface* contact_surface() noexcept { return surface_.get(); }
  const sim::SimulatedForceSensor& simulated_force_sensor() const noexcept { return *sensor_; }

 private:
  friend class SerialArmController;
  // Plans move_cp from the published setpoint and runs it kinematically (the damped inverse, the joint
  // limits) to see that it ends at the goal: nullopt when it does, else why not.
  std::optional<ServiceError> dry_run(const Eigen::Isometry3d& start, const teleop::ArmVector& q0,
                                      const Eigen::Isometry3d& goal, double& duration) const;

  // The "robot" kind's routine (network thread): checks, chooses the poses, starts the motion and the
  // worker that solves and saves.
  void set_up_calibrations();  // constructor, with "ultrasound"
  std::optional<std::string> start_robot_calibration(const OperatingStateView& state);
  void robot_calibration_worker(std::uint32_t run);

  RobotConfig config_;
  ArmSettings settings_;
  std::optional<UltrasoundSettings> ultrasound_;
  teleop::SerialArmKinematics model_;
  ArmDisplayModel display_;
  std::unique_ptr<LimbSimulation> limb_;          // before surface_: its height map outlives the surface
  std::unique_ptr<sim::ContactSurface> surface_;  // owned here: outlives the sensor (runtime-owned)
  sim::SimulatedVelocityArm* arm_ = nullptr;      // owned by the runtime (add_component)
  sim::SimulatedForceSensor* sensor_ = nullptr;   // owned by the runtime (add_component_in_control_thread)
  std::string sensor_name_;  // its name, for the stale-sensor hold's text (no allocation in the cycle)
  SerialArmController controller_{*this};
  hardware::LatestValue<ArmSnapshot> published_;
  hardware::LatestValue<UltrasoundProbeSample> probe_published_;
  std::unique_ptr<UltrasoundSweep> sweep_;  // control thread only
  hardware::LatestValue<SweepPlanData> plan_slot_;
  hardware::LatestValue<SweepSnapshot> sweep_published_;
  mutable std::mutex plan_mutex_;  // network threads only
  std::shared_ptr<const SweepPlan> plan_;
  // Calibrations (with "ultrasound" only).
  std::optional<OpticalTrackerSettings> tracker_settings_;
  std::unique_ptr<SimulatedOpticalTracker> tracker_;               // control thread only
  std::unique_ptr<CalibrationMotion> calibration_motion_;          // control thread only
  hardware::LatestValue<CalibrationPosesData> calibration_poses_;  // network → control thread
  hardware::LatestValue<CalibrationSnapshot> calibration_published_;
  hardware::LatestValue<CalibrationPairsData> calibration_pairs_;  // control → worker, once per run
  struct BaseCalibration {                                         // trivially copyable
    bool valid = false;
    std::array<double, 16> global_T_base{};  // column-major
  };
  // network → control thread (writers: worker_mutex_)
  hardware::LatestValue<BaseCalibration> base_calibration_;
  std::atomic<bool> marker_hidden_{false};
  std::unique_ptr<CalibrationStore> store_;
  std::unique_ptr<CalibrationRunner> runner_;
  std::unique_ptr<UltrasoundCalibrations> us_calibrations_;  // after runner_: its worker ends first
  std::function<bool(const PluginCommand&)> post_;           // the control thread's mailbox (set by api())
  std::mutex worker_mutex_;                                  // guards worker_ and run_
  std::thread worker_;
  std::uint32_t run_ = 0;
  std::atomic<bool> stopping_{false};
};

// The type's part of the network API (serial_arm_api.cpp).
std::unique_ptr<RobotApiExtension> make_serial_arm_api(SerialArm& robot, RobotService& service,
                                                       std::function<bool(const PluginCommand&)> post);

}  // namespace tendril::server
