#include "tendril/safety/limit_set.hpp"

#include <cmath>
#include <stdexcept>

#include "tendril/safety/safety_types.hpp"

namespace tendril::safety {
namespace {

std::string label(const JointLimit& j, std::size_t i) {
  return "joint " + std::to_string(i) + (j.name.empty() ? std::string() : " ('" + j.name + "')");
}

}  // namespace

LimitSet::LimitSet(std::vector<JointLimit> joints) : joints_(std::move(joints)) {
  if (joints_.empty() || joints_.size() > kMaxJoints)
    throw std::invalid_argument("LimitSet: expected 1.." + std::to_string(kMaxJoints) + " joints, got " +
                                std::to_string(joints_.size()));
  for (std::size_t i = 0; i < joints_.size(); ++i) {
    const JointLimit& j = joints_[i];
    const std::string who = "LimitSet: " + label(j, i) + ": ";
    for (double v :
         {j.lower, j.upper, j.soft_margin, j.max_velocity, j.max_acceleration, j.max_tracking_error})
      if (!std::isfinite(v)) throw std::invalid_argument(who + "every limit must be a finite number");
    if (!(j.lower < j.upper))
      throw std::invalid_argument(who + "lower (" + std::to_string(j.lower) + ") must be below upper (" +
                                  std::to_string(j.upper) + ")");
    if (j.soft_margin < 0.0 || 2.0 * j.soft_margin >= j.upper - j.lower)
      throw std::invalid_argument(who + "soft_margin " + std::to_string(j.soft_margin) +
                                  " must be >= 0 and leave room between the limits");
    if (j.max_velocity <= 0.0) throw std::invalid_argument(who + "max_velocity must be > 0");
    if (j.max_acceleration <= 0.0) throw std::invalid_argument(who + "max_acceleration must be > 0");
    if (j.max_tracking_error <= 0.0) throw std::invalid_argument(who + "max_tracking_error must be > 0");
  }
}

}  // namespace tendril::safety
