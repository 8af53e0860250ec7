// LimitSet: the per-joint safety limits of one robot (position with a soft margin, velocity,
// acceleration, tracking error), validated once at set-up.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

namespace tendril::safety {

struct JointLimit {
  std::string name;  // used in messages, e.g. "roll"
  std::string unit;  // position unit, e.g. "mm" or "rad"; velocity messages append "/s"
  double lower = 0.0;
  double upper = 0.0;
  double soft_margin = 0.0;         // setpoints are kept within [lower + margin, upper − margin]
  double max_velocity = 0.0;        // unit/s
  double max_acceleration = 0.0;    // unit/s²
  double max_tracking_error = 0.0;  // |measured − setpoint| beyond this faults (unit)
};

class LimitSet {
 public:
  // Throws std::invalid_argument naming the joint and the offending value when: there are no joints
  // or more than kMaxJoints, a value is not finite, lower >= upper, the margin is negative or leaves
  // no room (2·margin >= upper − lower), or a velocity/acceleration/tracking limit is not positive.
  explicit LimitSet(std::vector<JointLimit> joints);

  std::size_t size() const noexcept { return joints_.size(); }
  const JointLimit& operator[](std::size_t i) const noexcept { return joints_[i]; }
  std::span<const JointLimit> joints() const noexcept { return joints_; }

 private:
  std::vector<JointLimit> joints_;
};

}  // namespace tendril::safety
