// Small stepped simulations for the arm controller tests: the UR5 driven by joint velocities (ideal or
// with a first-order lag), a probe pointing straight down, and a flat spring "tissue" under it.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace tendril::teleop::test {

// A scanning pose with the flange pointing straight down (q2 + q3 + q4 = −π/2, q5 = −π/2): the tool z
// axis is −z of the base, the tool sits about 250 mm above the base plane, 610 mm out.
inline ArmVector probe_down_pose() {
  ArmVector q;
  const double q2 = -1.2, q3 = 1.6;
  q << 0.0, q2, q3, -std::numbers::pi / 2 - q2 - q3, -std::numbers::pi / 2, 0.0;
  return q;
}

// The tool's orientation at probe_down_pose(): x = y0, y = x0, z = −z0.
inline Eigen::Matrix3d probe_down_rotation() {
  Eigen::Matrix3d r;
  r << 0.0, 1.0, 0.0,  //
      1.0, 0.0, 0.0,   //
      0.0, 0.0, -1.0;
  return r;
}

// The arm's joints integrate the commanded velocities; with lag > 0 each joint velocity follows the
// command as a first-order system of that time constant (s).
struct VelocityArm {
  ArmVector q = probe_down_pose();
  ArmVector qd = ArmVector::Zero();
  double lag = 0.0;
  void step(const ArmVector& command, double dt) {
    const double a = lag > 0.0 ? 1.0 - std::exp(-dt / lag) : 1.0;
    const ArmVector before = qd;
    qd += a * (command - qd);
    q += 0.5 * (before + qd) * dt;
  }
};

// A horizontal plane at height z (mm, base frame) with stiffness k (N/mm): the force on a tool point
// below it is k·depth along +z. Returned in the tool frame, as a sensor on the tool would see it.
struct SpringFloor {
  double z = 0.0;
  double stiffness = 1.0;
  Eigen::Vector3d force_in_tool(const Eigen::Isometry3d& tool) const {
    const double depth = std::max(0.0, z - tool.translation().z());
    return tool.linear().transpose() * Eigen::Vector3d(0.0, 0.0, stiffness * depth);
  }
};

}  // namespace tendril::teleop::test
