// Cartesian commands for a velocity-commanded serial arm, in CRTK's names:
//   measured_cp / measured_cv — the tool pose and twist from the measured joints;
//   servo_cv — a streamed twist, resolved to joint velocities every cycle;
//   servo_cp — a streamed pose setpoint, tracked directly by the Appendix A pose law (A9 + A2–A8), whose
//              saturating speed profile keeps a jumpy stream smooth and within the caps;
//   move_cp  — a pose goal, planned as a CartesianTrajectory (quintic time scaling, a straight line in
//              position and a slerp in orientation on one clock) and tracked with the trajectory's twist
//              as feed-forward plus the same pose law on the remaining error.
// Twists are [v (mm/s); ω (rad/s)] of the tool point in the base frame. Every command is capped by
// CartesianLimits, then resolved through the damped inverse and the joint limits (resolve_twist).
// All functions are noexcept and allocation-free; a non-finite input gives zero joint velocities.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/teleop/serial_arm_kinematics.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::teleop {

// Defaults: Appendix A's caps (Table 1's V_d and ω_d), since the arm that uses these is the ultrasound
// arm. The accelerations are our choice: gentle enough for a probe on tissue (50 mm/s reached in 0.5 s).
struct CartesianLimits {
  double max_linear_speed = 50.0;          // mm/s
  double max_angular_speed = 0.1;          // rad/s
  double max_linear_acceleration = 100.0;  // mm/s², move_cp planning
  double max_angular_acceleration = 0.2;   // rad/s², move_cp planning
};
// Throws std::invalid_argument naming the field when a limit is not finite and positive.
void validate(const CartesianLimits& limits);

struct CartesianCommandResult {
  JointVelocityResult joints{};  // what to command (zero unless joints.valid)
  Twist twist = Twist::Zero();   // the twist actually resolved, after the caps
  bool twist_limited = false;    // a cap scaled the requested twist down
};

// The tool pose and twist at the measured joints (FK into data). False (outputs untouched) when an
// input is not finite.
bool measured_cp(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                 Eigen::Isometry3d& pose) noexcept;
bool measured_cv(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                 const ArmVector& joint_velocity, Twist& twist) noexcept;

CartesianCommandResult servo_cv(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                                const Twist& twist, const CartesianLimits& limits, double dt) noexcept;

CartesianCommandResult servo_cp(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                                const Eigen::Isometry3d& goal, const TaskSpaceGains& gains,
                                const CartesianLimits& limits, double dt) noexcept;

// A straight-line, slerp-oriented move between two poses on one quintic time scaling s(t) (zero
// velocity and acceleration at both ends), lasting the shortest time that keeps the peak linear and
// angular speeds and accelerations within the limits. Fixed-size: plan() and sample() run in the
// control cycle without allocating.
class CartesianTrajectory {
 public:
  struct Sample {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    Twist twist = Twist::Zero();  // feed-forward (mm/s, rad/s; base frame)
  };

  // Plans from `start` to `goal` beginning at time t0 (s). Returns false (the trajectory unchanged) when
  // a pose or limit is not finite, a rotation is not one, or a limit is not positive.
  bool plan(const Eigen::Isometry3d& start, const Eigen::Isometry3d& goal, const CartesianLimits& limits,
            double t0, double min_duration = 0.0) noexcept;
  // Holds at `pose` (a trajectory of zero length).
  void hold(const Eigen::Isometry3d& pose, double t) noexcept;

  Sample sample(double t) const noexcept;
  bool done(double t) const noexcept { return t >= start_time_ + duration_; }
  double start_time() const noexcept { return start_time_; }
  double duration() const noexcept { return duration_; }
  const Eigen::Vector3d& goal_position() const noexcept { return end_position_; }
  const Eigen::Quaterniond& goal_orientation() const noexcept { return end_orientation_; }

 private:
  Eigen::Vector3d start_position_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d end_position_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond start_orientation_ = Eigen::Quaterniond::Identity();
  Eigen::Quaterniond end_orientation_ = Eigen::Quaterniond::Identity();
  Eigen::Vector3d rotation_axis_ = Eigen::Vector3d::UnitZ();  // of end·start⁻¹, base frame
  double rotation_angle_ = 0.0;
  double start_time_ = 0.0;
  double duration_ = 0.0;
};

// One move_cp control cycle: the reference's twist plus the pose law on the error to the reference
// pose, capped and resolved.
CartesianCommandResult track(const SerialArmKinematics& model, SerialArmData& data, const ArmVector& q,
                             const CartesianTrajectory::Sample& reference, const TaskSpaceGains& gains,
                             const CartesianLimits& limits, double dt) noexcept;

}  // namespace tendril::teleop
