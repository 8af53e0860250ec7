#include "tendril/server/robot_types.hpp"

#include <algorithm>
#include <stdexcept>

#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/planning_api.hpp"

namespace tendril::server {

void RobotTypes::add(std::unique_ptr<RobotType> type) {
  const std::string kind = type->kind();
  if (!types_.emplace(kind, std::move(type)).second)
    throw std::logic_error("robot type '" + kind + "' is registered twice");
}

const RobotType* RobotTypes::find(const std::string& kind) const {
  const auto it = types_.find(kind);
  return it == types_.end() ? nullptr : it->second.get();
}

std::vector<std::string> RobotTypes::kinds() const {
  std::vector<std::string> out;
  for (const auto& [kind, type] : types_) out.push_back(kind);
  return out;
}

std::unique_ptr<PlanningApi> RobotType::planning_service(const std::vector<RobotConfig>& robots) const {
  (void)robots;
  return nullptr;
}

std::optional<sim::DriveParameters> RobotType::simulated_drive(const std::string& preset,
                                                               const JointConfig& joint) const {
  (void)preset;
  (void)joint;
  return std::nullopt;
}

void RobotPlugin::display_positions(std::span<const double> measured, std::span<double> out) const {
  std::copy(measured.begin(), measured.end(), out.begin());
}

Result<std::pair<PluginCommand, double>> RobotPlugin::cartesian_command(
    CartesianKind kind, const CartesianPose& pose, const CartesianTwist& twist,
    const OperatingStateView& state) const {
  (void)kind;
  (void)pose;
  (void)twist;
  (void)state;
  return ServiceError{ErrorKind::not_supported, "not_supported", "this robot takes no Cartesian commands"};
}

}  // namespace tendril::server
