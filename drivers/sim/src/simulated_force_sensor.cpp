#include "tendril/drivers/sim/simulated_force_sensor.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "periodic_runner.hpp"

namespace tendril::sim {

namespace {

constexpr int kFifoPriority = 70;  // as the other simulated devices

void require(bool ok, const std::string& what) {
  if (!ok) throw SimulationSetupError("simulated force sensor: " + what);
}

std::int64_t nanoseconds(Clock::time_point t) noexcept {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

}  // namespace

SimulatedForceSensor::SimulatedForceSensor(const SimulatedVelocityArm& arm,
                                           const teleop::SerialArmKinematics& kinematics,
                                           const ContactSurface& surface,
                                           SimulatedForceSensorParameters parameters)
    : arm_(arm),
      kinematics_(kinematics),
      surface_(surface),
      parameters_(std::move(parameters)),
      data_(kinematics_.make_data()),
      rng_(parameters_.seed) {
  const auto& p = parameters_;
  require(std::isfinite(p.sample_rate) && p.sample_rate > 0.0 && p.sample_rate <= 100'000.0,
          "sample_rate must be in (0, 100000] Hz (got " + std::to_string(p.sample_rate) + ")");
  require(std::isfinite(p.latency) && p.latency >= 0.0 &&
              p.latency * p.sample_rate < static_cast<double>(kMaxPending - 2),
          "latency must be >= 0 and shorter than " + std::to_string(kMaxPending - 2) + " sample periods");
  for (std::size_t i = 0; i < 3; ++i) {
    require(std::isfinite(p.noise[i]) && p.noise[i] >= 0.0, "noise must be finite and >= 0 on every axis");
    require(std::isfinite(p.bias[i]), "bias must be finite on every axis");
  }
  require(std::isfinite(p.range) && p.range > 0.0, "range must be positive");
}

SimulatedForceSensor::~SimulatedForceSensor() {
  stop_requested_ = true;
  if (thread_ && thread_->joinable()) thread_->join();
}

void SimulatedForceSensor::configure(const std::function<void()>&) { configured_ = true; }

void SimulatedForceSensor::activate(bool realtime_priority) {
  if (!configured_) throw hardware::HardwareError(parameters_.name + ": activate() before configure()");
  if (thread_running_.exchange(true)) throw hardware::HardwareError(parameters_.name + ": already active");
  stop_requested_ = false;
  const int priority = realtime_priority ? kFifoPriority : 0;
  thread_ = std::make_unique<std::thread>([this, priority] { run(priority); });
}

void SimulatedForceSensor::deactivate(std::chrono::milliseconds, const std::function<void()>&) {
  stop_requested_ = true;
  if (thread_ && thread_->joinable()) thread_->join();
  thread_.reset();
  thread_running_ = false;
  configured_ = false;
  hardware::ForceReading none = reading_.load();
  none.valid = false;
  reading_.store(none);
}

void SimulatedForceSensor::step(Clock::time_point now, double period, bool after_control) {
  if (after_control || thread_running_ || !configured_ || !(period > 0.0)) return;
  tick(now, period);
}

void SimulatedForceSensor::run(int fifo_priority) noexcept {
  const double period_s = 1.0 / parameters_.sample_rate;
  const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(period_s * 1e9));
  const std::function<void(Clock::time_point, double)> cycle = [this](Clock::time_point now, double dt) {
    tick(now, dt);
  };
  detail::run_periodic(period, std::max(5.0 * period_s, 0.01), fifo_priority, stop_requested_, stats_, cycle);
}

SimulatedForceSensor::Sample SimulatedForceSensor::take_sample(double time, Clock::time_point now) noexcept {
  const ArmTruth arm = arm_.truth();
  teleop::ArmVector q, qd;
  for (std::size_t i = 0; i < kSimulatedArmJoints; ++i) {
    q[static_cast<Eigen::Index>(i)] = arm.position[i];
    qd[static_cast<Eigen::Index>(i)] = arm.velocity[i];
  }
  Sample s;
  s.time = time;
  ContactSample contact;
  if (kinematics_.update(q, data_)) {
    const Eigen::Vector3d tool_velocity = data_.jacobian.topRows<3>() * qd;
    contact = surface_.contact(data_.tool.translation(), tool_velocity);
  }
  const Eigen::Vector3d in_sensor = data_.tool.linear().transpose() * contact.force;
  ForceSensorTruth truth;
  for (std::size_t i = 0; i < 3; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    truth.force_base[i] = contact.force[k];
    truth.force_sensor[i] = in_sensor[k];
    const double measured = in_sensor[k] + parameters_.bias[i] + parameters_.noise[i] * unit_normal_(rng_);
    s.force[i] = std::clamp(measured, -parameters_.range, parameters_.range);
  }
  truth.penetration = contact.penetration;
  truth.in_contact = contact.in_contact;
  truth.stamp_ns = nanoseconds(now);
  truth_.store(truth);
  return s;
}

void SimulatedForceSensor::tick(Clock::time_point now, double dt) noexcept {
  time_ += dt;
  const double sample_period = 1.0 / parameters_.sample_rate;
  constexpr double kSlack = 1e-9;  // s: rounding in the accumulated times
  while (next_sample_ <= time_ + kSlack) {
    pending_[pending_head_] = take_sample(next_sample_, now);
    pending_head_ = (pending_head_ + 1) % kMaxPending;
    pending_count_ = std::min(pending_count_ + 1, kMaxPending);
    next_sample_ += sample_period;
  }
  // Release every sample whose latency has passed; the newest of them becomes the reading.
  const Sample* ready = nullptr;
  while (pending_count_ > 0) {
    const Sample& oldest = pending_[(pending_head_ + kMaxPending - pending_count_) % kMaxPending];
    if (oldest.time > time_ - parameters_.latency + kSlack) break;
    ready = &oldest;
    --pending_count_;
  }
  if (ready == nullptr || silent_.load(std::memory_order_relaxed)) return;
  hardware::ForceReading reading;
  reading.force_n = ready->force;
  reading.stamp_ns = nanoseconds(now) - std::llround((time_ - ready->time) * 1e9);
  reading.valid = true;
  reading_.store(reading);
}

}  // namespace tendril::sim
