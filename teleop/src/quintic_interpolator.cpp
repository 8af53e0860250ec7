#include "tendril/teleop/quintic_interpolator.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

using Coefficients = std::array<double, 6>;

// Quintic in τ ∈ [0, 1] from (p0, v0, a0) to (pf, 0, 0) over duration T; v0 and a0 are in time units,
// so they are scaled by T and T² into τ units.
Coefficients make_coefficients(double p0, double v0, double a0, double pf, double T) noexcept {
  const double h = pf - p0;
  const double v = v0 * T;
  const double a = a0 * T * T;
  return {p0,
          v,
          0.5 * a,
          10.0 * h - 6.0 * v - 1.5 * a,
          -15.0 * h + 8.0 * v + 1.5 * a,
          6.0 * h - 3.0 * v - 0.5 * a};
}

double position(const Coefficients& b, double s) noexcept {
  return b[0] + s * (b[1] + s * (b[2] + s * (b[3] + s * (b[4] + s * b[5]))));
}
double d1(const Coefficients& b, double s) noexcept {
  return b[1] + s * (2.0 * b[2] + s * (3.0 * b[3] + s * (4.0 * b[4] + s * 5.0 * b[5])));
}
double d2(const Coefficients& b, double s) noexcept {
  return 2.0 * b[2] + s * (6.0 * b[3] + s * (12.0 * b[4] + s * 20.0 * b[5]));
}

// Roots in (0, 1) of c0 + c1 s + c2 s²; returns how many were written (sorted).
int quadratic_roots_in_unit(double c0, double c1, double c2, double out[2]) noexcept {
  int n = 0;
  const double scale = std::abs(c0) + std::abs(c1) + std::abs(c2);
  if (scale == 0.0) return 0;
  if (std::abs(c2) <= 1e-14 * scale) {
    if (std::abs(c1) > 1e-14 * scale) {
      const double r = -c0 / c1;
      if (r > 0.0 && r < 1.0) out[n++] = r;
    }
    return n;
  }
  const double disc = c1 * c1 - 4.0 * c2 * c0;
  if (disc < 0.0) return 0;
  // Numerically stable form avoids cancellation between −c1 and √disc.
  const double qq = -0.5 * (c1 + std::copysign(std::sqrt(disc), c1));
  double r[2] = {qq / c2, qq != 0.0 ? c0 / qq : qq / c2};
  if (r[0] > r[1]) std::swap(r[0], r[1]);
  for (double x : r)
    if (x > 0.0 && x < 1.0 && (n == 0 || x != out[n - 1])) out[n++] = x;
  return n;
}

// Peak |p'(s)| and |p''(s)| over s ∈ [0, 1].
void peaks(const Coefficients& b, double& peak_d1, double& peak_d2) noexcept {
  // p''' = 6 b3 + 24 b4 s + 60 b5 s²: its roots bound the monotonic pieces of p''.
  double cuts[4] = {0.0, 0.0, 0.0, 1.0};
  double roots[2];
  const int nr = quadratic_roots_in_unit(6.0 * b[3], 24.0 * b[4], 60.0 * b[5], roots);
  int nc = 1;
  for (int i = 0; i < nr; ++i) cuts[nc++] = roots[i];
  cuts[nc++] = 1.0;

  peak_d1 = std::max(std::abs(d1(b, 0.0)), std::abs(d1(b, 1.0)));
  peak_d2 = 0.0;
  for (int i = 0; i < nc; ++i) peak_d2 = std::max(peak_d2, std::abs(d2(b, cuts[i])));

  // Velocity extremes sit where p'' changes sign; p'' is monotonic on each piece, so bisect.
  for (int i = 0; i + 1 < nc; ++i) {
    double lo = cuts[i], hi = cuts[i + 1];
    double flo = d2(b, lo), fhi = d2(b, hi);
    if (flo == 0.0) {
      peak_d1 = std::max(peak_d1, std::abs(d1(b, lo)));
      continue;
    }
    if ((flo < 0.0) == (fhi < 0.0)) continue;
    for (int it = 0; it < 30; ++it) {  // τ to ~1e-9; the peak value is flat there
      const double mid = 0.5 * (lo + hi);
      const double fm = d2(b, mid);
      if ((fm < 0.0) == (flo < 0.0)) {
        lo = mid;
        flo = fm;
      } else {
        hi = mid;
      }
    }
    peak_d1 = std::max(peak_d1, std::abs(d1(b, 0.5 * (lo + hi))));
  }
}

bool all_finite(std::span<const double> v) noexcept {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}
bool all_positive(std::span<const double> v) noexcept {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x) && x > 0.0; });
}

}  // namespace

const char* to_string(RetargetStatus status) noexcept {
  switch (status) {
    case RetargetStatus::kOk:
      return "ok";
    case RetargetStatus::kInvalidArgument:
      return "invalid argument (size, non-finite value or non-positive limit)";
    case RetargetStatus::kLimitsUnreachable:
      return "velocity/acceleration limits cannot be met from the current motion state";
  }
  return "unknown";
}

QuinticInterpolator::QuinticInterpolator(std::size_t joints, double min_duration)
    : joints_(joints), min_duration_(min_duration) {
  if (joints == 0 || joints > kMaxInterpolatedJoints)
    throw std::invalid_argument("QuinticInterpolator: joint count " + std::to_string(joints) +
                                " is outside 1.." + std::to_string(kMaxInterpolatedJoints));
  if (!(min_duration > 0.0) || !std::isfinite(min_duration))
    throw std::invalid_argument(
        "QuinticInterpolator: min_duration must be a positive number of seconds, got " +
        std::to_string(min_duration));
}

void QuinticInterpolator::reset(std::span<const double> q, double t) noexcept {
  if (q.size() != joints_ || !all_finite(q) || !std::isfinite(t)) return;
  start_time_ = t;
  duration_ = 0.0;
  for (std::size_t j = 0; j < joints_; ++j) {
    coefficients_[j] = {q[j], 0.0, 0.0, 0.0, 0.0, 0.0};
    goal_[j] = q[j];
  }
}

double QuinticInterpolator::worst_limit_ratio(double T, const std::array<double, kMaxInterpolatedJoints>& q0,
                                              const std::array<double, kMaxInterpolatedJoints>& v0,
                                              const std::array<double, kMaxInterpolatedJoints>& a0,
                                              std::span<const double> goal, std::span<const double> vmax,
                                              std::span<const double> amax) const noexcept {
  double worst = 0.0;
  for (std::size_t j = 0; j < joints_; ++j) {
    const Coefficients b = make_coefficients(q0[j], v0[j], a0[j], goal[j], T);
    double pv, pa;
    peaks(b, pv, pa);
    const double v_allowed = std::max(vmax[j], std::abs(v0[j]));
    const double a_allowed = std::max(amax[j], std::abs(a0[j]));
    worst = std::max({worst, pv / T / v_allowed, pa / (T * T) / a_allowed});
  }
  return worst;
}

RetargetStatus QuinticInterpolator::retarget(double t_now, std::span<const double> goal,
                                             std::span<const double> max_velocity,
                                             std::span<const double> max_acceleration) noexcept {
  if (goal.size() != joints_ || max_velocity.size() != joints_ || max_acceleration.size() != joints_ ||
      !std::isfinite(t_now) || !all_finite(goal) || !all_positive(max_velocity) ||
      !all_positive(max_acceleration))
    return RetargetStatus::kInvalidArgument;

  std::array<double, kMaxInterpolatedJoints> q0{}, v0{}, a0{};
  sample(t_now, {q0.data(), joints_}, {v0.data(), joints_}, {a0.data(), joints_});

  bool start_exceeds = false;
  for (std::size_t j = 0; j < joints_; ++j)
    start_exceeds |= std::abs(v0[j]) > max_velocity[j] || std::abs(a0[j]) > max_acceleration[j];

  // Feasibility is not monotonic in T when the segment inherits motion (a long segment lets an
  // inherited acceleration build up speed), so scan a geometric grid for the first feasible T and
  // then bisect between it and the previous infeasible one.
  constexpr double kTolerance = 1e-9;
  constexpr double kGrowth = 1.5;
  auto ratio = [&](double T) {
    return worst_limit_ratio(T, q0, v0, a0, goal, max_velocity, max_acceleration);
  };

  bool at_rest = true;
  for (std::size_t j = 0; j < joints_; ++j) at_rest &= v0[j] == 0.0 && a0[j] == 0.0;

  double best_T = min_duration_;
  double best_ratio = 0.0;
  double chosen = -1.0;
  if (at_rest) {
    // Rest to rest (the common case: a goal arrives while holding) has peaks |v| = 15/8·|h|/T and
    // |a| = 10/√3·|h|/T², so the shortest duration is known in closed form.
    chosen = min_duration_;
    for (std::size_t j = 0; j < joints_; ++j) {
      const double h = std::abs(goal[j] - q0[j]);
      chosen = std::max(
          {chosen, 1.875 * h / max_velocity[j], std::sqrt(10.0 / std::sqrt(3.0) * h / max_acceleration[j])});
    }
  } else if ((best_ratio = ratio(min_duration_)) <= 1.0 + kTolerance) {
    chosen = min_duration_;
  } else {
    // Integer-counted grid (CERT FLP30): 2048 steps of x1.5 reach kMaxDuration even from the smallest
    // positive double, so the T bound below always ends the scan first.
    constexpr int kMaxGridSteps = 2048;
    double prev = min_duration_;
    for (int step = 1; step <= kMaxGridSteps; ++step) {
      const double T = prev * kGrowth;
      if (T > kMaxDuration * kGrowth) break;
      const double r = ratio(T);
      if (r < best_ratio) {
        best_ratio = r;
        best_T = T;
      }
      if (r <= 1.0 + kTolerance) {
        double lo = prev, hi = T;
        while (hi - lo > 1e-5 * hi) {
          const double mid = 0.5 * (lo + hi);
          (ratio(mid) <= 1.0 + kTolerance ? hi : lo) = mid;
        }
        chosen = hi;
        break;
      }
      prev = T;
    }
  }
  const bool feasible = chosen > 0.0;
  const double T = feasible ? chosen : best_T;

  start_time_ = t_now;
  duration_ = T;
  for (std::size_t j = 0; j < joints_; ++j) {
    coefficients_[j] = make_coefficients(q0[j], v0[j], a0[j], goal[j], T);
    goal_[j] = goal[j];
  }
  return (feasible && !start_exceeds) ? RetargetStatus::kOk : RetargetStatus::kLimitsUnreachable;
}

RetargetStatus QuinticInterpolator::retarget(double t_now, std::span<const double> goal, double max_velocity,
                                             double max_acceleration) noexcept {
  std::array<double, kMaxInterpolatedJoints> vmax, amax;
  vmax.fill(max_velocity);
  amax.fill(max_acceleration);
  if (goal.size() > kMaxInterpolatedJoints) return RetargetStatus::kInvalidArgument;
  return retarget(t_now, goal, {vmax.data(), goal.size()}, {amax.data(), goal.size()});
}

void QuinticInterpolator::sample(double t, std::span<double> q, std::span<double> qd,
                                 std::span<double> qdd) const noexcept {
  if (q.size() < joints_ || qd.size() < joints_ || qdd.size() < joints_) return;
  if (duration_ <= 0.0 || !(t < start_time_ + duration_)) {
    // Finished (or NaN time): hold the goal at rest.
    for (std::size_t j = 0; j < joints_; ++j) {
      q[j] = goal_[j];
      qd[j] = 0.0;
      qdd[j] = 0.0;
    }
    return;
  }
  const double s = std::max(0.0, (t - start_time_) / duration_);
  const double inv_T = 1.0 / duration_;
  for (std::size_t j = 0; j < joints_; ++j) {
    const Coefficients& b = coefficients_[j];
    q[j] = position(b, s);
    qd[j] = d1(b, s) * inv_T;
    qdd[j] = d2(b, s) * inv_T * inv_T;
  }
}

}  // namespace tendril::teleop
