// RobotTypes: the robot types a server knows, by the robot file's "kind". The core never names a type:
// tendrild and the tests pass builtin_robot_types(), which is generated at configure time from the
// plug-in folders under server/src/robots/ (each provides register_<folder>(RobotTypes&)).
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "tendril/server/robot_type.hpp"

namespace tendril::server {

class RobotTypes {
 public:
  // Throws std::logic_error when the kind is registered twice.
  void add(std::unique_ptr<RobotType> type);
  const RobotType* find(const std::string& kind) const;
  std::vector<std::string> kinds() const;

 private:
  std::map<std::string, std::unique_ptr<RobotType>> types_;
};

// Every robot type built into this binary (server/src/robots/*), registered once.
const RobotTypes& builtin_robot_types();

}  // namespace tendril::server
