// RobotRuntime: assembles every configured robot from its file through its robot type (kinematics,
// modes, controllers, simulated devices), the buses they share (one CANopen master per bus, for all
// robots' drives on it) and the safety supervisors, and runs the real-time control loop. It implements
// RobotService: commands are checked here, then handed to the real-time thread through a lock-free
// mailbox; state comes back through seqlock snapshots.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/periodic_thread.hpp"
#include "tendril/server/robot_service.hpp"
#include "tendril/server/robot_types.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::sim {
class SimulatedCia402Drive;
}  // namespace tendril::sim

namespace tendril::server {

class RobotApiExtension;
class RobotPlugin;

struct RuntimeOptions {
  double control_rate_hz = 1000.0;
  bool realtime_priority = false;  // SCHED_FIFO + mlockall for the control thread
  // Stepped: no threads; the owner calls step() to advance simulated devices, buses and the control
  // loop by one control period in simulated time. Used by tests to make timing deterministic.
  bool stepped = false;
  // Simulated time (tendrild --simulated-time): stepped mode paced by the runtime's own thread, one
  // step per period at real-time pace while the machine keeps up. Every device, bus and control cycle
  // advances by one nominal period per step, so no time is ever lost: when the machine stalls,
  // simulated time slips behind the wall clock instead, and no stall can fault or hold a robot. Only
  // with every device SIMULATED (every bus "virtual"; the constructor throws ConfigError otherwise).
  // For tests of the logic on a shared machine; step() and stall() are refused (it paces itself).
  bool simulated_time = false;
  // The scene's vessel (ServerConfig "scene"), handed to the robot types (RobotAssembly::scene_vessel).
  std::vector<teleop::CenterlinePolyline> scene_vessel;
};

class RobotRuntime final : public RobotService {
 public:
  // Checks every robot file against its type's schema, builds every robot and bus (bus load, node
  // ids, simulation presets) and throws ConfigError with the file, key and reason. Opens no thread.
  RobotRuntime(std::vector<RobotConfig> robots, RuntimeOptions options, const RobotTypes& types);
  ~RobotRuntime() override;
  RobotRuntime(const RobotRuntime&) = delete;
  RobotRuntime& operator=(const RobotRuntime&) = delete;

  // Configures the hardware (CANopen start-up over SDO), then starts bus, simulation and control
  // threads. Throws hardware::HardwareError (or canopen::CanopenError) when a device does not come up.
  void start();
  // Disables every drive cleanly, then stops all threads. Idempotent.
  void stop();
  // After stop(): whether every joint reported its power stage off. Names those that did not.
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
  // Whether the runtime runs in simulated time (RuntimeOptions::simulated_time).
  bool simulated_time() const noexcept;

  // Test and diagnostics access.
  std::size_t robot_count() const noexcept;
  // An extra endpoint on a virtual bus that sees every frame (for tests and benchmarks); nullptr when
  // the bus is not virtual. Call before start().
  std::unique_ptr<can::Bus> tap_bus(const std::string& bus);
  // The simulated drive behind a joint, or nullptr when the joint's drive is real hardware.
  sim::SimulatedCia402Drive* simulated_drive(const std::string& robot, const std::string& joint);
  // A robot's plug-in (its type's object), for the type's own tests; nullptr for an unknown robot.
  RobotPlugin* plugin(const std::string& robot);
  // The robot type's part of the network API for `robot` (made once, owned here); nullptr when unknown.
  RobotApiExtension* api_extension(const std::string& robot);
  std::uint64_t control_ticks() const noexcept;
  // RobotPlugin::vessel_entry of `robot` (nullopt for an unknown robot or one without).
  std::optional<Eigen::Isometry3d> vessel_entry(const std::string& robot) const;
  LoopStatistics loop_statistics() const noexcept;

  // RobotService
  std::vector<RobotDescription> robots() const override;
  bool has_robot(const std::string& robot) const override;
  Result<JointStateView> measured_js(const std::string& robot) const override;
  Result<JointStateView> setpoint_js(const std::string& robot) const override;
  Result<PoseView> measured_cp(const std::string& robot) const override;
  Result<TwistView> measured_cv(const std::string& robot) const override;
  Result<WrenchView> measured_cf(const std::string& robot) const override;
  Result<ShapeView> shape(const std::string& robot) const override;
  Result<OperatingStateView> operating_state(const std::string& robot) const override;
  Result<DiagnosticsView> diagnostics(const std::string& robot) const override;
  Result<OperatingStateView> state_command(const std::string& robot, StateRequest request) override;
  Status mode(const std::string& robot, const std::string& mode) override;
  Result<double> move_jp(const std::string& robot, std::span<const double> goal) override;
  Status servo_jv(const std::string& robot, std::span<const double> velocity) override;
  Result<double> move_cp(const std::string& robot, const CartesianPose& goal) override;
  Status servo_cp(const std::string& robot, const CartesianPose& goal) override;
  Status servo_cv(const std::string& robot, const CartesianTwist& twist) override;
  Status estop(const std::string& actor) override;
  Status estop_reset(const std::string& actor) override;
  void operator_lost(const std::string& robot) override;
  bool report_warning(const std::string& robot, safety::FaultCode code, const std::string& text) override;
  std::vector<SafetyEventView> faults(std::size_t max_events) const override;
  std::vector<SafetyEventView> events_since(std::uint64_t since, std::uint64_t& total) const override;
  std::string metrics() const override;
  Status load_path(const std::string& robot, PathPlan plan) override;
  Result<std::pair<std::int32_t, double>> path_step(const std::string& robot,
                                                    std::optional<std::int32_t> step,
                                                    std::int32_t advance) override;
  Result<PathView> path_following(const std::string& robot) const override;
  std::vector<Parameter> parameters() const override;
  Result<std::vector<Parameter>> set_parameters(const std::vector<ParameterChange>& changes) override;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
  std::vector<std::unique_ptr<RobotApiExtension>> extensions_;
};

}  // namespace tendril::server
