// Pid: the per-joint low-level position controller (Abah 2022, §4.7, 1 kHz PID on q_des − q_cur).
// Derivative acts on the measurement (no kick on setpoint steps) through a first-order filter; the
// integrator is protected against wind-up while the output saturates, either by conditional
// integration or by back-calculation. update() is noexcept and allocation-free.
#pragma once

namespace tendril::teleop {

enum class AntiWindup {
  kNone,             // plain integration (only the integral limit bounds it)
  kConditional,      // stop integrating while saturated and the error pushes further into saturation
  kBackCalculation,  // bleed the integrator by tracking_gain · (saturated − unsaturated output)
};

const char* to_string(AntiWindup mode) noexcept;

struct PidGains {
  double kp = 0.0;
  double ki = 0.0;                      // per second
  double kd = 0.0;                      // seconds
  double integral_limit = 1e300;        // bound on the integral term, in output units
  double output_limit = 1e300;          // output is clamped to ±output_limit
  double derivative_filter_time = 0.0;  // first-order filter time constant on the derivative (s); 0 = none
  AntiWindup anti_windup = AntiWindup::kConditional;
  double tracking_gain = 0.0;  // back-calculation gain (1/s); 0 picks ki/kp (or 1/s without kp)
};

class Pid {
 public:
  Pid() = default;
  // Throws std::invalid_argument when a gain is negative or non-finite or a limit is not positive.
  explicit Pid(const PidGains& gains);

  // One control step: returns the clamped output. A non-finite input or dt ≤ 0 leaves the state
  // untouched and returns 0 (no drive effort) — the safe choice for a corrupted sample.
  // feed_forward is added to the output before the limit (e.g. kd·v_desired plus friction
  // compensation), so saturation and anti-windup account for it.
  double update(double setpoint, double measurement, double dt, double feed_forward = 0.0) noexcept;

  void reset() noexcept;

  const PidGains& gains() const noexcept { return gains_; }
  double integral() const noexcept { return integral_; }
  double filtered_derivative() const noexcept { return derivative_; }
  bool saturated() const noexcept { return saturated_; }
  double last_output() const noexcept { return output_; }

 private:
  PidGains gains_{};
  double integral_ = 0.0;    // integral term in output units (already multiplied by ki)
  double derivative_ = 0.0;  // filtered d(−measurement)/dt
  double previous_measurement_ = 0.0;
  bool has_previous_ = false;
  bool saturated_ = false;
  double output_ = 0.0;
};

}  // namespace tendril::teleop
