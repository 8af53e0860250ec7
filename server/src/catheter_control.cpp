// Steerable-catheter parts of the control cycle (real-time thread: no allocation, locks or blocking):
// spring-deflection supervision, the configuration, active-compliance and telemanipulation modes of
// the mid-level controller (seed 000 §4.7), and retraction while held.
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
  if (state != OperatingState::kEnabled || !s.drives_ready) return;
  auto held = [&](safety::FaultCode code, int joint, const char* detail) {
    if (!r.supervisor->hold(t, code, joint, detail)) return;
    s.hold_code = code;
    s.retraction_only = c.settings.retraction_only_while_held;
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
  // the servo stream or a joystick; everything else stays where it is.
  auto& s = r.rt;
  std::array<double, kJoints> v{};
  if (s.servo_active && t - s.last_servo_time <= s.limits.servo_timeout_s) {
    v[0] = s.servo_velocity[0];
  } else {
    s.servo_active = false;
    joystick_velocity(r, t, now_ns, v);
  }
  const double withdraw = std::min(v[0], 0.0);
  s.qd_des[0] = withdraw;
  s.q_des[0] += withdraw * period;
  r.interpolator->reset({s.q_des.data(), r.n}, t);
}

bool RobotRuntime::Impl::holding(const RobotUnit& r, double t) const noexcept {
  const auto& s = r.rt;
  if (s.enable_pending || s.goal_pending || s.servo_active || !r.interpolator->done(t)) return false;
  if (!r.catheter) return true;
  if (s.mode == ControlMode::configuration && !r.catheter->configuration->done(t)) return false;
  // A joystick whose deadman is held is driving the robot.
  return !(s.mode == ControlMode::telemanipulation || s.mode == ControlMode::active_compliance) ||
         !s.joystick_deadman;
}

}  // namespace tendril::server
