// The steerable catheter's part of the control cycle (real-time thread: no allocation, locks or
// blocking): spring-deflection supervision, the configuration, active-compliance and telemanipulation
// modes of the mid-level controller (Abah 2022, §4.7), and the ways out of a hold: retraction, relaxing
// the springs, and resume only once the cause has cleared.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "steerable_catheter/catheter_robot.hpp"
#include "steerable_catheter/image_guidance.hpp"

namespace tendril::server {

namespace {

using safety::OperatingState;

constexpr std::size_t kJoints = 4;
constexpr std::int64_t kAnalogJoystickStaleNs = 100'000'000;
constexpr double kRelaxSettleS = 0.1;  // relaxed: both springs within half the resume bound this long
// A bus silent for this long no longer keeps its last readings fresh (its drives' heartbeat
// consumers fault the robot well before: 250 ms for the SRMC).
constexpr std::int64_t kSilentBusNs = 1'000'000'000;

Eigen::Vector4d vec4(std::span<const double> q) { return {q[0], q[1], q[2], q[3]}; }

}  // namespace

// Age of a reading stamped by the bus thread, on the bus thread's own clock: from the reading to the
// newest frame heard on that bus. A stall of the bus or control thread (or of the whole machine)
// delays every frame alike and leaves this age alone; a node that falls silent while the drives
// keep talking makes it grow. Past kSilentBusNs of silence on the whole bus, the wall clock counts.
std::int64_t CatheterController::reading_age_ns(std::int64_t stamp_ns, std::int64_t now_ns) const noexcept {
  const std::int64_t heard = robot_.bus_heard_ns_.load(std::memory_order_relaxed);
  return std::max(heard - stamp_ns, now_ns - stamp_ns - kSilentBusNs);
}

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

// Velocity per joint from the joystick sources whose deadman is held. Exactly one such source moves
// the robot; two at once cancel (two hands on one catheter is a conflict, not a sum).
void CatheterController::joystick_velocity(const ControlContext& ctx,
                                           std::array<double, kJoints>& v) noexcept {
  std::array<double, kJoints> axes{};
  int held = 0;
  JoystickSource source = JoystickSource::none;
  auto take = [&](JoystickSource from, const std::array<double, kJoints>& a) {
    ++held;
    source = from;
    axes = a;
  };
  if (console_deadman_ && console_time_ >= 0 && ctx.t - console_time_ <= ctx.limits->servo_timeout_s)
    take(JoystickSource::console, console_axes_);
  if (robot_.evdev_) {
    const auto st = robot_.evdev_->state();
    if (st.connected && st.deadman) {
      std::array<double, kJoints> a{};
      for (std::size_t j = 0; j < kJoints; ++j)
        if (robot_.evdev_output_[j] >= 0)
          a[j] = st.outputs[static_cast<std::size_t>(robot_.evdev_output_[j])];
      take(JoystickSource::evdev, a);
    }
  }
  if (robot_.joystick_receiver_) {
    const auto st = robot_.analog_joystick_.load();
    if (st.connected && st.deadman && reading_age_ns(st.stamp_ns, ctx.now_ns) <= kAnalogJoystickStaleNs)
      take(JoystickSource::analog, {0.0, st.outputs[0], st.outputs[1], st.outputs[2]});  // roll, prox, distal
  }
  joystick_conflict_ = held > 1;
  joystick_source_ = held == 1 ? source : JoystickSource::none;
  joystick_deadman_ = held > 0;
  for (std::size_t j = 0; j < kJoints; ++j) {
    const double a = held == 1 && std::isfinite(axes[j]) ? std::clamp(axes[j], -1.0, 1.0) : 0.0;
    joystick_axes_[j] = a;
    v[j] = a * robot_.settings_.telemanipulation_max_speed[j];
  }
}

void CatheterController::sense(ControlContext& ctx) noexcept {
  const auto& settings = robot_.settings_;
  const auto reading = robot_.deflection_.load();
  const auto stale_ns = static_cast<std::int64_t>(settings.deflection.stale_ms * 1e6);
  deflection_fresh_ = reading.valid && reading_age_ns(reading.stamp_ns, ctx.now_ns) <= stale_ns;
  spring_deflection_ = deflection_fresh_ ? reading.mm : std::array<double, 2>{};
  if (relaxing_ && ctx.state != OperatingState::kPaused) {  // resumed, disabled, faulted or e-stopped
    relaxing_ = false;
    relax_outcome_ = RelaxOutcome::stopped;
  }
  if (ctx.state != OperatingState::kPaused) withdrawing_ = false;
  if (ctx.state != OperatingState::kEnabled || !ctx.drives_ready) return;
  auto held = [&](safety::FaultCode code, int joint, const char* detail) {
    if (!ctx.hold(code, joint, detail)) return;
    console_deadman_ = false;
    retraction_only_ = settings.retraction_only_while_held;
    relax_outcome_ = RelaxOutcome::none;
  };
  if (!deflection_fresh_) {
    char detail[80];
    std::snprintf(detail, sizeof detail, "no valid spring-deflection reading from node 0x%02X for %.0f ms",
                  settings.deflection.node_id, settings.deflection.stale_ms);
    held(safety::FaultCode::kSensorStale, -1, detail);
    return;
  }
  for (std::size_t i = 0; i < 2; ++i) {
    if (std::abs(spring_deflection_[i]) <= settings.deflection.limit_mm) continue;
    char detail[80];
    std::snprintf(detail, sizeof detail, "%.2f mm, bound %.2f mm", spring_deflection_[i],
                  settings.deflection.limit_mm);
    held(safety::FaultCode::kSpringDeflection, static_cast<int>(2 + i), detail);
    return;
  }
}

void CatheterController::control(ControlContext& ctx) noexcept {
  auto& configuration = *robot_.configuration_;
  std::array<double, kJoints> v{};
  switch (ctx.mode) {
    case kConfigurationMode: {
      Eigen::Vector4d q = vec4(ctx.q_des), qd;
      if (!configuration.step(ctx.t, ctx.period, q, qd)) {
        // Singular map (a segment at a bend where the model has no slope): hold where we are.
        configuration.reset(ctx.t, q);
        qd.setZero();
      }
      for (std::size_t j = 0; j < kJoints; ++j) {
        ctx.q_des[j] = q[static_cast<Eigen::Index>(j)];
        ctx.qd_des[j] = qd[static_cast<Eigen::Index>(j)];
      }
      break;
    }
    case kActiveComplianceMode: {
      // Insertion and roll from the operator (servo stream or joystick), bends from eq. 4.24.
      if (ctx.servo_live()) {
        v[0] = ctx.servo_velocity()[0];
        v[1] = ctx.servo_velocity()[1];
      } else {
        ctx.stop_servo();
        joystick_velocity(ctx, v);
      }
      for (std::size_t j = 0; j < 2; ++j) {
        ctx.qd_des[j] = v[j];
        ctx.q_des[j] += v[j] * ctx.period;
      }
      // Eq. 4.24 adds the increments to q_cur. Here q_cur is the previous setpoint, not the encoder:
      // the drive's position loop lags its setpoint, and re-basing on the lagging encoder every tick
      // caps the admittance speed at what that lag allows (0.4 mm/s instead of v_max = 2 mm/s in the
      // simulated channel).
      const std::array<double, kJoints> current{ctx.q_des[0], ctx.q_des[1], ctx.q_des[2], ctx.q_des[3]};
      teleop::apply_active_compliance(robot_.settings_.compliance, current, spring_deflection_, ctx.period,
                                      ctx.q_des.first(kJoints));
      for (std::size_t i = 2; i < kJoints; ++i) ctx.qd_des[i] = (ctx.q_des[i] - current[i]) / ctx.period;
      break;
    }
    case kImageGuidedMode:
      image_guided(ctx);
      break;
    case kTelemanipulationMode: {
      joystick_velocity(ctx, v);
      for (std::size_t j = 0; j < kJoints; ++j) {
        ctx.qd_des[j] = v[j];
        ctx.q_des[j] += v[j] * ctx.period;
      }
      break;
    }
    default:
      break;
  }
}

// The insertion velocity the operator asks for where only insertion is theirs (image_guided, and
// retraction while held): the servo stream while it is live, else the joysticks' insertion axis.
double CatheterController::operator_insertion_velocity(ControlContext& ctx) noexcept {
  if (ctx.servo_live()) return ctx.servo_velocity()[0];
  ctx.stop_servo();
  std::array<double, kJoints> v{};
  joystick_velocity(ctx, v);
  return v[0];
}

// image_guided (issue 15): insertion from the operator; roll and bends from the newest target the
// imaging thread replanned (ImageGuidance), through the configuration controller (eq. 4.21 with the
// coupling compensation). No new target for kTrackingLostS: the bends hold where they are and the
// operator is warned once; the next target takes over again.
void CatheterController::image_guided(ControlContext& ctx) noexcept {
  auto& configuration = *robot_.configuration_;
  const double insertion_velocity = operator_insertion_velocity(ctx);
  const auto target = robot_.guidance_->target().load();
  if (target.sequence != guided_sequence_) {
    guided_sequence_ = target.sequence;
    guided_fix_t_ = ctx.t;
    // The target's insertion is the replanner's (one step ahead); insertion stays the operator's.
    if (configuration.retarget(ctx.t,
                               Eigen::Vector4d(ctx.q_des[0], target.psi[1], target.psi[2], target.psi[3])) &&
        guidance_lost_) {
      guidance_lost_ = false;
      ctx.supervisor->record(ctx.t, safety::EventKind::kWarning, safety::FaultCode::kSensorStale, -1,
                             "image_guided: tip tracking again; roll and bends follow the replanned targets");
    }
  }
  if (!guidance_lost_ && ctx.t - guided_fix_t_ > kTrackingLostS) {
    guidance_lost_ = true;
    configuration.reset(ctx.t, vec4(ctx.q_des));  // the bends hold where they are now
    char text[120];
    std::snprintf(
        text, sizeof text,
        "image_guided: tip tracking lost for %.1f s; the bends hold, insertion stays with the operator",
        kTrackingLostS);
    ctx.supervisor->record(ctx.t, safety::EventKind::kWarning, safety::FaultCode::kSensorStale, -1, text);
  }
  const double insertion = ctx.q_des[0];
  Eigen::Vector4d q = vec4(ctx.q_des), qd;
  if (!configuration.step(ctx.t, ctx.period, q, qd)) {
    configuration.reset(ctx.t, vec4(ctx.q_des));
    qd.setZero();
    q = vec4(ctx.q_des);
  }
  for (std::size_t j = 1; j < kJoints; ++j) {
    ctx.q_des[j] = q[static_cast<Eigen::Index>(j)];
    ctx.qd_des[j] = qd[static_cast<Eigen::Index>(j)];
  }
  ctx.qd_des[0] = insertion_velocity;
  ctx.q_des[0] = insertion + insertion_velocity * ctx.period;
}

void CatheterController::retraction(ControlContext& ctx) noexcept {
  // Held after a limit: the operator may withdraw the catheter (insertion only, never forward), from
  // the servo stream, a joystick or a requested distance; everything else stays where it is.
  const double insertion_velocity = operator_insertion_velocity(ctx);
  double withdraw = std::min(insertion_velocity, 0.0);
  if (withdrawing_) {
    // A requested distance goes at the joystick's full insertion speed and stops on the millimetre.
    const double remaining = ctx.q_des[0] - withdraw_to_;
    const double speed =
        std::min(robot_.settings_.telemanipulation_max_speed[0], ctx.limits->max_velocity[0]);
    if (remaining <= 1e-9 || speed <= 0.0)
      withdrawing_ = false;
    else
      withdraw = std::min(withdraw, -std::min(speed, remaining / ctx.period));
  }
  ctx.qd_des[0] = withdraw;
  ctx.q_des[0] += withdraw * ctx.period;
}

void CatheterController::start_relax(ControlContext& ctx) noexcept {
  if (ctx.state != OperatingState::kPaused || !ctx.drives_ready || !deflection_fresh_) return;
  relaxing_ = true;
  relax_started_ = ctx.t;
  relax_settled_s_ = 0.0;
  relax_outcome_ = RelaxOutcome::running;
  char text[96];
  std::snprintf(text, sizeof text, "relax: bend drives follow their springs (%.2f, %.2f mm) down to %.2f mm",
                spring_deflection_[0], spring_deflection_[1], 0.5 * robot_.settings_.deflection.resume_mm);
  ctx.supervisor->record(ctx.t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1, text);
}

void CatheterController::relax(ControlContext& ctx) noexcept {
  if (!relaxing_) return;
  const auto& d = robot_.settings_.deflection;
  char text[192];
  auto end = [&](RelaxOutcome outcome) {
    relaxing_ = false;
    relax_outcome_ = outcome;
    ctx.qd_des[2] = ctx.qd_des[3] = 0.0;
    ctx.supervisor->record(ctx.t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1,
                           text);
  };
  if (!deflection_fresh_) {
    std::snprintf(text, sizeof text, "relax stopped: no valid spring-deflection reading");
    return end(RelaxOutcome::sensor_stale);
  }
  // Relax goes on to half the resume bound and stays there for 100 ms, so the spring settling after
  // the drives stop (the carriage is damped, the wall still pushes) does not take it back over.
  const double worst = std::max(std::abs(spring_deflection_[0]), std::abs(spring_deflection_[1]));
  relax_settled_s_ = worst <= 0.5 * d.resume_mm ? relax_settled_s_ + ctx.period : 0.0;
  if (relax_settled_s_ >= kRelaxSettleS) {
    std::snprintf(text, sizeof text, "springs relaxed (%.2f mm, resume bound %.2f mm): resume is possible",
                  worst, d.resume_mm);
    return end(RelaxOutcome::relaxed);
  }
  if (ctx.t - relax_started_ > d.relax_timeout_s) {
    std::snprintf(text, sizeof text, "relax stopped after %.0f s with %.2f mm left (resume bound %.2f mm)",
                  d.relax_timeout_s, worst, d.resume_mm);
    return end(RelaxOutcome::timed_out);
  }
  // Eqs. 4.24–4.26 on the bend drives only; insertion and roll stay (or withdraw, see retraction).
  const std::array<double, kJoints> current{ctx.q_des[0], ctx.q_des[1], ctx.q_des[2], ctx.q_des[3]};
  teleop::apply_active_compliance(robot_.settings_.compliance, current, spring_deflection_, ctx.period,
                                  ctx.q_des.first(kJoints));
  for (std::size_t i = 2; i < kJoints; ++i) {
    const auto& j = robot_.config_.joints[i].limit;
    const double lo = std::max(j.lower + j.soft_margin, ctx.limits->lower[i]);
    const double hi = std::min(j.upper - j.soft_margin, ctx.limits->upper[i]);
    if ((ctx.q_des[i] < lo && ctx.q_des[i] < current[i]) ||
        (ctx.q_des[i] > hi && ctx.q_des[i] > current[i])) {
      relax_limit_joint_ = static_cast<int>(i);
      relax_limit_upper_ = ctx.q_des[i] > hi;
      ctx.q_des[i] = current[i];
      relax_limit_mm_ = relax_limit_upper_ ? hi : lo;
      std::snprintf(text, sizeof text,
                    "relax stopped: the %s drive at its %s limit (%.1f mm) with %.2f mm of spring deflection "
                    "left; withdraw",
                    i == 2 ? "proximal bend" : "distal bend", relax_limit_upper_ ? "upper" : "lower",
                    relax_limit_mm_, worst);
      return end(RelaxOutcome::at_limit);
    }
    ctx.qd_des[i] = (ctx.q_des[i] - current[i]) / ctx.period;
  }
}

bool CatheterController::while_held(ControlContext& ctx) noexcept {
  const bool may_move = retraction_only_ || relaxing_;
  if (retraction_only_) retraction(ctx);
  relax(ctx);
  if (may_move) ctx.setpoint_moved();
  return may_move;
}

void CatheterController::apply(ControlContext& ctx, const PluginCommand& command) noexcept {
  switch (static_cast<CatheterCommand>(command.id)) {
    case CatheterCommand::move_configuration:
      if (ctx.mode != kConfigurationMode || ctx.state != OperatingState::kEnabled || !ctx.drives_ready) break;
      robot_.configuration_->retarget(
          ctx.t, Eigen::Vector4d(command.values[0], command.values[1], command.values[2], command.values[3]));
      break;
    case CatheterCommand::joystick:
      for (std::size_t i = 0; i < kJoints; ++i) console_axes_[i] = command.values[i];
      console_deadman_ = command.flag != 0;
      console_time_ = ctx.t;
      break;
    case CatheterCommand::relax:
      start_relax(ctx);
      break;
    case CatheterCommand::withdraw:
      // Re-checked here: held with retraction allowed, and only ever backwards.
      if (retraction_only_ && ctx.state == OperatingState::kPaused && ctx.drives_ready &&
          std::isfinite(command.values[0]) && command.values[0] < ctx.q_des[0]) {
        withdrawing_ = true;
        withdraw_to_ = command.values[0];
      }
      break;
  }
}

void CatheterController::delay(ControlContext& ctx, double lost) noexcept {
  (void)ctx;
  robot_.configuration_->delay(lost);
}

void CatheterController::reset(ControlContext& ctx) noexcept {
  robot_.configuration_->reset(ctx.t, vec4(ctx.q_des));
  if (ctx.mode == kImageGuidedMode) {
    // Entered, enabled or resumed: targets from before do not apply, and tracking gets a fresh
    // kTrackingLostS to deliver the next one.
    guided_sequence_ = robot_.guidance_->target().load().sequence;
    guided_fix_t_ = ctx.t;
    guidance_lost_ = false;
  }
  if (ctx.mode != last_mode_) {
    // A stream for the old mode must not carry over.
    last_mode_ = ctx.mode;
    console_deadman_ = false;
    joystick_deadman_ = false;
    joystick_source_ = JoystickSource::none;
    joystick_axes_ = {};
  }
}

void CatheterController::state_command(ControlContext& ctx, safety::StateCommand command) noexcept {
  if (command != safety::StateCommand::kPause) return;
  withdrawing_ = false;
  if (relaxing_) {  // pause while relaxing: the operator stops the relax
    relaxing_ = false;
    relax_outcome_ = RelaxOutcome::stopped;
    ctx.supervisor->record(ctx.t, safety::EventKind::kRecovery, safety::FaultCode::kSpringDeflection, -1,
                           "relax stopped by the operator");
  }
}

void CatheterController::operator_lost(ControlContext& ctx) noexcept {
  (void)ctx;
  console_deadman_ = false;  // the operator is gone: the console joystick lets go
}

bool CatheterController::moving(const ControlContext& ctx) const noexcept {
  if (relaxing_ || withdrawing_) return true;
  if (ctx.mode == kConfigurationMode && !robot_.configuration_->done(ctx.t)) return true;
  // A joystick whose deadman is held is driving the robot.
  // image_guided: the bends follow a new target every frame, so their motion is the mode's steady
  // state, not a move to wait for (counted, it would refuse every mode switch while tracking runs);
  // the operator's insertion (a held deadman, a live stream) is.
  return (ctx.mode == kTelemanipulationMode || ctx.mode == kActiveComplianceMode ||
          ctx.mode == kImageGuidedMode) &&
         joystick_deadman_;
}

bool CatheterController::servo_allowed(const ControlContext& ctx, std::span<const double> v) const noexcept {
  // Active compliance: insertion and roll (the bends comply). Held with retraction allowed: insertion
  // backwards only.
  const bool bends_still = v.size() == kJoints && v[2] == 0.0 && v[3] == 0.0;
  return (ctx.mode == kActiveComplianceMode && ctx.state == OperatingState::kEnabled && bends_still) ||
         (ctx.mode == kImageGuidedMode && ctx.state == OperatingState::kEnabled && bends_still &&
          v[1] == 0.0) ||
         (retraction_only_ && ctx.state == OperatingState::kPaused && bends_still && v[1] == 0.0 &&
          v[0] <= 0.0);
}

bool CatheterController::hold_cleared(const ControlContext& ctx, char* why,
                                      std::size_t why_size) const noexcept {
  const auto& d = robot_.settings_.deflection;
  if (!deflection_fresh_) {
    if (why)
      std::snprintf(why, why_size, "resume refused: no valid spring-deflection reading from node 0x%02X",
                    d.node_id);
    return false;
  }
  if (relaxing_) {
    if (why) std::snprintf(why, why_size, "resume refused: the springs are relaxing");
    return false;
  }
  const double value = std::max(std::abs(spring_deflection_[0]), std::abs(spring_deflection_[1]));
  const double bound = ctx.hold_cause() == safety::FaultCode::kSpringDeflection ? d.resume_mm : d.limit_mm;
  if (value <= bound) return true;
  if (why)
    std::snprintf(why, why_size, "resume refused: spring deflected %.2f mm, over %.2f mm; relax or withdraw",
                  value, bound);
  return false;
}

void CatheterController::hold_ended(ControlContext& ctx) noexcept {
  (void)ctx;
  retraction_only_ = false;
}

void CatheterController::publish(const ControlContext& ctx) noexcept {
  CatheterSnapshot s;
  s.state = ctx.state;
  s.drives_ready = ctx.drives_ready;
  s.mode = ctx.mode;
  s.hold_code = ctx.hold_cause();
  for (std::size_t i = 0; i < kJoints; ++i) {
    s.position[i] = ctx.q[i];
    s.setpoint[i] = ctx.q_des[i];
  }
  s.spring_deflection = spring_deflection_;
  s.deflection_fresh = deflection_fresh_;
  s.retraction_only = retraction_only_;
  const auto goal = robot_.configuration_->goal();
  for (std::size_t i = 0; i < kJoints; ++i) s.configuration_goal[i] = goal[static_cast<Eigen::Index>(i)];
  s.configuration_moving = ctx.mode == kConfigurationMode && !robot_.configuration_->done(ctx.t);
  s.joystick_source = joystick_source_;
  s.joystick_deadman = joystick_deadman_;
  s.joystick_conflict = joystick_conflict_;
  s.joystick_axes = joystick_axes_;
  s.relaxing = relaxing_;
  s.relax_outcome = relax_outcome_;
  s.relax_limit_joint = relax_limit_joint_;
  s.relax_limit_upper = relax_limit_upper_;
  s.relax_limit_mm = relax_limit_mm_;
  s.withdrawing = withdrawing_;
  s.guidance_lost = ctx.mode == kImageGuidedMode && guidance_lost_;
  s.guidance_age_s = ctx.mode == kImageGuidedMode ? ctx.t - guided_fix_t_ : -1.0;
  robot_.published_.store(s);
}

}  // namespace tendril::server
