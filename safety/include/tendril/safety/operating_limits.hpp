// OperatingLimits: the limits a robot runs under now — its configured LimitSet, possibly tightened at
// run time (through parameters) but never widened. Trivially copyable, so the control thread reads
// them lock-free from a LatestValue slot; the checks are noexcept and allocation-free.
#pragma once

#include <array>
#include <cstddef>
#include <span>
#include <string>

#include "tendril/safety/limit_set.hpp"
#include "tendril/safety/safety_types.hpp"

namespace tendril::safety {

struct OperatingLimits {
  std::array<double, kMaxJoints> lower{}, upper{}, max_velocity{};
  double servo_timeout_s = 0.0;

  // The configured limits themselves.
  static OperatingLimits configured(const LimitSet& limits, double servo_timeout_s) noexcept;

  bool within_position(std::span<const double> q) const noexcept;
  bool within_velocity(std::span<const double> v) const noexcept;
  // First joint outside the operating position range (or over its velocity), -1 when none.
  int first_outside_position(std::span<const double> q) const noexcept;
  int first_over_velocity(std::span<const double> v) const noexcept;
};

// Whether `tightened` stays inside `configured` for every one of `joints` joints (and its servo
// timeout is positive and no longer); `why` names the first value that does not.
bool tightens(const OperatingLimits& tightened, const OperatingLimits& configured, std::size_t joints,
              const LimitSet& names, std::string* why = nullptr);

}  // namespace tendril::safety
