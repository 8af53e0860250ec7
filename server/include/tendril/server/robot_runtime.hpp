// RobotRuntime: assembles every configured robot (model, safety supervisor, controllers, CANopen
// drives on their buses, simulated drives on virtual buses) and runs the real-time control loop.
// It implements ControlApi for the network front end: commands are validated here, then handed to
// the real-time thread through a lock-free mailbox; state comes back through seqlock snapshots.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/control_api.hpp"
#include "tendril/server/periodic_thread.hpp"

namespace tendril::sim {
class SimulatedCia402Drive;
class SimulatedAnalogJoystick;
class SimulatedAnalogInputNode;
}  // namespace tendril::sim

namespace tendril::server {

struct RuntimeOptions {
  double control_rate_hz = 1000.0;
  bool realtime_priority = false;  // SCHED_FIFO + mlockall for the control thread
  // Stepped: no threads; the owner calls step() to advance simulated drives, buses and the control
  // loop by one control period in simulated time. Used by tests to make timing deterministic.
  bool stepped = false;
};

class RobotRuntime final : public ControlApi {
 public:
  // Validates the whole configuration (kinematics, bus load, simulation presets) and builds every
  // object; throws ConfigError with the file, key and reason. Opens no thread yet.
  RobotRuntime(std::vector<RobotConfig> robots, RuntimeOptions options);
  ~RobotRuntime() override;
  RobotRuntime(const RobotRuntime&) = delete;
  RobotRuntime& operator=(const RobotRuntime&) = delete;

  // Boots the drives (CANopen start-up over SDO), then starts bus, simulation and control threads
  // (realtime mode). Throws canopen::CanopenError when a drive does not come up.
  void start();
  // Disables every drive cleanly, then stops all threads. Idempotent.
  void stop();
  // After stop(): whether every drive reported its power stage off (not operation enabled, not
  // quick stop active). Names the drives that did not in `not_disabled`.
  bool drives_disabled(std::vector<std::string>* not_disabled = nullptr) const;
  // Stepped mode only: advance simulation, buses and control by one control period.
  void step();
  // Stepped mode only: a stall of `duration` (whole periods), after which the next step() is the late
  // control cycle that reports the lost time. Tests of the loop-timing policy
  // (safety::SupervisorOptions). control_thread: buses and simulated drives run on, the control cycle
  // does not. whole_process: nothing runs (the machine stalled); the simulated hardware then catches
  // up in one step, as its real-time thread does.
  enum class Stall : std::uint8_t { control_thread, whole_process };
  void stall(std::chrono::nanoseconds duration, Stall what);
  // Current control time (s since start), stepped or real.
  double time() const noexcept;

  // Test and diagnostics access.
  std::size_t robot_count() const noexcept;
  // An extra endpoint on a virtual bus that sees every frame (for tests and benchmarks); nullptr
  // when the bus is not virtual. Call before start().
  std::unique_ptr<can::Bus> tap_bus(const std::string& robot, const std::string& bus);
  // The simulated drive behind a joint, or nullptr when the joint's drive is real hardware.
  sim::SimulatedCia402Drive* simulated_drive(const std::string& robot, const std::string& joint);
  // A steerable catheter's simulated ADC nodes (joystick with pedal; spring-deflection
  // potentiometers), or nullptr when the robot has none or they are real hardware.
  sim::SimulatedAnalogJoystick* simulated_analog_joystick(const std::string& robot);
  sim::SimulatedAnalogInputNode* simulated_spring_sensor(const std::string& robot);
  std::uint64_t control_ticks() const noexcept;
  LoopStatistics loop_statistics() const noexcept;

  // ControlApi
  nlohmann::json robots() const override;
  bool has_robot(const std::string& robot) const override;
  ApiResult measured_js(const std::string& robot) const override;
  ApiResult setpoint_js(const std::string& robot) const override;
  ApiResult measured_cp(const std::string& robot) const override;
  ApiResult shape(const std::string& robot) const override;
  ApiResult operating_state(const std::string& robot) const override;
  ApiResult state_command(const std::string& robot, const nlohmann::json& body) override;
  ApiResult mode(const std::string& robot, const nlohmann::json& body) override;
  ApiResult move_jp(const std::string& robot, const nlohmann::json& body) override;
  ApiResult servo_jv(const std::string& robot, const nlohmann::json& body) override;
  ApiResult estop() override;
  ApiResult estop_from(const std::string& actor) override;
  ApiResult estop_reset() override;
  nlohmann::json faults(std::size_t max_events = 200) const override;
  std::string metrics() const override;
  std::vector<std::string> topics() const override;
  std::optional<nlohmann::json> topic_message(const std::string& topic, std::uint64_t since_version,
                                              std::uint64_t& version) const override;
  void operator_lost() override;
  ApiResult load_path(const std::string& robot, const nlohmann::json& plan,
                      const std::string& plan_id) override;
  ApiResult path_step(const std::string& robot, const nlohmann::json& body) override;
  ApiResult path_following(const std::string& robot) const override;
  ApiResult move_configuration(const std::string& robot, const nlohmann::json& body) override;
  ApiResult joystick(const std::string& robot, const nlohmann::json& body) override;
  nlohmann::json parameters() const override;
  ApiResult set_parameters(const nlohmann::json& parameters) override;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::server
