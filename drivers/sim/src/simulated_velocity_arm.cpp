#include "tendril/drivers/sim/simulated_velocity_arm.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "periodic_runner.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace tendril::sim {

namespace {

constexpr int kFifoPriority = 70;  // as the catheter's simulated drives

void require(bool ok, const std::string& what) {
  if (!ok) throw SimulationSetupError("simulated arm: " + what);
}

hardware::PowerState power_of(ArmControllerState state) noexcept {
  switch (state) {
    case ArmControllerState::power_off:
      return hardware::PowerState::off;
    case ArmControllerState::brake_release:
      return hardware::PowerState::switching_on;
    case ArmControllerState::running:
      return hardware::PowerState::on;
    case ArmControllerState::quick_stop:
      return hardware::PowerState::stopping;
    case ArmControllerState::protective_stop:
      return hardware::PowerState::fault;
  }
  return hardware::PowerState::fault;
}

// How strongly a request speaks for the whole arm: the most cautious joint wins.
int precedence(hardware::PowerRequest r) noexcept {
  switch (r) {
    case hardware::PowerRequest::on:
      return 0;
    case hardware::PowerRequest::quick_stop:
      return 1;
    case hardware::PowerRequest::off:
      return 2;
    case hardware::PowerRequest::fault_reset:
      return 3;
  }
  return 2;
}

std::int64_t stamp(Clock::time_point t) noexcept {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

}  // namespace

const char* to_string(ArmControllerState state) noexcept {
  switch (state) {
    case ArmControllerState::power_off:
      return "power off";
    case ArmControllerState::brake_release:
      return "releasing brakes";
    case ArmControllerState::running:
      return "running";
    case ArmControllerState::quick_stop:
      return "quick stop";
    case ArmControllerState::protective_stop:
      return "protective stop";
  }
  return "unknown";
}

SimulatedVelocityArmParameters ur5_simulated_arm(const std::array<double, kSimulatedArmJoints>& initial) {
  const teleop::SerialArmParameters ur5 = teleop::ur5_parameters();
  SimulatedVelocityArmParameters p;
  p.name = "simulated UR5";
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    const teleop::ArmJointLimit& l = ur5.limits[i];
    p.joints[i] = {.lower = l.lower,
                   .upper = l.upper,
                   .max_velocity = l.max_velocity,
                   .max_acceleration = l.max_acceleration,
                   .initial_position = initial[i]};
  }
  return p;
}

SimulatedVelocityArm::SimulatedVelocityArm(SimulatedVelocityArmParameters parameters)
    : parameters_(std::move(parameters)), rng_(parameters_.seed) {
  const auto& p = parameters_;
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    const SimulatedArmJoint& j = p.joints[i];
    const std::string name = "joint " + std::to_string(i + 1) + ": ";
    require(std::isfinite(j.lower) && std::isfinite(j.upper) && j.lower < j.upper,
            name + "hard limits must be finite with lower < upper");
    require(j.initial_position >= j.lower && j.initial_position <= j.upper,
            name + "initial position " + std::to_string(j.initial_position) + " is outside the hard limits");
    require(std::isfinite(j.max_velocity) && j.max_velocity > 0.0, name + "max_velocity must be positive");
    require(std::isfinite(j.max_acceleration) && j.max_acceleration > 0.0,
            name + "max_acceleration must be positive");
    position_[i] = j.initial_position;
  }
  require(std::isfinite(p.controller_period) && p.controller_period > 0.0 && p.controller_period <= 0.1,
          "controller_period must be in (0, 0.1] s (got " + std::to_string(p.controller_period) + ")");
  require(p.latency_periods >= 0 && p.latency_periods <= static_cast<int>(kMaxLatency),
          "latency_periods must be in [0, " + std::to_string(kMaxLatency) + "]");
  require(std::isfinite(p.velocity_time_constant) && p.velocity_time_constant >= 0.0,
          "velocity_time_constant must be >= 0");
  require(std::isfinite(p.watchdog_timeout) && p.watchdog_timeout > 0.0, "watchdog_timeout must be positive");
  require(std::isfinite(p.switch_on_time) && p.switch_on_time >= 0.0, "switch_on_time must be >= 0");
  require(std::isfinite(p.position_noise) && p.position_noise >= 0.0, "position_noise must be >= 0");
  require(std::isfinite(p.velocity_noise) && p.velocity_noise >= 0.0, "velocity_noise must be >= 0");
  publish(Clock::time_point{});
}

SimulatedVelocityArm::~SimulatedVelocityArm() {
  stop_requested_ = true;
  if (thread_ && thread_->joinable()) thread_->join();
}

void SimulatedVelocityArm::configure(const std::function<void()>&) {
  configured_ = true;  // the link of a simulation opens at once
  if (!thread_running_) publish(Clock::now());
}

void SimulatedVelocityArm::activate(bool realtime_priority) {
  if (!configured_) throw hardware::HardwareError(parameters_.name + ": activate() before configure()");
  if (thread_running_.exchange(true)) throw hardware::HardwareError(parameters_.name + ": already active");
  stop_requested_ = false;
  const int priority = realtime_priority ? kFifoPriority : 0;
  thread_ = std::make_unique<std::thread>([this, priority] { run(priority); });
}

void SimulatedVelocityArm::deactivate(std::chrono::milliseconds, const std::function<void()>&) {
  stop_requested_ = true;
  if (thread_ && thread_->joinable()) thread_->join();
  thread_.reset();
  thread_running_ = false;
  // Power off: the brakes hold the arm where it is, and the link closes.
  state_ = ArmControllerState::power_off;
  velocity_.fill(0.0);
  configured_ = false;
  publish(Clock::now());
}

void SimulatedVelocityArm::step(Clock::time_point now, double period, bool after_control) {
  // Commands are taken at the start of the next cycle; nothing is urgent after the control cycle.
  if (after_control || thread_running_ || !(period > 0.0) || !std::isfinite(period)) return;
  // The simulated controller keeps its own rate whatever the control period (a real UR runs at 500 Hz
  // whether its client sends at 125 Hz or 1 kHz): every controller cycle due by `now`, each stamped
  // with its own time; the remainder waits for the next step.
  const double cycle = parameters_.controller_period;
  constexpr double kSlack = 1e-9;  // s: rounding in the accumulated time
  unsimulated_time_ += period;
  while (unsimulated_time_ >= cycle - kSlack) {
    unsimulated_time_ = std::max(0.0, unsimulated_time_ - cycle);
    const auto behind = std::chrono::nanoseconds(std::llround(unsimulated_time_ * 1e9));
    tick(now - std::chrono::duration_cast<Clock::duration>(behind), cycle);
  }
}

void SimulatedVelocityArm::run(int fifo_priority) noexcept {
  const auto period =
      std::chrono::nanoseconds(static_cast<std::int64_t>(parameters_.controller_period * 1e9));
  const std::function<void(Clock::time_point, double)> cycle = [this](Clock::time_point now, double dt) {
    tick(now, dt);
  };
  detail::run_periodic(period, 5.0 * parameters_.controller_period, fifo_priority, stop_requested_, stats_,
                       cycle);
}

const char* SimulatedVelocityArm::device_state_text(std::uint8_t state) const noexcept {
  return to_string(static_cast<ArmControllerState>(state));
}

void SimulatedVelocityArm::read(std::size_t joint, hardware::JointFeedback& out) const noexcept {
  if (joint >= kSimulatedArmJoints) {
    out = {};
    return;
  }
  out = feedback_[joint].load();
}

void SimulatedVelocityArm::write(std::size_t joint, const hardware::JointCommand& command) noexcept {
  if (joint >= kSimulatedArmJoints) return;
  CommandSlot slot = commands_[joint].load();  // this thread is the slot's only writer
  slot.command = command;
  ++slot.sequence;
  commands_[joint].store(slot);
}

void SimulatedVelocityArm::tick(Clock::time_point now, double dt) noexcept {
  time_ += dt;
  receive(time_);
  // The delay line: what arrived latency_periods cycles ago is applied now.
  const std::size_t size = delay_line_.size();
  const auto latency = static_cast<std::size_t>(parameters_.latency_periods);
  const Received applied = delay_line_[(delay_head_ + size - latency) % size];
  delay_head_ = (delay_head_ + 1) % size;
  advance_power(applied, dt);
  move_joints(applied, dt);
  publish(now);
}

void SimulatedVelocityArm::receive(double now_s) noexcept {
  Received r;
  bool fresh = false;
  int strongest = -1;
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    const CommandSlot slot = commands_[i].load();
    if (slot.sequence != last_sequence_[i]) {
      fresh = true;
      last_sequence_[i] = slot.sequence;
    }
    // A non-finite velocity is taken as zero: the joint brakes to rest rather than following garbage.
    r.velocity[i] = std::isfinite(slot.command.velocity) ? slot.command.velocity : 0.0;
    if (precedence(slot.command.request) > strongest) {
      strongest = precedence(slot.command.request);
      r.request = slot.command.request;
    }
  }
  if (fresh) last_command_time_ = now_s;
  delay_line_[delay_head_] = r;
}

void SimulatedVelocityArm::advance_power(const Received& applied, double dt) noexcept {
  using hardware::PowerRequest;
  const PowerRequest request = applied.request;
  const bool reset_edge = request == PowerRequest::fault_reset && last_request_ != PowerRequest::fault_reset;
  last_request_ = request;
  const bool at_rest = std::all_of(velocity_.begin(), velocity_.end(), [](double v) { return v == 0.0; });
  switch (state_) {
    case ArmControllerState::power_off:
      if (request == PowerRequest::on) {
        state_ = ArmControllerState::brake_release;
        switch_on_elapsed_ = 0.0;
      }
      break;
    case ArmControllerState::brake_release:
      if (request != PowerRequest::on) {
        state_ = ArmControllerState::power_off;
      } else if ((switch_on_elapsed_ += dt) >= parameters_.switch_on_time) {
        state_ = ArmControllerState::running;
        last_command_time_ = time_;  // the watchdog starts now
      }
      break;
    case ArmControllerState::running:
      if (request == PowerRequest::off) {
        state_ = ArmControllerState::power_off;
      } else if (request == PowerRequest::quick_stop) {
        state_ = ArmControllerState::quick_stop;
      } else if (time_ - last_command_time_ >
                 parameters_.watchdog_timeout + 1e-9) {  // 1 ns: rounding of time_
        fault(kArmErrorWatchdog, 0);
      }
      break;
    case ArmControllerState::quick_stop:
      if (request == PowerRequest::off) {
        state_ = ArmControllerState::power_off;
      } else if (request == PowerRequest::on && at_rest) {
        state_ = ArmControllerState::running;
        last_command_time_ = time_;
      }
      break;
    case ArmControllerState::protective_stop:
      if (reset_edge && at_rest) state_ = ArmControllerState::power_off;
      break;
  }
  if (state_ == ArmControllerState::power_off) velocity_.fill(0.0);  // brakes (stop category 0)
}

void SimulatedVelocityArm::move_joints(const Received& applied, double dt) noexcept {
  const double tc = parameters_.velocity_time_constant;
  const double follow = tc > 0.0 ? -std::expm1(-dt / tc) : 1.0;
  int limit_hit = -1;
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    const SimulatedArmJoint& j = parameters_.joints[i];
    const double v0 = velocity_[i];
    const double max_change = j.max_acceleration * dt;
    double v1 = 0.0;
    switch (state_) {
      case ArmControllerState::running: {
        const double target = std::clamp(applied.velocity[i], -j.max_velocity, j.max_velocity);
        v1 = v0 + std::clamp((target - v0) * follow, -max_change, max_change);
        break;
      }
      case ArmControllerState::quick_stop:
      case ArmControllerState::protective_stop:
        v1 = v0 - std::copysign(std::min(std::abs(v0), max_change), v0);
        break;
      case ArmControllerState::power_off:
      case ArmControllerState::brake_release:
        v1 = 0.0;
        break;
    }
    double q1 = position_[i] + 0.5 * (v0 + v1) * dt;
    if (q1 >= j.upper && v0 + v1 > 0.0) {
      q1 = j.upper;
      v1 = 0.0;
      limit_hit = static_cast<int>(i);
    } else if (q1 <= j.lower && v0 + v1 < 0.0) {
      q1 = j.lower;
      v1 = 0.0;
      limit_hit = static_cast<int>(i);
    }
    position_[i] = q1;
    velocity_[i] = v1;
  }
  if (limit_hit >= 0 && state_ != ArmControllerState::protective_stop) {
    fault(kArmErrorJointLimit, static_cast<std::uint8_t>(limit_hit + 1));
  }
}

void SimulatedVelocityArm::fault(std::uint32_t code, std::uint8_t detail) noexcept {
  state_ = ArmControllerState::protective_stop;
  ++error_count_;
  error_code_ = code;
  error_detail_ = detail;
}

void SimulatedVelocityArm::publish(Clock::time_point now) noexcept {
  const bool link = configured_.load(std::memory_order_relaxed);
  ArmTruth truth;
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    hardware::JointFeedback fb;
    fb.position = position_[i] + parameters_.position_noise * unit_normal_(rng_);
    fb.velocity = velocity_[i] + parameters_.velocity_noise * unit_normal_(rng_);
    fb.effort = 0.0;
    fb.power = power_of(state_);
    fb.device_state = static_cast<std::uint8_t>(state_);
    fb.link_alive = link;
    fb.link_operational = link;
    fb.error_count = error_count_;
    fb.error_code = error_code_;
    fb.error_detail = error_detail_;
    feedback_[i].store(fb);
    truth.position[i] = position_[i];
    truth.velocity[i] = velocity_[i];
  }
  truth.state = state_;
  truth.time = time_;
  truth.stamp_ns = stamp(now);
  truth_.store(truth);
}

}  // namespace tendril::sim
