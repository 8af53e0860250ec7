#include "tendril/teleop/pid.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

const char* to_string(AntiWindup mode) noexcept {
  switch (mode) {
    case AntiWindup::kNone:
      return "none";
    case AntiWindup::kConditional:
      return "conditional integration";
    case AntiWindup::kBackCalculation:
      return "back-calculation";
  }
  return "unknown";
}

Pid::Pid(const PidGains& gains) : gains_(gains) {
  auto require = [](bool ok, const char* what, double value) {
    if (!ok) throw std::invalid_argument(std::string("Pid: ") + what + ", got " + std::to_string(value));
  };
  auto non_negative = [](double x) { return std::isfinite(x) && x >= 0.0; };
  require(non_negative(gains.kp), "kp must be a finite number >= 0", gains.kp);
  require(non_negative(gains.ki), "ki must be a finite number >= 0", gains.ki);
  require(non_negative(gains.kd), "kd must be a finite number >= 0", gains.kd);
  require(gains.integral_limit > 0.0, "integral_limit must be > 0", gains.integral_limit);
  require(gains.output_limit > 0.0, "output_limit must be > 0", gains.output_limit);
  require(non_negative(gains.derivative_filter_time), "derivative_filter_time must be >= 0 s",
          gains.derivative_filter_time);
  require(non_negative(gains.tracking_gain), "tracking_gain must be >= 0", gains.tracking_gain);
}

void Pid::reset() noexcept {
  integral_ = 0.0;
  derivative_ = 0.0;
  previous_measurement_ = 0.0;
  has_previous_ = false;
  saturated_ = false;
  output_ = 0.0;
}

double Pid::update(double setpoint, double measurement, double dt, double feed_forward) noexcept {
  if (!std::isfinite(setpoint) || !std::isfinite(measurement) || !std::isfinite(dt) || dt <= 0.0 ||
      !std::isfinite(feed_forward)) {
    output_ = 0.0;
    return 0.0;
  }
  const double error = setpoint - measurement;

  // Derivative on measurement: a setpoint step does not kick the output.
  if (has_previous_) {
    const double raw = -(measurement - previous_measurement_) / dt;
    const double alpha = dt / (gains_.derivative_filter_time + dt);
    derivative_ += alpha * (raw - derivative_);
  }
  previous_measurement_ = measurement;
  has_previous_ = true;

  const double limit = gains_.output_limit;
  const double proportional = gains_.kp * error;
  // Feed-forward joins the damping term so saturation and anti-windup see the whole output.
  const double damping = gains_.kd * derivative_ + feed_forward;
  const double integral_step = gains_.ki * error * dt;

  switch (gains_.anti_windup) {
    case AntiWindup::kNone:
      integral_ += integral_step;
      break;
    case AntiWindup::kConditional: {
      const double trial = integral_ + integral_step;
      const double unsaturated = proportional + trial + damping;
      // Integrate unless the output saturates and the step would push it deeper into saturation.
      const bool pushes_deeper =
          (unsaturated > limit && integral_step > 0.0) || (unsaturated < -limit && integral_step < 0.0);
      if (!pushes_deeper) integral_ = trial;
      break;
    }
    case AntiWindup::kBackCalculation: {
      const double unsaturated = proportional + integral_ + damping;
      const double saturated = std::clamp(unsaturated, -limit, limit);
      double kt = gains_.tracking_gain;
      if (kt == 0.0) kt = gains_.kp > 0.0 ? gains_.ki / gains_.kp : 1.0;
      integral_ += integral_step + kt * (saturated - unsaturated) * dt;
      break;
    }
  }
  integral_ = std::clamp(integral_, -gains_.integral_limit, gains_.integral_limit);

  const double unsaturated = proportional + integral_ + damping;
  output_ = std::clamp(unsaturated, -limit, limit);
  saturated_ = output_ != unsaturated;
  return output_;
}

}  // namespace tendril::teleop
