#include "tendril/teleop/active_compliance.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

void validate(const ActiveComplianceParameters& p) {
  auto bad = [](const std::string& what) { throw std::invalid_argument("active compliance: " + what); };
  if (!std::isfinite(p.gain) || p.gain <= 0) bad("gain K_a must be a positive number");
  if (!std::isfinite(p.min_speed) || p.min_speed < 0) bad("min_speed must be >= 0 mm/s");
  if (!std::isfinite(p.max_speed) || p.max_speed < p.min_speed)
    bad("max_speed must be a number >= min_speed (mm/s)");
  if (!std::isfinite(p.max_deflection) || p.max_deflection <= 0) bad("max_deflection must be > 0 mm");
  if (!std::isfinite(p.deadband) || p.deadband < 0 || p.deadband >= p.max_deflection)
    bad("deadband must be >= 0 and smaller than max_deflection (mm)");
}

double active_compliance_increment(const ActiveComplianceParameters& p, double deflection,
                                   double dt) noexcept {
  if (!std::isfinite(deflection) || !(dt > 0) || std::abs(deflection) < p.deadband) return 0.0;
  const double t = std::min(std::abs(deflection) / p.max_deflection, 1.0);
  const double speed = p.gain * ((1.0 - t) * p.min_speed + t * p.max_speed);
  return -std::copysign(speed * dt, deflection);
}

void apply_active_compliance(const ActiveComplianceParameters& p, std::span<const double> q_measured,
                             const std::array<double, 2>& deflection, double dt,
                             std::span<double> q_des) noexcept {
  if (q_measured.size() < 4 || q_des.size() < 4) return;
  for (std::size_t i = 0; i < 2; ++i)
    q_des[2 + i] = q_measured[2 + i] + active_compliance_increment(p, deflection[i], dt);
}

}  // namespace tendril::teleop
