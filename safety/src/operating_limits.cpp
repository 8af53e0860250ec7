#include "tendril/safety/operating_limits.hpp"

#include <cmath>
#include <sstream>

namespace tendril::safety {

OperatingLimits OperatingLimits::configured(const LimitSet& limits, double servo_timeout_s) noexcept {
  OperatingLimits out;
  for (std::size_t i = 0; i < limits.size(); ++i) {
    out.lower[i] = limits[i].lower;
    out.upper[i] = limits[i].upper;
    out.max_velocity[i] = limits[i].max_velocity;
  }
  out.servo_timeout_s = servo_timeout_s;
  return out;
}

int OperatingLimits::first_outside_position(std::span<const double> q) const noexcept {
  for (std::size_t i = 0; i < q.size() && i < kMaxJoints; ++i)
    if (!(q[i] >= lower[i] && q[i] <= upper[i])) return static_cast<int>(i);
  return -1;
}

int OperatingLimits::first_over_velocity(std::span<const double> v) const noexcept {
  for (std::size_t i = 0; i < v.size() && i < kMaxJoints; ++i)
    if (!(std::abs(v[i]) <= max_velocity[i])) return static_cast<int>(i);
  return -1;
}

bool OperatingLimits::within_position(std::span<const double> q) const noexcept {
  return first_outside_position(q) < 0;
}
bool OperatingLimits::within_velocity(std::span<const double> v) const noexcept {
  return first_over_velocity(v) < 0;
}

bool tightens(const OperatingLimits& t, const OperatingLimits& c, std::size_t joints, const LimitSet& names,
              std::string* why) {
  std::ostringstream out;
  for (std::size_t i = 0; i < joints && out.tellp() == 0; ++i) {
    const auto& j = names[i];
    const std::string p = j.name + "/";
    if (t.lower[i] < c.lower[i])
      out << p << "lower " << t.lower[i] << " " << j.unit << " is below the configured limit " << c.lower[i]
          << " " << j.unit << ": limits may only be tightened";
    else if (t.upper[i] > c.upper[i])
      out << p << "upper " << t.upper[i] << " " << j.unit << " is above the configured limit " << c.upper[i]
          << " " << j.unit << ": limits may only be tightened";
    else if (t.lower[i] + 2 * j.soft_margin >= t.upper[i])
      out << p << "lower (" << t.lower[i] << ") must be below upper (" << t.upper[i]
          << ") by more than twice the soft margin (" << j.soft_margin << " " << j.unit << ")";
    else if (!(t.max_velocity[i] > 0) || t.max_velocity[i] > c.max_velocity[i])
      out << p << "max_velocity " << t.max_velocity[i] << " " << j.unit
          << "/s must be above 0 and at most the configured " << c.max_velocity[i] << " " << j.unit << "/s";
  }
  if (out.tellp() == 0 && (!(t.servo_timeout_s >= 0.005) || t.servo_timeout_s > c.servo_timeout_s))
    out << "servo_timeout_s " << t.servo_timeout_s << " s must be between 0.005 s and the configured "
        << c.servo_timeout_s << " s";
  if (out.tellp() == 0) return true;
  if (why) *why = out.str();
  return false;
}

}  // namespace tendril::safety
