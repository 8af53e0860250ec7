// Steerable-catheter parts of the control cycle (real-time thread: no allocation, locks or blocking):
// spring-deflection supervision, the configuration, active-compliance and telemanipulation modes of
// the mid-level controller (seed 000 §4.7), and the ways out of a hold: retraction, relaxing the
// springs, and resume only once the cause has cleared.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "catheter_unit.hpp"
#include "robot_runtime_impl.hpp"

namespace tendril::server {

namespace {

using safety::OperatingState;

constexpr std::size_t kJoints = 4;
constexpr std::int64_t kAnalogJoystickStaleNs = 100'000'000;
constexpr double kRelaxSettleS = 0.1;  // relaxed: both springs within half the resume bound this long
// A bus silent for this long no longer keeps its last readings fresh (its drives' heartbeat
// consumers fault the robot well before: 250 ms for the SRMC).
constexpr std::int64_t kSilentBusNs = 1'000'000'000;

// Age of a reading stamped by the bus thread, on the bus thread's own clock: from the reading to the
// newest frame heard on that bus. A stall of the bus or control thread (or of the whole machine)
// delays every frame alike and leaves this age alone; a node that falls silent while the drives
// keep talking makes it grow. Past kSilentBusNs of silence on the whole bus, the wall clock counts.
std::int64_t reading_age_ns(const CatheterUnit& c, std::int64_t stamp_ns, std::int64_t now_ns) noexcept {
  const std::int64_t heard = c.bus_heard_ns.load(std::memory_order_relaxed);
  return std::max(heard - stamp_ns, now_ns - stamp_ns - kSilentBusNs);
}

// Velocity per joint from the joystick sources whose deadman is held. Exactly one such source moves
// the robot; two at once cancel (two hands on one catheter is a conflict, not a sum).
void joystick_velocity(RobotUnit& r, double t, std::int64_t now_ns, std::array<double, kJoints>& v) noexcept {
  auto& s = r.rt;
  auto& c = *r.catheter;
  std::array<double, kJoints> axes{};
  int held = 0;
  JoystickSource source = JoystickSource::none;
  auto take = [&](JoystickSource from, const std::array<double, kJoints>& a) {
    ++held;
    source = from;
    axes = a;
  };
  if (s.console_deadman && s.console_time >= 0 && t - s.console_time <= s.limits.servo_timeout_s)
    take(JoystickSource::console, s.console_axes);
  if (c.evdev) {
    const auto st = c.evdev->state();
    if (st.connected && st.deadman) {
      std::array<double, kJoints> a{};
      for (std::size_t j = 0; j < kJoints; ++j)
        if (c.evdev_output[j] >= 0) a[j] = st.outputs[static_cast<std::size_t>(c.evdev_output[j])];
      take(JoystickSource::evdev, a);
    }
  }
  if (c.joystick_receiver) {
    const auto st = c.analog_joystick.load();
    if (st.connected && st.deadman && reading_age_ns(c, st.stamp_ns, now_ns) <= kAnalogJoystickStaleNs)
      take(JoystickSource::analog, {0.0, st.outputs[0], st.outputs[1], st.outputs[2]});  // roll, prox, distal
  }
  s.joystick_conflict = held > 1;
  s.joystick_source = held == 1 ? static_cast<std::uint8_t>(source) : 0;
  s.joystick_deadman = held > 0;
  for (std::size_t j = 0; j < kJoints; ++j) {
    const double a = held == 1 && std::isfinite(axes[j]) ? std::clamp(axes[j], -1.0, 1.0) : 0.0;
    s.joystick_axes[j] = a;
    v[j] = a * c.settings.telemanipulation_max_speed[j];
  }
}

}  // namespace

const char* to_string(RelaxOutcome outcome) noexcept {
  switch (outcome) {
    case RelaxOutcome::running:
      return "running";
    case RelaxOutcome::relaxed:
      return "relaxed";
    case RelaxOutcome::timed_out:
      return "timed_out";
    case RelaxOutcome::at_limit:
      return "at_limit";
    case RelaxOutcome::sensor_stale:
      return "sensor_stale";
    case RelaxOutcome::stopped:
      return "stopped";
    case RelaxOutcome::none:
      break;
  }
  return "none";
}

const char* to_string(JoystickSource source) noexcept {
  switch (source) {
    case JoystickSource::console:
      return "console";
    case JoystickSource::evdev:
      return "evdev";
    case JoystickSource::analog:
      return "analog";
    case JoystickSource::none:
      break;
  }
  return "none";
}

void RobotRuntime::Impl::catheter_sensors(RobotUnit& r, double t, OperatingState state) noexcept {
  auto& s = r.rt;
  auto& c = *r.catheter;
  const auto reading = c.deflection.load();
  const auto stale_ns = static_cast<std::int64_t>(c.settings.deflection.stale_ms * 1e6);
  s.deflection_fresh = reading.valid && reading_age_ns(c, reading.stamp_ns, now_ns) <= stale_ns;
  s.spring_deflection = s.deflection_fresh ? reading.mm : std::array<double, 2>{};
  if (s.relaxing && state != OperatingState::kPaused) {  // resumed, disabled, faulted or e-stopped
    s.relaxing = false;
    s.relax_outcome = RelaxOutcome::stopped;
  }
  if (state != OperatingState::kPaused) s.withdrawing = false;
  if (state != OperatingState::kEnabled || !s.drives_ready) return;
  auto held = [&](safety::FaultCode code, int joint, const char* detail) {
    if (!r.supervisor->hold(t, code, joint, detail)) return;
    s.hold_code = code;
    s.retraction_only = c.settings.retraction_only_while_held;
    s.relax_outcome = RelaxOutcome::none;
    s.servo_active = false;
    s.console_deadman = false;
    c.configuration->reset(t, Eigen::Vector4d(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]));
    r.interpolator->reset({s.q_des.data(), r.n}, t);
  };
  if (!s.deflection_fresh) {
    char detail[80];
    std::snprintf(detail, sizeof detail, "no valid spring-deflection reading from node 0x%02X for %.0f ms",
                  c.settings.deflection.node_id, c.settings.deflection.stale_ms);
    held(safety::FaultCode::kSensorStale, -1, detail);
    return;
  }
  for (std::size_t i = 0; i < 2; ++i) {
    if (std::abs(s.spring_deflection[i]) <= c.settings.deflection.limit_mm) continue;
    char detail[80];
    std::snprintf(detail, sizeof detail, "%.2f mm, bound %.2f mm", s.spring_deflection[i],
                  c.settings.deflection.limit_mm);
    held(safety::FaultCode::kSpringDeflection, static_cast<int>(2 + i), detail);
    return;
  }
}

void RobotRuntime::Impl::catheter_mid_level(RobotUnit& r, double t) noexcept {
  auto& s = r.rt;
  auto& c = *r.catheter;
  std::array<double, kJoints> v{};
  switch (s.mode) {
    case ControlMode::configuration: {
      Eigen::Vector4d q(s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]), qd;
      if (!c.configuration->step(t, period, q, qd)) {
        // Singular map (a segment at a bend where the model has no slope): hold where we are.
        c.configuration->reset(t, q);
        qd.setZero();
      }
      for (std::size_t j = 0; j < kJoints; ++j) {
        s.q_des[j] = q[static_cast<Eigen::Index>(j)];
        s.qd_des[j] = qd[static_cast<Eigen::Index>(j)];
      }
      break;
    }
    case ControlMode::active_compliance: {
      // Insertion and roll from the operator (servo stream or joystick), bends from eq. 4.24.
      const bool servo =
          s.servo_active && r.supervisor->servo_live() && t - s.last_servo_time <= s.limits.servo_timeout_s;
      if (servo) {
        v[0] = s.servo_velocity[0];
        v[1] = s.servo_velocity[1];
      } else {
        s.servo_active = false;
        joystick_velocity(r, t, now_ns, v);
      }
      for (std::size_t j = 0; j < 2; ++j) {
        s.qd_des[j] = v[j];
        s.q_des[j] += v[j] * period;
      }
      // Eq. 4.24 adds the increments to q_cur. Here q_cur is the previous setpoint, not the encoder:
      // the drive's position loop lags its setpoint, and re-basing on the lagging encoder every tick
      // caps the admittance speed at what that lag allows (0.4 mm/s instead of v_max = 2 mm/s in the
      // simulated channel).
      const std::array<double, kJoints> current{s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]};
      teleop::apply_active_compliance(c.settings.compliance, current, s.spring_deflection, period,
                                      {s.q_des.data(), kJoints});
      for (std::size_t i = 2; i < kJoints; ++i) s.qd_des[i] = (s.q_des[i] - current[i]) / period;
      break;
    }
    case ControlMode::telemanipulation: {
      joystick_velocity(r, t, now_ns, v);
      for (std::size_t j = 0; j < kJoints; ++j) {
        s.qd_des[j] = v[j];
        s.q_des[j] += v[j] * period;
      }
      break;
    }
    case ControlMode::joint:
    case ControlMode::path_following:
      return;
  }
  // Joint mode takes over from wherever these modes left the setpoint.
  r.interpolator->reset({s.q_des.data(), r.n}, t);
}

void RobotRuntime::Impl::catheter_retraction(RobotUnit& r, double t) noexcept {
  // Held after a limit: the operator may withdraw the catheter (insertion only, never forward), from
  // the servo stream, a joystick or a requested distance; everything else stays where it is.
  auto& s = r.rt;
  std::array<double, kJoints> v{};
  if (s.servo_active && t - s.last_servo_time <= s.limits.servo_timeout_s) {
    v[0] = s.servo_velocity[0];
  } else {
    s.servo_active = false;
    joystick_velocity(r, t, now_ns, v);
  }
  double withdraw = std::min(v[0], 0.0);
  if (s.withdrawing) {
    // A requested distance goes at the joystick's full insertion speed and stops on the millimetre.
    const double remaining = s.q_des[0] - s.withdraw_to;
    const double speed =
        std::min(r.catheter->settings.telemanipulation_max_speed[0], s.limits.max_velocity[0]);
    if (remaining <= 1e-9 || speed <= 0.0)
      s.withdrawing = false;
    else
      withdraw = std::min(withdraw, -std::min(speed, remaining / period));
  }
  s.qd_des[0] = withdraw;
  s.q_des[0] += withdraw * period;
  r.interpolator->reset({s.q_des.data(), r.n}, t);
}

void RobotRuntime::Impl::catheter_start_relax(RobotUnit& r, double t) noexcept {
  auto& s = r.rt;
  if (r.supervisor->state() != OperatingState::kPaused || !s.drives_ready || !s.deflection_fresh) return;
  s.relaxing = true;
  s.relax_started = t;
  s.relax_settled_s = 0.0;
  s.relax_outcome = RelaxOutcome::running;
  char text[96];
  std::snprintf(text, sizeof text, "relax: bend drives follow their springs (%.2f, %.2f mm) down to %.2f mm",
                s.spring_deflection[0], s.spring_deflection[1],
                0.5 * r.catheter->settings.deflection.resume_mm);
  r.supervisor->record(t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1, text);
}

void RobotRuntime::Impl::catheter_relax(RobotUnit& r, double t) noexcept {
  auto& s = r.rt;
  if (!s.relaxing) return;
  const auto& d = r.catheter->settings.deflection;
  char text[96];
  auto end = [&](RelaxOutcome outcome) {
    s.relaxing = false;
    s.relax_outcome = outcome;
    s.qd_des[2] = s.qd_des[3] = 0.0;
    r.supervisor->record(t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1, text);
  };
  if (!s.deflection_fresh) {
    std::snprintf(text, sizeof text, "relax stopped: no valid spring-deflection reading");
    return end(RelaxOutcome::sensor_stale);
  }
  // Relax goes on to half the resume bound and stays there for 100 ms, so the spring settling after
  // the drives stop (the carriage is damped, the wall still pushes) does not take it back over.
  const double worst = std::max(std::abs(s.spring_deflection[0]), std::abs(s.spring_deflection[1]));
  s.relax_settled_s = worst <= 0.5 * d.resume_mm ? s.relax_settled_s + period : 0.0;
  if (s.relax_settled_s >= kRelaxSettleS) {
    std::snprintf(text, sizeof text, "springs relaxed (%.2f mm, resume bound %.2f mm): resume is possible",
                  worst, d.resume_mm);
    return end(RelaxOutcome::relaxed);
  }
  if (t - s.relax_started > d.relax_timeout_s) {
    std::snprintf(text, sizeof text, "relax stopped after %.0f s with %.2f mm left (resume bound %.2f mm)",
                  d.relax_timeout_s, worst, d.resume_mm);
    return end(RelaxOutcome::timed_out);
  }
  // Eqs. 4.24–4.26 on the bend drives only; insertion and roll stay (or withdraw, see retraction).
  const std::array<double, kJoints> current{s.q_des[0], s.q_des[1], s.q_des[2], s.q_des[3]};
  teleop::apply_active_compliance(r.catheter->settings.compliance, current, s.spring_deflection, period,
                                  {s.q_des.data(), kJoints});
  for (std::size_t i = 2; i < kJoints; ++i) {
    const auto& j = r.config.joints[i];
    const double lo = std::max(j.lower + j.soft_margin, s.limits.lower[i]);
    const double hi = std::min(j.upper - j.soft_margin, s.limits.upper[i]);
    if ((s.q_des[i] < lo && s.q_des[i] < current[i]) || (s.q_des[i] > hi && s.q_des[i] > current[i])) {
      s.q_des[i] = current[i];
      std::snprintf(text, sizeof text, "relax stopped: drive '%s' at its limit with %.2f mm left; withdraw",
                    j.name.c_str(), worst);
      return end(RelaxOutcome::at_limit);
    }
    s.qd_des[i] = (s.q_des[i] - current[i]) / period;
  }
  r.interpolator->reset({s.q_des.data(), r.n}, t);
}

bool RobotRuntime::Impl::catheter_may_resume(RobotUnit& r, double t) noexcept {
  const auto& s = r.rt;
  const auto& d = r.catheter->settings.deflection;
  char text[96];
  if (!s.deflection_fresh) {
    std::snprintf(text, sizeof text, "resume refused: no valid spring-deflection reading from node 0x%02X",
                  d.node_id);
    r.supervisor->record(t, safety::EventKind::kRefused, safety::FaultCode::kSensorStale, -1, text);
    return false;
  }
  const int worst = std::abs(s.spring_deflection[0]) >= std::abs(s.spring_deflection[1]) ? 0 : 1;
  const double value = std::abs(s.spring_deflection[static_cast<std::size_t>(worst)]);
  const double bound = s.hold_code == safety::FaultCode::kSpringDeflection ? d.resume_mm : d.limit_mm;
  if (value <= bound) return true;
  std::snprintf(text, sizeof text,
                "resume refused: spring deflected %.2f mm, over %.2f mm; relax or withdraw", value, bound);
  r.supervisor->record(t, safety::EventKind::kRefused, safety::FaultCode::kSpringDeflection, 2 + worst, text);
  return false;
}

bool RobotRuntime::Impl::holding(const RobotUnit& r, double t) const noexcept {
  const auto& s = r.rt;
  if (s.enable_pending || s.goal_pending || s.servo_active || !r.interpolator->done(t)) return false;
  if (!r.catheter) return true;
  if (s.relaxing || s.withdrawing) return false;
  if (s.mode == ControlMode::configuration && !r.catheter->configuration->done(t)) return false;
  // A joystick whose deadman is held is driving the robot.
  return !(s.mode == ControlMode::telemanipulation || s.mode == ControlMode::active_compliance) ||
         !s.joystick_deadman;
}

}  // namespace tendril::server
