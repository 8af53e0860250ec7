// Angulated scissor linkage and disk interference (Abah 2022, §2.3–2.4); see the header.
#include "tendril/teleop/variable_diameter_linkage.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

[[noreturn]] void fail(const std::string& what) { throw std::invalid_argument("scissor linkage: " + what); }

void require_positive(const char* name, double value) {
  if (!std::isfinite(value) || value <= 0.0) {
    std::ostringstream out;
    out << name << " must be a positive finite length in mm, got " << value;
    fail(out.str());
  }
}

}  // namespace

ScissorLinkage::ScissorLinkage(const ScissorLinkageParameters& parameters) : parameters_(parameters) {
  if (parameters.rhombus_count <= 2) {
    fail("rhombus_count (n) must be greater than 2, got " + std::to_string(parameters.rhombus_count));
  }
  require_positive("inner_arm_length (l1)", parameters.inner_arm_length);
  require_positive("outer_arm_length (l2)", parameters.outer_arm_length);
  require_positive("hinge_diameter (d)", parameters.hinge_diameter);
  const double l1 = parameters.inner_arm_length;
  const double half_d = 0.5 * parameters.hinge_diameter;
  if (half_d >= l1) {
    std::ostringstream out;
    out << "hinge_diameter (d) = " << parameters.hinge_diameter
        << " mm must be less than twice inner_arm_length (l1) = " << l1 << " mm";
    fail(out.str());
  }
  const double sigma = std::numbers::pi / parameters.rhombus_count;
  sin_sigma_ = std::sin(sigma);
  cos_sigma_ = std::cos(sigma);
  const double arm = std::sqrt(l1 * l1 - half_d * half_d);
  r_min_ = half_d / std::tan(sigma) + arm;  // (2.9)
  r_max_ = arm / sin_sigma_;                // (2.10)
  if (!(r_min_ < r_max_)) {
    std::ostringstream out;
    out << "hinge_diameter (d) = " << parameters.hinge_diameter << " mm leaves no motion: r_min = " << r_min_
        << " mm is not below r_max = " << r_max_ << " mm";
    fail(out.str());
  }
  if (!(r_max_ < parameters.outer_arm_length / sin_sigma_)) {
    std::ostringstream out;
    out << "outer_arm_length (l2) = " << parameters.outer_arm_length
        << " mm is too short: the outer vertices cannot follow the linkage to r_max = " << r_max_ << " mm";
    fail(out.str());
  }
  a_min_ = inner_radius(r_min_);  // (2.14)
  a_max_ = inner_radius(r_max_);
  b_min_ = parameters.rhombus_count < 6 ? outer_radius(r_max_) : outer_radius(r_min_);
  const double r_peak = configuration_radius_at_outer_peak();
  if (r_peak >= r_min_ && r_peak <= r_max_) {
    r_at_b_max_ = r_peak;
  } else {
    r_at_b_max_ = outer_radius(r_min_) >= outer_radius(r_max_) ? r_min_ : r_max_;
  }
  b_max_ = outer_radius(r_at_b_max_);
}

double ScissorLinkage::inner_radius(double r) const noexcept {
  const double l1 = parameters_.inner_arm_length;
  const double under = l1 * l1 - r * r * sin_sigma_ * sin_sigma_;
  if (!std::isfinite(r) || r < 0.0 || under <= 0.0) return kNaN;
  return r * cos_sigma_ - std::sqrt(under);
}

double ScissorLinkage::outer_radius(double r) const noexcept {
  const double l2 = parameters_.outer_arm_length;
  const double under = l2 * l2 - r * r * sin_sigma_ * sin_sigma_;
  if (!std::isfinite(r) || r < 0.0 || under <= 0.0) return kNaN;
  return r * cos_sigma_ + std::sqrt(under);
}

double ScissorLinkage::configuration_radius(double a) const noexcept {
  const double l1 = parameters_.inner_arm_length;
  const double under = l1 * l1 - a * a * sin_sigma_ * sin_sigma_;
  if (!std::isfinite(a) || under < 0.0) return kNaN;
  return a * cos_sigma_ + std::sqrt(under);
}

double ScissorLinkage::inner_radius_rate(double r) const noexcept {
  const double l1 = parameters_.inner_arm_length;
  const double under = l1 * l1 - r * r * sin_sigma_ * sin_sigma_;
  if (!std::isfinite(r) || under <= 0.0) return kNaN;
  return cos_sigma_ + r * sin_sigma_ * sin_sigma_ / std::sqrt(under);
}

double ScissorLinkage::outer_radius_rate(double r) const noexcept {
  const double l2 = parameters_.outer_arm_length;
  const double under = l2 * l2 - r * r * sin_sigma_ * sin_sigma_;
  if (!std::isfinite(r) || under <= 0.0) return kNaN;
  return cos_sigma_ - r * sin_sigma_ * sin_sigma_ / std::sqrt(under);
}

double ScissorLinkage::configuration_radius_rate(double a) const noexcept {
  return 1.0 / inner_radius_rate(configuration_radius(a));
}

double ScissorLinkage::elbow_angle(double r) const noexcept {
  const double s2 = sin_sigma_ * sin_sigma_;
  const double x1 = r / parameters_.inner_arm_length;
  const double x2 = r / parameters_.outer_arm_length;
  const double u1 = 1.0 - x1 * x1 * s2;
  const double u2 = 1.0 - x2 * x2 * s2;
  if (!std::isfinite(r) || u1 < 0.0 || u2 < 0.0) return kNaN;
  // Rounding can push the cosines a hair past ±1 at the ends of the range.
  const double alpha = std::acos(std::clamp(x1 * s2 + cos_sigma_ * std::sqrt(u1), -1.0, 1.0));  // (2.5)
  const double beta = std::acos(std::clamp(x2 * s2 - cos_sigma_ * std::sqrt(u2), -1.0, 1.0));   // (2.6)
  return alpha + beta;                                                                          // (2.4)
}

double ScissorLinkage::outer_radius_peak() const noexcept {
  return parameters_.outer_arm_length / sin_sigma_;
}

double ScissorLinkage::configuration_radius_at_outer_peak() const noexcept {
  return parameters_.outer_arm_length * cos_sigma_ / sin_sigma_;
}

double ScissorLinkage::configuration_radius_for_outer_limit(double b_limit) const noexcept {
  if (std::isnan(b_limit)) return kNaN;
  if (b_limit >= b_max_) return r_max_;
  if (outer_radius(r_min_) > b_limit) return kNaN;
  // f_b rises monotonically on [r_min, r_at_b_max] (db/dr ≥ 0 there) and reaches b_max > b_limit, so
  // the first crossing lies in that interval.
  double lo = r_min_, hi = r_at_b_max_;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (outer_radius(mid) <= b_limit) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  return lo;
}

double interference_outer_radius_limit(const DiskInterferenceParameters& disks, double bend) noexcept {
  if (!std::isfinite(bend)) return kNaN;
  const double magnitude = std::abs(bend);
  if (magnitude < 1e-12) return std::numeric_limits<double>::infinity();
  // (2.16) with Θ = −|bend| (Θ ≤ 0 when bent): b = h_d(1/Θ − 1/(2 tan(Θ/(2(1 − n_d))))) − L/Θ, which is
  // (L − h_d)/|Θ| − (h_d/2)/tan(|Θ|/(2(n_d − 1))), the form of (2.15) solved for b.
  const double theta = -magnitude;
  const double h = disks.disk_height;
  const double half_step = theta / (2.0 * (1.0 - disks.disk_count));
  return h * (1.0 / theta - 1.0 / (2.0 * std::tan(half_step))) - disks.segment_length / theta;
}

double interference_outer_radius_ratio(double packing_fraction, int disk_count, double bend) noexcept {
  if (!std::isfinite(bend) || !std::isfinite(packing_fraction)) return kNaN;
  const double magnitude = std::abs(bend);
  if (magnitude < 1e-12) return std::numeric_limits<double>::infinity();
  const double theta = -magnitude;
  const double half_step = theta / (2.0 * (1.0 - disk_count));
  return packing_fraction / disk_count * (1.0 / theta - 1.0 / (2.0 * std::tan(half_step))) -
         1.0 / theta;  // (2.18)
}

void validate(const DiskInterferenceParameters& disks) {
  auto complain = [](const std::string& what) { throw std::invalid_argument("disk interference: " + what); };
  if (!std::isfinite(disks.segment_length) || disks.segment_length <= 0.0) {
    complain("segment_length (L) must be a positive finite length in mm, got " +
             std::to_string(disks.segment_length));
  }
  if (!std::isfinite(disks.disk_height) || disks.disk_height <= 0.0) {
    complain("disk_height (h_d) must be a positive finite length in mm, got " +
             std::to_string(disks.disk_height));
  }
  if (disks.disk_count < 2) {
    complain("disk_count (n_d) must be at least 2 (a base and an end disk), got " +
             std::to_string(disks.disk_count));
  }
  if (disks.disk_count * disks.disk_height > disks.segment_length) {
    complain("the disks (n_d·h_d = " + std::to_string(disks.disk_count * disks.disk_height) +
             " mm) do not fit in the segment (L = " + std::to_string(disks.segment_length) + " mm)");
  }
}

}  // namespace tendril::teleop
