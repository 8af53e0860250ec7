// The robot–world calibration's motion (Heunis et al. 2021, §2.3) and the SIMULATED optical tracker it reads.
//
// CalibrationMotion is a phase machine on the control thread, like the sweep: the network thread
// chooses K tool poses near the current one (calibration_poses(), checked against the workspace box and
// run kinematically first) and hands them over through a slot and the mailbox; the control thread then
// moves the tool to each pose in turn (a straight-line quintic under the Cartesian caps, tracked with
// the pose law — move_cp's law), stands still there for `dwell` (the arm settles; the tracker's newest
// sample is then of the still arm), and records a pair (forward kinematics of the measured joints, the
// tracked marker pose) into a preallocated slot. After the last pose it returns to where it started and
// publishes the pairs; the solve (ultrasound/hand_eye.hpp) runs off the control thread. No allocation,
// no locks. A tracker sample older than `tracker_timeout` (the marker hidden, the tracker silent) or a
// hold, pause, disable or mode switch ends the routine (`failed`, with the reason).
//
// SimulatedOpticalTracker: the SIMULATED motion-capture system that defines the global frame {G}. The
// arm's base sits at a true H_B^G and a marker rigid body on the probe at a true X = H_U^M (both from
// the robot file's ultrasound.simulation.tracker). At 120 Hz it samples where the probe really is — the
// forward kinematics of the measured joints plus the arm's own positioning error (Heunis et al. 2021, §4.3:
// 0.3 ± 0.1 mm; modelled as a smooth function of the joints, i.e. fixed geometric errors of the arm against
// its model: the same pose gives the same error) — and reports the marker in {G} with the triangulation error
// (0.56 ± 0.08 mm in a random direction, plus 0.02° per axis of rotation noise), and the limb in {G} (H_B^G
// times the limb tracker's pose in the base frame). It runs where the control thread asks it (stepped with
// the measured joints), since the truth it needs is the simulated arm's.
#pragma once

#include <array>
#include <cstdint>
#include <random>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/teleop/cartesian_control.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::server {

inline constexpr int kMaxCalibrationPoses = 24;

struct OpticalTrackerSettings {
  Eigen::Isometry3d global_T_base = Eigen::Isometry3d::Identity();   // true H_B^G
  Eigen::Isometry3d marker_T_probe = Eigen::Isometry3d::Identity();  // true X = H_U^M
  double rate_hz = 120.0;
  double triangulation_mean_mm = 0.56, triangulation_sd_mm = 0.08;
  double rotation_noise_deg = 0.02;
  double robot_error_mean_mm = 0.3, robot_error_sd_mm = 0.1;
  std::uint64_t seed = 41;
};

struct TrackerSample {              // trivially copyable
  double t = -1.0;                  // control time of the sample (s); < 0: none yet
  std::array<double, 16> marker{};  // H_M^G, column-major
  bool visible = false;
};

class SimulatedOpticalTracker {
 public:
  explicit SimulatedOpticalTracker(const OpticalTrackerSettings& settings);
  const OpticalTrackerSettings& settings() const noexcept { return settings_; }
  // The arm's positioning error at joints q (mm, base frame): smooth in q, 0.3 ± 0.1 mm.
  Eigen::Vector3d robot_error(const teleop::ArmVector& q) const noexcept;
  // Control thread: a new sample when one is due at time t (the probe's kinematic pose at the measured
  // joints q). Silent (no new samples) while `silent` is set — the marker hidden.
  void step(double t, const teleop::ArmVector& q, const Eigen::Isometry3d& probe_kinematic) noexcept;
  const TrackerSample& latest() const noexcept { return latest_; }
  void set_silent(bool silent) noexcept { silent_ = silent; }  // control thread (a test's hook)
  bool silent() const noexcept { return silent_; }

 private:
  OpticalTrackerSettings settings_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double next_ = 0.0;
  bool silent_ = false;
  TrackerSample latest_{};
};

struct CalibrationPosesData {  // trivially copyable: the network thread's poses for the control thread
  std::uint32_t run = 0;
  int count = 0;
  std::array<std::array<double, 16>, kMaxCalibrationPoses> poses{};  // tool in base, column-major
};

struct CalibrationPairsData {  // trivially copyable: the recorded pairs for the solver
  std::uint32_t run = 0;
  int count = 0;
  std::array<std::array<double, 16>, kMaxCalibrationPoses> kinematic{};  // F_k = H_U^B
  std::array<std::array<double, 16>, kMaxCalibrationPoses> tracked{};    // A_k = H_M^G
};

enum class CalibrationPhase : std::uint8_t { idle, moving, dwelling, returning, collected, failed };
const char* to_string(CalibrationPhase phase) noexcept;

struct CalibrationSnapshot {  // trivially copyable
  std::uint32_t run = 0;
  CalibrationPhase phase = CalibrationPhase::idle;
  int pose = 0;  // 0-based pose being moved to or recorded
  int poses = 0;
  std::array<char, 160> message{};
};

// K poses near `current` (tool in base): tilts of `tilt` rad about axes going round the tool's z in
// steps of 2π/K, turned about z by 0.6 tilt · sin of the same angle, the tool point moved by up to
// `shift` mm — an order in which consecutive poses are close (short moves at 0.1 rad/s) while the whole
// set spreads in rotation.
int calibration_poses(const Eigen::Isometry3d& current, int count, double tilt, double shift,
                      CalibrationPosesData& out) noexcept;

class CalibrationMotion {
 public:
  CalibrationMotion(const teleop::CartesianLimits& limits, const teleop::TaskSpaceGains& gains, double dwell,
                    double tracker_timeout);

  // Control thread. Starts the run from the tool's current setpoint pose.
  void start(const CalibrationPosesData& poses, const Eigen::Isometry3d& tool, double t) noexcept;
  // One cycle: the law's joint velocities in `result` (false: stand still). `measured_tool` is the
  // forward kinematics of the measured joints, `tracker` the newest tracker sample.
  bool step(const teleop::SerialArmKinematics& model, teleop::SerialArmData& data, const teleop::ArmVector& q,
            const Eigen::Isometry3d& measured_tool, const TrackerSample& tracker, double t, double dt,
            teleop::CartesianCommandResult& result) noexcept;
  // Ends a running routine with a reason (a hold, a disable, a mode switch).
  void fail(const char* why) noexcept;
  void delay(double lost) noexcept { delay_ += lost; }
  bool running() const noexcept {
    return snapshot_.phase == CalibrationPhase::moving || snapshot_.phase == CalibrationPhase::dwelling ||
           snapshot_.phase == CalibrationPhase::returning;
  }
  const CalibrationSnapshot& snapshot() const noexcept { return snapshot_; }
  const CalibrationPairsData& pairs() const noexcept { return pairs_; }

 private:
  void message(const char* format, double a = 0, double b = 0) noexcept;
  bool plan_to(const Eigen::Isometry3d& from, const Eigen::Isometry3d& goal, double t) noexcept;

  teleop::CartesianLimits limits_;
  teleop::TaskSpaceGains gains_;
  double dwell_, tracker_timeout_;
  CalibrationPosesData poses_{};
  CalibrationPairsData pairs_{};
  CalibrationSnapshot snapshot_{};
  Eigen::Isometry3d home_ = Eigen::Isometry3d::Identity();
  teleop::CartesianTrajectory trajectory_;
  double delay_ = 0.0;
  double dwell_start_ = 0.0;
};

}  // namespace tendril::server
