// QuinticInterpolator: joint-space point-to-point interpolation (Abah 2022, §4.7.1).
// Each retarget starts a quintic segment from the currently sampled position, velocity and
// acceleration and ends at rest on the goal, with one duration for all joints chosen as the shortest
// one that keeps every joint within its velocity and acceleration limits. Storage is fixed-size, so
// retarget/sample run in the control tick without allocating.
#pragma once

#include <array>
#include <cstddef>
#include <span>

namespace tendril::teleop {

// Upper bound on joints per interpolator; robots declare their own count at construction.
inline constexpr std::size_t kMaxInterpolatedJoints = 16;

enum class RetargetStatus {
  kOk,                 // new segment within all limits
  kInvalidArgument,    // wrong size, non-finite goal or time, non-positive limits: segment unchanged
  kLimitsUnreachable,  // the inherited velocity/acceleration already exceeds a limit or no duration
                       // up to kMaxDuration meets them; the least-violating duration was used
};

const char* to_string(RetargetStatus status) noexcept;

class QuinticInterpolator {
 public:
  // Longest segment considered by the duration search (s).
  static constexpr double kMaxDuration = 3600.0;

  // joints in [1, kMaxInterpolatedJoints]; min_duration > 0 (s). Throws std::invalid_argument.
  explicit QuinticInterpolator(std::size_t joints, double min_duration = 0.01);

  // Hold at q with zero velocity and acceleration (segment of zero length starting at t).
  void reset(std::span<const double> q, double t = 0.0) noexcept;

  // Start a new segment at t_now towards goal. Limits are per joint (same size as goal).
  RetargetStatus retarget(double t_now, std::span<const double> goal, std::span<const double> max_velocity,
                          std::span<const double> max_acceleration) noexcept;
  // Same limits for every joint.
  RetargetStatus retarget(double t_now, std::span<const double> goal, double max_velocity,
                          double max_acceleration) noexcept;

  // Position, velocity and acceleration at time t (before the segment start: its start state; after
  // its end: the goal at rest). Output spans must have size joints(); smaller ones are left untouched.
  void sample(double t, std::span<double> q, std::span<double> qd, std::span<double> qdd) const noexcept;

  // Shifts the segment `dt` later (dt > 0 and finite; anything else is ignored): after the control
  // loop lost dt, the motion continues from where it stood instead of jumping ahead.
  void delay(double dt) noexcept {
    if (dt > 0.0 && dt < kMaxDuration) start_time_ += dt;
  }

  bool done(double t) const noexcept { return t >= start_time_ + duration_; }
  double duration() const noexcept { return duration_; }
  double start_time() const noexcept { return start_time_; }
  std::span<const double> goal() const noexcept { return {goal_.data(), joints_}; }
  std::size_t joints() const noexcept { return joints_; }
  double min_duration() const noexcept { return min_duration_; }

 private:
  // Coefficients of q(τ) = Σ b_k τ^k, τ = (t − t0)/T ∈ [0, 1].
  using Coefficients = std::array<double, 6>;

  // Largest ratio of peak |velocity| / limit and peak |acceleration| / limit over all joints when
  // the segment lasts T. Start values that already exceed a limit are excused (they cannot change).
  double worst_limit_ratio(double T, const std::array<double, kMaxInterpolatedJoints>& q0,
                           const std::array<double, kMaxInterpolatedJoints>& v0,
                           const std::array<double, kMaxInterpolatedJoints>& a0, std::span<const double> goal,
                           std::span<const double> vmax, std::span<const double> amax) const noexcept;

  std::size_t joints_;
  double min_duration_;
  double start_time_ = 0.0;
  double duration_ = 0.0;
  std::array<Coefficients, kMaxInterpolatedJoints> coefficients_{};
  std::array<double, kMaxInterpolatedJoints> goal_{};
};

}  // namespace tendril::teleop
