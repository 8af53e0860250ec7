// RobotKinematics: the display/pose model of a robot, chosen by name in the robot file's
// "kinematics.model". Used outside the real-time thread (shape, tip pose for the API and scene).
#pragma once

#include <memory>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

namespace tendril::server {

struct Pose {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};

class RobotKinematics {
 public:
  virtual ~RobotKinematics() = default;
  virtual std::string frame() const = 0;
  // Backbone or link polyline (mm) at joint positions q.
  virtual std::vector<Eigen::Vector3d> shape(std::span<const double> q) const = 0;
  virtual Pose tip(std::span<const double> q) const = 0;
};

// Builds the model named in `kinematics["model"]` for a robot with `joint_count` joints; throws
// ConfigError naming `file` and the key when the model is unknown or its parameters are wrong.
std::unique_ptr<RobotKinematics> make_kinematics(const nlohmann::json& kinematics, std::size_t joint_count,
                                                 const std::string& file);

}  // namespace tendril::server
