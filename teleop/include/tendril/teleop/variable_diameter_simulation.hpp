// A simulation (not a controller for hardware) of the dissertation's variable-diameter experiment (Abah 2022,
// §2.7.2, Figs. 2.11–2.13): the three-segment robot of variable_diameter_robot.hpp follows a circle with
// its tip while carrying a payload, once with the diameter held at a_min and once with the diameter
// free for gradient projection, and the two actuation-force histories are compared.
//
// Set-up from the dissertation: circle in the x-z plane centred at [0, 150, 435] mm, radius 70 mm; end disk
// kept parallel to the x-z plane; 2 kg payload, W_e = [0, 0, −19.62, 0, 0, 0]; dt = 1 ms. Where the
// dissertation is silent (teleop/mbcr_vd/README.md):
// - the end disk's normal points along +y and its x axis along +x (R = Rx(−90°), the orientation of
//   a robot bent in its y-z plane);
// - the circle starts at its top, [0, 150, 505] mm, and runs once towards −x (counter-clockwise seen
//   from +y), so its middle is the bottom point nearest the base, where the robot must curl most;
// - one turn takes `period` = 20 s;
// - the start configuration is the damped-least-squares solution for the start pose from a planar
//   guess (solve_tip_pose), shared by both runs; the varying run starts at a_min plus
//   `start_offset` (H of (2.36) is infinite at a limit itself).
// These functions allocate (they record a history) and belong to set-up, tests and tools.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <string>
#include <vector>

#include "tendril/teleop/variable_diameter_robot.hpp"

namespace tendril::teleop {

struct CircleTrajectoryParameters {
  Eigen::Vector3d centre{0.0, 150.0, 435.0};    // mm
  double radius = 70.0;                         // mm
  double period = 20.0;                         // s per turn (our choice)
  double start_angle = 1.57079632679489661923;  // rad from +x towards +z; π/2 is the top
  double direction = 1.0;  // +1: start angle grows (top → −x → bottom → +x → top)
  double dt = 1e-3;        // s
  Wrench payload = (Wrench() << 0.0, 0.0, -19.62, 0.0, 0.0, 0.0).finished();
  Eigen::Matrix3d orientation =
      Eigen::AngleAxisd(-1.57079632679489661923, Eigen::Vector3d::UnitX()).toRotationMatrix();
  double start_offset = 0.05;  // mm above a_min where the varying run starts
};

// Tip pose and twist of the circle at time t.
Eigen::Isometry3d circle_pose(const CircleTrajectoryParameters& circle, double t) noexcept;
StackTwist circle_twist(const CircleTrajectoryParameters& circle, double t) noexcept;

// Damped least-squares iterations (set-up, not real time) from psi towards the pose; psi holds the
// solution. Returns the final position error (mm); the caller decides what is close enough.
double solve_tip_pose(const VariableDiameterRobot& robot, const Eigen::Isometry3d& target,
                      StackConfiguration& psi, int iterations = 2000);

// The two inverse-kinematics branches that reach the circle's start with the end disk facing +y.
enum class CircleBranch {
  kHook,    // segments bent ≈ 46°, 87°, 131° at the start and up to 187° at the bottom: disks interfere
  kSShape,  // segments bent ≈ 10°, 29°, 71° at the start and at most 123°: disks never interfere
};

// A planar guess for the branch and its solution for the circle's start pose.
StackConfiguration circle_start_configuration(const VariableDiameterRobot& robot,
                                              const CircleTrajectoryParameters& circle,
                                              CircleBranch branch = CircleBranch::kHook);

struct CircleSample {
  double time = 0.0;
  double diameter_joint = 0.0;  // a (mm)
  double diameter_upper = 0.0;  // upper limit of a at this step (mm)
  double interference = 0.0;    // interference limit alone (mm, +inf when none)
  double force_norm = 0.0;      // ‖τ̃_s‖ (N)
  double tracking_error = 0.0;  // mm
  double largest_bend = 0.0;    // max_k |Θ_k| (rad)
  StackJoints joints = StackJoints::Zero();
  VariableDiameterStatus status = VariableDiameterStatus::kOk;
};

struct CircleRun {
  std::vector<CircleSample> samples;
  std::size_t clamped_steps = 0;  // steps after which a had to be clamped into its limits
  std::size_t failed_steps = 0;   // steps that reported a non-finite value (the run stops there)
};

CircleRun simulate_circle(const VariableDiameterRobot& robot, const CircleTrajectoryParameters& circle,
                          const StackConfiguration& start, bool vary_diameter);

struct ForceComparison {
  double rms_fixed = 0.0;     // RMS of ‖τ̃_s‖ with a = a_min (N)
  double rms_variable = 0.0;  // RMS of ‖τ̃_s‖ with the diameter free (N)
  double rms_reduction = 0.0;  // RMS over time of ‖τ̃_fixed‖ − ‖τ̃_variable‖ (the dissertation's 48.3 N)
  double mean_reduction = 0.0;
  double std_reduction = 0.0;  // standard deviation of that difference (the dissertation's 17.6 N)
  double min_reduction = 0.0;
  double max_reduction = 0.0;
};

// Sample by sample; both runs must have the same length.
ForceComparison compare_forces(const CircleRun& fixed, const CircleRun& variable);

// Writes time, a, its upper limit, and both force norms as CSV, and the same as a two-panel SVG plot.
// Return false when a file cannot be written.
bool write_circle_csv(const std::string& path, const CircleRun& fixed, const CircleRun& variable);
bool write_circle_svg(const std::string& path, const CircleRun& fixed, const CircleRun& variable);

}  // namespace tendril::teleop
