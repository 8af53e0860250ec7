// Private parts of RobotRuntime shared by its source files:
//   can_bus.cpp          a CAN bus shared by every robot that names it (one CANopen master)
//   robot_runtime.cpp    assembly of robots and hardware from the robot files, lifecycle
//   robot_control.cpp    the control cycle (real-time thread)
//   robot_service.cpp    the typed RobotService (network threads): checks, then the mailbox
// No robot type is named here: robot-specific behaviour reaches the cycle through RobotController.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/cia402_joints.hpp"
#include "tendril/drivers/canopen/master.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/safety/operating_limits.hpp"
#include "tendril/safety/safety_supervisor.hpp"
#include "tendril/server/command_mailbox.hpp"
#include "tendril/server/periodic_thread.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_type.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"

namespace tendril::server {

using JointArray = std::array<double, kMaxJoints>;

enum class CommandKind : std::uint8_t {
  state,
  move_jp,
  servo_jv,
  estop,
  estop_reset,
  hold,         // the operator is gone: streams stop
  mode,         // index = ModeId; applied only while holding
  path_loaded,  // a new plan was loaded: no step reached yet
  path_step,    // index = step; values = the step's joint configuration
  plugin,       // the robot type's own command
  warning,      // log `text` with `code` as a warning event (no state change)
};

// One command from the network threads to the control thread; trivially copyable, fixed size.
struct RobotCommand {
  CommandKind kind = CommandKind::hold;
  safety::StateCommand state = safety::StateCommand::kDisable;
  std::uint32_t count = 0;
  JointArray values{};
  std::int32_t index = 0;  // mode or path step
  PluginCommand plugin{};
  std::chrono::steady_clock::time_point received{};
  char actor[48] = {};              // who sent it, for the event log (e-stop); NUL-terminated
  std::uint64_t estop_presses = 0;  // estop_reset: the supervisor's estop_presses() when it was asked for
  safety::FaultCode code = safety::FaultCode::kNone;  // warning
  char text[96] = {};                                 // warning; NUL-terminated
};

// A plan loaded for path following: built and freed on network threads, never seen by the control
// thread (each step's joint values reach it inside a fixed-size path_step command).
struct LoadedPath {
  std::string plan_id;
  std::vector<JointArray> steps;
  std::vector<Eigen::Vector3d> vessel;
  std::vector<Eigen::Vector3d> tips;
};

// What the control thread publishes every tick.
struct RobotSnapshot {
  std::uint64_t tick = 0;
  double time = 0.0;
  std::uint32_t joints = 0;
  JointArray position{}, velocity{}, effort{}, setpoint{}, setpoint_velocity{};
  safety::OperatingState state = safety::OperatingState::kDisabled;
  bool estop = false;
  bool busy = false;  // a move is running, a stream is live, or drives are enabling
  bool drives_ready = false;
  std::array<hardware::PowerState, kMaxJoints> power{};
  std::array<std::uint8_t, kMaxJoints> device_state{};
  std::array<bool, kMaxJoints> link_alive{};
  safety::FaultInfo fault{};
  safety::SafetySupervisor::LostControlRecord lost_control{};  // loop-timing record (SupervisorOptions)
  safety::FaultCode hold_code = safety::FaultCode::kNone;      // the cause of the current hold
  bool hold_can_resume = false;                                // the robot type says the cause cleared
  std::uint64_t estop_tick = 0;  // tick at which the last e-stop reached the control thread
  std::uint64_t commands_applied = 0;
  std::uint64_t mailbox_full = 0;
  ModeId mode = kJointMode;
  std::int32_t path_step = -1;    // last plan step reached (-1: none since the plan was loaded)
  std::int32_t path_target = -1;  // step being moved to (== path_step when not moving to one)
};

// A CAN bus and everything on it: the CANopen master serving every robot's drives on this bus, the
// simulated drives and nodes when it is virtual, and the bus thread.
struct CanBusComponent final : hardware::HardwareComponent {
  BusConfig config;
  std::vector<std::string> robots;  // the robots whose files name this bus
  std::unique_ptr<can::VirtualBus> virtual_bus;
  std::unique_ptr<can::Bus> master_endpoint;
  std::unique_ptr<canopen::CanopenMaster> master;
  std::vector<canopen::DriveSetup> drive_setups;  // index = the master's drive index
  std::vector<std::unique_ptr<can::Bus>> sim_endpoints;
  std::vector<std::unique_ptr<sim::SimulatedCia402Drive>> sim_drives;  // same index, virtual buses only
  double load = 0.0;
  std::string load_breakdown;
  double extra_bits_per_second = 0.0;     // the robot types' own nodes
  std::map<int, std::string> node_owner;  // node id -> "robot/joint" or "robot/what", across robots
  std::string extra_breakdown;
  std::thread bus_thread;
  PeriodicThread sim_thread;
  std::atomic<bool> stopping{false};
  // Other nodes on the bus: every received frame also goes to these, on the bus thread.
  std::vector<std::function<void(const can::Frame&, std::chrono::steady_clock::time_point)>> frame_listeners;
  std::vector<sim::Plant*> plants;              // stepped after the drives (virtual buses only)
  std::vector<std::function<void()>> on_start;  // after the master is up
  bool stepped = false;

  std::string name() const override { return "CAN bus '" + config.name + "' (" + config.interface + ")"; }
  void configure(const std::function<void()>& idle) override;
  void activate(bool realtime_priority) override;
  void deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) override;
  void step(Clock::time_point now, double period, bool after_control) override;
  std::function<void()> stepped_idle() override;
  void run_bus(bool realtime_priority);
  void start_simulation(bool realtime_priority);
  // The whole bus's worst-case load from its drives and the robot types' nodes; throws ConfigError
  // naming the numbers when it is over max_load.
  void check_load(const std::string& where);
};

struct RobotUnit;

// The control thread's view of one robot, handed to its RobotController.
class UnitContext final : public ControlContext {
 public:
  explicit UnitContext(RobotUnit& unit) : unit_(unit) {}
  bool servo_live() const noexcept override;
  std::span<const double> servo_velocity() const noexcept override;
  void stop_servo() noexcept override;
  bool hold(safety::FaultCode code, int joint, const char* detail) noexcept override;
  safety::FaultCode hold_cause() const noexcept override;
  void setpoint_moved() noexcept override;

 private:
  RobotUnit& unit_;
};

struct RobotUnit {
  RobotConfig config;
  const RobotType* type = nullptr;
  std::unique_ptr<RobotPlugin> plugin;
  RobotController* controller = nullptr;
  std::unique_ptr<safety::SafetySupervisor> supervisor;
  std::unique_ptr<teleop::QuinticInterpolator> interpolator;
  std::unique_ptr<hardware::JointInterface> own_joints;  // built from the file's drives (CANopen)
  hardware::JointInterface* joints = nullptr;            // own_joints or the type's
  std::vector<CanBusComponent*> buses;                   // the buses the robot's file names
  std::vector<ModeInfo> modes;                           // by ModeId
  CommandMailbox<RobotCommand> mailbox{256};
  hardware::LatestValue<RobotSnapshot> snapshot;
  std::atomic<std::uint64_t> mailbox_full{0};
  std::size_t n = 0;
  JointArray max_acceleration{};
  // Per joint: its bus's drive heartbeat timeout (ms; 0 without a CANopen drive), named in the fault
  // text when the drive goes silent.
  std::array<int, kMaxJoints> heartbeat_timeout_ms{};
  double velocity_gain = 10.0;             // 1/s: position error fed back on velocity joints
  std::mutex path_mutex;                   // network threads only
  std::shared_ptr<const LoadedPath> path;  // guarded by path_mutex
  hardware::LatestValue<safety::OperatingLimits> operating_limits;
  std::mutex limits_write_mutex;  // network threads only: read-modify-write of operating_limits
  std::mutex refusal_mutex;
  std::optional<ModeRefusal> mode_refusal;  // guarded by refusal_mutex
  std::unique_ptr<UnitContext> context;

  // Control-thread state (touched only by the control thread).
  struct ControlState {
    JointArray q{}, qd{}, effort{}, q_des{}, qd_des{}, qdd_des{}, servo_velocity{};
    bool servo_active = false;
    double last_servo_time = 0.0;
    bool drives_ready = false;
    double enable_started = 0.0;
    bool enable_pending = false;
    bool goal_pending = false;  // move_jp received while the drives were still enabling
    JointArray pending_goal{};
    std::array<std::uint32_t, kMaxJoints> errors_seen{};
    std::array<bool, kMaxJoints> link_was_alive{};
    std::array<bool, kMaxJoints> link_was_operational{};
    std::uint64_t estop_tick = 0;
    std::uint64_t commands_applied = 0;
    bool initialised = false;
    ModeId mode = kJointMode;
    std::int32_t path_step = -1, path_target = -1;
    JointArray path_goal{};
    safety::OperatingLimits limits{};  // copy of operating_limits, refreshed when its version changes
    std::uint64_t limits_version = ~std::uint64_t{0};
    safety::FaultCode hold_code = safety::FaultCode::kNone;
    // Whether the robot was moving when the last cycle ended (a move, a servo stream, the robot
    // type's own motion, or a setpoint that changed): what a stall before the next cycle interrupts.
    bool moving = false;
  } rt;

  ModeId mode_id(const std::string& name) const;  // modes.size() when unknown
  const std::string& mode_name(ModeId id) const;
};

struct RobotRuntime::Impl {
  RuntimeOptions options;
  std::vector<std::unique_ptr<RobotUnit>> robots;
  std::vector<std::unique_ptr<CanBusComponent>> buses;
  // Every component in start order: buses first, then the robot types' own components.
  std::vector<std::unique_ptr<hardware::HardwareComponent>> extra_components;
  std::vector<hardware::HardwareComponent*> components;
  // Those of them the live control thread steps before each cycle (they are never activated).
  std::vector<hardware::HardwareComponent*> control_thread_components;
  std::map<std::string, RobotUnit*> by_name;
  PeriodicThread control_thread;
  std::atomic<bool> running{false};
  std::atomic<std::uint64_t> ticks{0};
  std::chrono::steady_clock::time_point start_time{};
  std::chrono::steady_clock::time_point stepped_now{};
  double wall_offset = 0.0;  // unix time at start_time
  double period = 0.001;
  std::int64_t now_ns = 0;  // control-cycle time on the steady clock (ns), for sensor freshness

  // Safety events drained from every supervisor, newest last; guarded by events_mutex.
  mutable std::mutex events_mutex;
  mutable std::deque<SafetyEventView> events;
  mutable std::uint64_t events_total = 0;

  // Stepped mode: control time the next step() reports lost, and simulated time it catches up.
  double stepped_lost = 0.0;
  double stepped_sim_lost = 0.0;
  double stepped_control_devices_lost = 0.0;  // a control-thread stall: what its own devices missed
  // Simulated time: stepped_now for readers on other threads (time()), ns since the clock's epoch.
  std::atomic<std::int64_t> published_now_ns{0};

  // Stepped mode: one period of simulated time (RobotRuntime::step(); the pacing thread in simulated time).
  void advance_one_period();

  bool in_control_thread(const hardware::HardwareComponent* c) const noexcept {
    return std::find(control_thread_components.begin(), control_thread_components.end(), c) !=
           control_thread_components.end();
  }

  // Control thread. `lost`: time since the previous cycle ran beyond one period (s), see
  // PeriodicThread's CycleTiming.
  void control_cycle(std::chrono::steady_clock::time_point now, double lost) noexcept;
  void control_robot(RobotUnit& r, double t, double lost) noexcept;
  void apply_command(RobotUnit& r, const RobotCommand& c, double t) noexcept;
  bool holding(RobotUnit& r, double t) noexcept;
  void end_hold(RobotUnit& r) noexcept;

  // Network threads.
  RobotUnit* find(const std::string& robot) const;
  bool post(RobotUnit& r, const RobotCommand& c);
  void collect_events() const;
};

}  // namespace tendril::server
