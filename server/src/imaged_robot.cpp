#include "tendril/server/imaged_robot.hpp"

#include "tendril/server/config.hpp"

namespace tendril::server {

std::string choose_imaged_robot(RobotRuntime& runtime, const std::vector<std::string>& robots,
                                const std::string& named, const std::string& scene_robot,
                                const std::string& file) {
  if (!named.empty()) {
    if (!runtime.has_robot(named))
      throw ConfigError(file + ": imaging.robot: no robot named '" + named + "' is configured");
    return named;
  }
  if (robots.empty()) throw ConfigError(file + ": imaging: no robot to image");
  if (robots.size() == 1) return robots.front();
  std::vector<std::string> candidates;
  for (const auto& r : robots) {
    auto* plugin = runtime.plugin(r);
    if ((plugin && plugin->image_feedback()) || runtime.vessel_entry(r)) candidates.push_back(r);
  }
  if (candidates.size() == 1) return candidates.front();
  for (const auto& c : candidates)
    if (c == scene_robot) return c;
  std::string all;
  for (const auto& r : robots) all += (all.empty() ? "" : ", ") + r;
  std::string which;
  for (const auto& c : candidates) which += (which.empty() ? "" : ", ") + c;
  throw ConfigError(file + ": imaging.robot: " + std::to_string(robots.size()) + " robots are configured (" +
                    all + ") and " +
                    (candidates.empty() ? std::string("none of them enters a vessel or uses the images")
                                        : "several enter a vessel or use the images (" + which + ")") +
                    ": name the imaged robot in imaging.robot");
}

}  // namespace tendril::server
