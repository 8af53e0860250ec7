// SimulatedForceSensor: a SIMULATED 3-axis force sensor between the arm's flange and its tool (Heunis
// et al. 2021: a K3D40 between the UR5 and the ultrasound probe), behind hardware::ForceSensor.
//
// Each sample takes the arm's true joint state (SimulatedVelocityArm::truth()), puts the tool point
// where the kinematic model says it is, asks the ContactSurface for the force on it, and reports that
// force in the sensor frame — the model's tool frame (z along the probe) — as the force the environment
// exerts on the tool: pressing the tissue with a probe whose z points into it reads negative z. On top:
// a constant bias, Gaussian noise (seeded), saturation at the measuring range, a sample rate and a
// latency (a reading becomes visible `latency` after it was sampled, stamped with its sampling time).
//
// Defaults (the article names the K3D40 but no range or rate): ±10 N range, 0.02 N noise (1σ, our
// choice for the simulated set-up), zero bias (settable:
// real sensors are tared), 1 kHz sampling and 2 ms latency (amplifier filter and transport), so the
// 500 Hz arm controller and a 1 kHz control loop always see a reading under 3 ms old. In stepped
// simulation every sample due within a step sees the arm's state at the end of that step (the arm and
// the sensor are stepped one after the other), less than one step ahead of its sampling time: with
// 2 ms steps and 1 kHz sampling 1 ms ahead, 0.7 mN at the controller's 1.33 mm/s into 0.5 N/mm tissue.
//
// Threads: read() is called by the control thread and only loads a LatestValue slot. Sampling runs in
// the sensor's own periodic thread (activate(), one period per sample) or in step(now, period,
// after_control = false), which takes every sample due in that period (stepped simulation, or a live
// control thread that steps the sensor before each cycle) — step it after the arm so it sees the arm's
// new state. step() allocates nothing and takes no lock.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <thread>

#include "tendril/drivers/hardware/joint_interface.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/hardware/sensor_interfaces.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/drivers/sim/simulated_velocity_arm.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/teleop/serial_arm_kinematics.hpp"

namespace tendril::sim {

struct SimulatedForceSensorParameters {
  std::string name = "simulated force sensor";
  double sample_rate = 1000.0;                    // Hz
  double latency = 0.002;                         // s from sampling to reading
  std::array<double, 3> noise{0.02, 0.02, 0.02};  // N (1σ) per sensor axis (our choice)
  std::array<double, 3> bias{0.0, 0.0, 0.0};      // N per sensor axis
  double range = 10.0;                            // N: each axis saturates at ±range
  std::uint64_t seed = 0xF0ACE5u;
};

// The noiseless contact of the latest sample, for tests and the console's ground truth.
struct ForceSensorTruth {
  std::array<double, 3> force_base{};    // N on the tool, arm base frame
  std::array<double, 3> force_sensor{};  // the same in the sensor frame
  double penetration = 0.0;              // mm
  bool in_contact = false;
  std::int64_t stamp_ns = 0;
};

class SimulatedForceSensor final : public hardware::HardwareComponent, public hardware::ForceSensor {
 public:
  // `arm` and `surface` must outlive the sensor; the kinematic model (with the tool transform of the
  // probe) is copied. Throws SimulationSetupError naming a parameter out of range.
  SimulatedForceSensor(const SimulatedVelocityArm& arm, const teleop::SerialArmKinematics& kinematics,
                       const ContactSurface& surface, SimulatedForceSensorParameters parameters);
  ~SimulatedForceSensor() override;
  SimulatedForceSensor(const SimulatedForceSensor&) = delete;
  SimulatedForceSensor& operator=(const SimulatedForceSensor&) = delete;

  const SimulatedForceSensorParameters& parameters() const noexcept { return parameters_; }

  // hardware::HardwareComponent
  std::string name() const override { return parameters_.name; }
  void configure(const std::function<void()>& idle) override;
  void activate(bool realtime_priority) override;
  void deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) override;
  void step(Clock::time_point now, double period, bool after_control) override;

  // hardware::ForceSensor: the newest reading whose latency has passed; invalid before the first one
  // and after deactivate().
  hardware::ForceReading read() const noexcept override { return reading_.load(); }

  // Failure injection (any thread): a silent sensor stops publishing; its last reading keeps its stamp,
  // so the control cycle sees it go stale.
  void set_silent(bool silent) noexcept { silent_.store(silent); }

  ForceSensorTruth truth() const noexcept { return truth_.load(); }
  bool running() const noexcept { return thread_running_.load(); }
  RealtimeStatistics realtime_statistics() const noexcept { return stats_.load(); }

 private:
  struct Sample {
    std::array<double, 3> force{};
    double time = 0.0;  // simulated s
  };
  static constexpr std::size_t kMaxPending = 64;

  void tick(Clock::time_point now, double dt) noexcept;
  Sample take_sample(double time, Clock::time_point now) noexcept;
  void run(int fifo_priority) noexcept;

  const SimulatedVelocityArm& arm_;
  const teleop::SerialArmKinematics kinematics_;
  const ContactSurface& surface_;
  SimulatedForceSensorParameters parameters_;
  hardware::LatestValue<hardware::ForceReading> reading_;
  hardware::LatestValue<ForceSensorTruth> truth_;
  std::atomic<bool> silent_{false};
  std::atomic<bool> configured_{false};

  // Owned by the sampling thread (or the stepping caller).
  teleop::SerialArmData data_;
  std::array<Sample, kMaxPending> pending_{};  // ring of samples waiting out the latency
  std::size_t pending_head_ = 0;               // next slot to write
  std::size_t pending_count_ = 0;
  double time_ = 0.0;
  double next_sample_ = 0.0;
  std::mt19937_64 rng_;
  std::normal_distribution<double> unit_normal_{0.0, 1.0};

  std::atomic<bool> thread_running_{false};
  std::atomic<bool> stop_requested_{false};
  std::unique_ptr<std::thread> thread_;
  hardware::LatestValue<RealtimeStatistics> stats_;
};

}  // namespace tendril::sim
