// Which robot the bi-plane imaging images (issue 31): the one `imaging.robot` names; with one robot,
// that one; with several and none named, the only one that closes a loop on the images or enters the
// scene's vessel (image feedback or a vessel entry) — the scene's robot when several do. Otherwise a
// ConfigError asks for imaging.robot, naming the candidates.
#pragma once

#include <string>

#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {

// `named`: imaging.robot ("" when absent); `scene_robot`: the robot whose entry places the scene's vessel
// ("" when none); `file`: the server file, for the error.
std::string choose_imaged_robot(RobotRuntime& runtime, const std::vector<std::string>& robots,
                                const std::string& named, const std::string& scene_robot,
                                const std::string& file);

}  // namespace tendril::server
