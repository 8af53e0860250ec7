// The ultrasound sweep of the serial arm (robot "us_arm", issue 17, Heunis et al. 2021, §2.4, §3.1 and
// Appendix A): a robot file's optional "ultrasound" section adds the SIMULATED limb (limb_simulation.hpp),
// the plan (Algorithms 1–2 and ICP, made on a network thread) and the mode "sweep", whose controller runs on
// the control thread:
//
//   idle → planned → pre_positioning → ready → approaching → acquiring → moving → acquiring … → done
//                       (pause: paused, start continues; abort: aborted, after a retraction)
//
//  * pre_positioning / ready: the probe goes to `approach_height` above via-point 0 along its normal and
//    follows it there (pose control only, the force phase disabled) until start;
//  * approaching: the HybridPositionForceController (App. A) brings the probe down onto via-point 0 —
//    position control, then the explicit force law A10 on 0.8 N, without overshoot;
//  * acquiring: the acquisition gate is open (|E_∥| < 0.5 mm, E_θ < 0.01 rad, |F_n − d_f| ≤ 0.1 N for
//    100 ms); the gate must stay open for `acquire_time` (the slice is taken then), after which the sweep
//    moves on;
//  * moving: to the next via-point, in the force phase (the probe slides on the skin);
//  * paused: the probe stays in contact on the current via-point at the force target, following the
//    limb, and acquires nothing (our choice: lifting off and landing again would cost the approach
//    time and the images' continuity; abort is the way off the skin); start continues;
//  * done / aborted: the probe retracts along the via-point's normal (out of the skin) at
//    `retract_speed` (≤ 10 mm/s) for `retract_distance`, then holds still.
// A hold of the robot (force sensor lost, F_max, a limit) or a mode switch turns a running sweep into
// paused: after resume, start continues it.
//
// Motion compensation: every cycle each target is re-expressed from the limb's tracked pose,
// H_i^B(t) = H_P^B(t) · H_i^P (the form of Heunis et al. 2021, §3.1; world = the arm's base frame), with the
// pose the SIMULATED 120 Hz tracker reported last.
#pragma once

#include <array>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "serial_arm/limb_simulation.hpp"
#include "tendril/server/config.hpp"
#include "tendril/teleop/cartesian_control.hpp"
#include "tendril/teleop/hybrid_force_controller.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::server {

inline constexpr int kMaxViaPoints = 64;

struct UltrasoundSettings {
  LimbParameters limb;
  // Planning (Algorithms 1–2): n via-points between start_x and end_x of the limb frame.
  int via_points = 16;
  double start_x = -55.0, end_x = 55.0;  // mm, limb frame
  int nearest = 5;                       // surface points averaged per via-point (our choice for Algorithm 2)
  // Control.
  teleop::ForceControlParameters force{};
  teleop::AcquisitionGateParameters gate{};
  double approach_height = 20.0;        // mm above via-point 0 where pre-positioning ends
  double pre_position_tolerance = 1.0;  // mm (and gate.orientation_setpoint) for "ready"
  double acquire_time = 0.25;           // s the gate stays open per slice
  double retract_speed = 10.0;          // mm/s (retraction at ≤ 10 mm/s: ≤ 10)
  double retract_distance = 20.0;       // mm
  // Motion compensation's velocity feed-forward: the via-point's velocity, from the last two tracker
  // samples, added to the hybrid controller's twist (without it only the force law follows the limb
  // along the normal, and lags it by v / 1.67 (mm/s)/N).
  bool velocity_feed_forward = true;
  // The tracked limb pose is noisy (0.3 mm); the feed-forward's velocity would amplify it
  // (a difference over one 8.3 ms tracker period: σ·√2·120 ≈ 50 mm/s from 0.3 mm, the speed cap). The
  // tracker's reports go through a critically damped alpha-beta filter (LimbPoseFilter) of this natural
  // frequency: both the targets and the feed-forward use its pose and velocity. 0: off (raw reports,
  // the velocity from the last two). teleop/ultrasound_arm/README.md has the measurements behind 0.5 Hz.
  double tracker_filter_hz = 0.5;
};

// A critically damped alpha-beta filter on the tracked limb pose, run at each new tracker report
// (control thread: no allocation). Position: x̂ and v̂ per axis; orientation: the rotation vector r of
// R0ᵀ·R (R0 the first report's orientation — the limb turns by a few degrees, far from the chart's
// singularity at π) and its rate. With the tracker period T and the natural frequency ω_n both poles
// sit at ρ = e^(−ω_n·T): α = 1 − ρ², β = (1 − ρ)². It follows a constant velocity without lag, lags an
// acceleration a by a/ω_n², and passes the reports' noise σ as about σ·√(α/2) in position and
// σ·ω_n^1.5·√T in velocity (for small ω_n·T).
class LimbPoseFilter {
 public:
  void configure(double natural_hz, double nominal_period) noexcept;
  void reset() noexcept { initialised_ = false; }
  // A new report at time t (s); a gap of more than 0.1 s (a stall) restarts the filter from it.
  void update(const Eigen::Isometry3d& pose, double t) noexcept;
  bool valid() const noexcept { return initialised_; }
  Eigen::Isometry3d pose() const noexcept { return pose_after(0.0); }
  // The velocity of a point fixed to the limb (its coordinates in the limb frame), mm/s.
  Eigen::Vector3d point_velocity(const Eigen::Vector3d& p_limb) const noexcept;

 private:
  Eigen::Isometry3d pose_after(double h) const noexcept;  // the filtered pose extrapolated by h s
  double alpha_ = 1.0, beta_ = 0.0, period_ = 1.0 / 120.0;
  bool initialised_ = false;
  double t_ = 0.0;
  Eigen::Matrix3d r0_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d x_ = Eigen::Vector3d::Zero(), v_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d r_ = Eigen::Vector3d::Zero(), w_ = Eigen::Vector3d::Zero();
};

// Parses the file's "ultrasound" section (nullopt without one). Throws ConfigError naming file and key.
std::optional<UltrasoundSettings> parse_ultrasound_settings(const RobotConfig& config);

enum class SweepPhase : std::uint8_t {
  idle,
  planned,
  pre_positioning,
  ready,
  approaching,
  acquiring,
  moving,
  paused,
  done,
  aborted
};
const char* to_string(SweepPhase phase) noexcept;

enum class SweepAction : std::uint8_t { plan, preview, pre_position, start, pause, abort };
const char* to_string(SweepAction action) noexcept;
std::optional<SweepAction> sweep_action(const std::string& name);

// The plan, made off the control thread (network thread): ICP of the CT skin onto the scanned skin,
// Algorithm 1 on the CT artery wall mapped by it, Algorithm 2 on the scanned skin.
struct SweepPlan {
  Eigen::Isometry3d ct_to_limb = Eigen::Isometry3d::Identity();  // ICP's T (CT → {P})
  double icp_rms = 0.0;                                          // mm
  int icp_iterations = 0;
  double registration_error = 0.0;         // mm: |T·p − truth| averaged over the CT wall (SIMULATED truth)
  double registration_error_across = 0.0;  // mm: the same without its part along the limb (x)
  std::vector<Eigen::Vector3d> centroids;  // Ψ in {P}
  std::vector<Eigen::Isometry3d> via_points;  // H_i^P
  std::vector<Eigen::Vector3d> skin;          // the scanned skin in {P}
  double planning_time = 0.0;                 // s of wall time the plan took
};

// Throws ultrasound::PlanningInputError (or std::invalid_argument) when the data give no plan.
SweepPlan make_sweep_plan(const LimbSimulation& limb, const UltrasoundSettings& settings);

// The plan as the control thread receives it (trivially copyable; poses 4×4 column-major in {P}).
struct SweepPlanData {
  int count = 0;
  std::array<std::array<double, 16>, kMaxViaPoints> via_points{};
};

// What the control thread publishes (trivially copyable).
struct SweepSnapshot {
  SweepPhase phase = SweepPhase::idle;
  SweepPhase paused_from = SweepPhase::idle;  // the phase a pause or hold interrupted
  int via_point = 0;
  int via_points = 0;
  int slices = 0;
  double progress = 0.0;
  double force_n = 0.0;  // F_n (N)
  double position_error_mm = 0.0;
  double angle_error_rad = 0.0;
  bool force_ok = false;
  bool gate_open = false;
  bool in_contact = false;  // the hybrid controller's force phase
  bool retracting = false;
  std::array<double, 3> limb_offset_mm{};  // tracked limb position minus its rest position (base frame)
  std::array<double, 16> world_T_limb{};   // the tracked pose the targets used
  std::array<double, 16> target{};         // the current target H_i^B (base frame)
  char message[160] = "no plan yet: POST sweep {\"action\":\"plan\"}";
};

// The sweep's control-thread half: no allocation, no locks, no exceptions after construction.
class UltrasoundSweep {
 public:
  // Throws std::invalid_argument for gains or gate parameters out of range.
  UltrasoundSweep(const UltrasoundSettings& settings, const teleop::TaskSpaceGains& gains,
                  const teleop::CartesianLimits& limits);

  struct Inputs {
    teleop::ArmVector q = teleop::ArmVector::Zero();  // the joint setpoint the law runs on
    Eigen::Vector3d force = Eigen::Vector3d::Zero();  // tool frame (N), environment on the probe
    bool force_valid = false;
    Eigen::Isometry3d world_T_limb = Eigen::Isometry3d::Identity();  // tracked
    double limb_t = 0.0;                                             // the tracker sample's time (s)
    double t = 0.0, dt = 0.001;
  };

  void load(const SweepPlanData& plan) noexcept;  // planned, unless a sweep runs
  // An action (pre_position, start, pause, abort) from the control thread's mailbox: applied when the
  // phase allows it, else ignored (the network thread refused it with the reason already).
  void command(SweepAction action, double t) noexcept;
  // A hold of the robot, a mode switch or a lost operator: a running sweep becomes paused.
  void interrupt(const char* why) noexcept;
  // One control cycle in mode sweep: true and `out` filled when the joints move.
  bool step(const teleop::SerialArmKinematics& model, teleop::SerialArmData& data, const Inputs& in,
            teleop::CartesianCommandResult& out) noexcept;
  bool running() const noexcept;  // a phase that moves the arm
  const SweepSnapshot& snapshot() const noexcept { return snapshot_; }
  bool acquiring() const noexcept { return snapshot_.phase == SweepPhase::acquiring && snapshot_.gate_open; }

 private:
  Eigen::Isometry3d target(int i, const Eigen::Isometry3d& world_T_limb) const noexcept;
  Eigen::Matrix4d plan_via(int i) const noexcept;  // H_i^P of via-point i (clamped to the plan)
  // The operator's sentence, formatted into the snapshot's fixed buffer (no allocation).
  template <typename... Args>
  void set_message(const char* fmt, Args... args) noexcept {
    std::snprintf(snapshot_.message, sizeof snapshot_.message, fmt, args...);
  }
  void start_retraction(SweepPhase phase) noexcept;

  UltrasoundSettings settings_;
  teleop::CartesianLimits limits_;
  teleop::HybridPositionForceController controller_;
  teleop::HybridControlState state_;
  SweepPlanData plan_{};
  SweepSnapshot snapshot_{};
  Eigen::Vector3d rest_ = Eigen::Vector3d::Zero();
  double ready_since_ = -1.0;    // pre_positioning: since when the pose is within tolerance
  double acquire_since_ = -1.0;  // acquiring: since when the gate is open
  Eigen::Vector3d retract_direction_ = Eigen::Vector3d::Zero();
  double retracted_ = 0.0;
  bool interrupted_ = false;  // set by interrupt(): the hybrid state restarts at the next step
  // The velocity feed-forward: the tracker's previous sample (a different time than the latest).
  Eigen::Isometry3d previous_limb_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d latest_limb_ = Eigen::Isometry3d::Identity();
  double previous_limb_t_ = -1.0, latest_limb_t_ = -1.0;
  LimbPoseFilter limb_filter_;  // used when settings_.tracker_filter_hz > 0
};

}  // namespace tendril::server
