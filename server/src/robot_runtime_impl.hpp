// Private parts of RobotRuntime shared by its source files (assembly, control cycle, API).
#pragma once

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
#include "tendril/drivers/canopen/master.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/safety/safety_supervisor.hpp"
#include "tendril/server/command_mailbox.hpp"
#include "tendril/server/robot_kinematics.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"

namespace tendril::server {

inline constexpr std::size_t kMaxJoints = safety::kMaxJoints;
using JointArray = std::array<double, kMaxJoints>;

enum class CommandKind : std::uint8_t {
  state,
  move_jp,
  servo_jv,
  estop,
  estop_reset,
  hold,
  mode,                // index = ControlMode; applied only while holding
  path_loaded,         // a new plan was loaded: no step reached yet
  path_step,           // index = step; values = the step's joint configuration
  move_configuration,  // values = goal ψ (insertion, roll, θ_L1, θ_L2), steerable catheter only
  joystick,            // console joystick: values = axes per joint (−1..1), index = deadman held
  relax,               // steerable catheter held PAUSED: the bend drives relax their springs
  withdraw             // steerable catheter held with retraction allowed: values[0] = insertion goal (mm)
};

// How the last relax of a catheter's springs ended (operating_state "hold.relax").
enum class RelaxOutcome : std::uint8_t { none, running, relaxed, timed_out, at_limit, sensor_stale, stopped };
const char* to_string(RelaxOutcome outcome) noexcept;

// Control modes (operating_state "mode"), the mid-level controller of seed 000 §4.7:
//   joint: move_jp (quintic) and servo_jv;
//   path_following: a loaded plan is played back one insertion step at a time (path_step commands);
//   configuration (catheter): move_configuration goals in ψ = (insertion, roll, θ_L1, θ_L2) through
//     eq. 4.21 with loss and coupling compensation;
//   active_compliance (catheter): the bend drives yield to their spring deflection (eqs. 4.24–4.26);
//     insertion and roll follow servo_jv or a joystick;
//   telemanipulation (catheter): joint velocities from a joystick while its deadman is held.
enum class ControlMode : std::uint8_t {
  joint,
  path_following,
  configuration,
  active_compliance,
  telemanipulation
};
const char* to_string(ControlMode mode) noexcept;
bool parse_control_mode(const std::string& name, ControlMode& mode) noexcept;
struct CatheterUnit;

// One command from the network threads to the control thread; trivially copyable, fixed size.
struct RobotCommand {
  CommandKind kind = CommandKind::hold;
  safety::StateCommand state = safety::StateCommand::kDisable;
  std::uint32_t count = 0;
  JointArray values{};
  std::int32_t index = 0;  // mode or path step
  std::chrono::steady_clock::time_point received{};
  char actor[48] = {};  // who sent it, for the event log (e-stop); NUL-terminated
};

// A plan loaded for path following: built and freed on network threads, never seen by the control
// thread (each step's joint values reach it inside a fixed-size path_step command).
struct LoadedPath {
  std::string plan_id;                  // job id, empty for an inline plan
  std::vector<JointArray> steps;        // joint configurations, checked against the limits at load
  std::vector<Eigen::Vector3d> vessel;  // vessel centerline for the scene (may be empty)
  std::vector<Eigen::Vector3d> tips;    // planned tip position of each step (from the backbones)
};

// Operating limits: the configured limits, possibly tightened at run time through parameters
// (ControlApi::set_parameters), never wider. Written by network threads (under
// RobotUnit::limits_write_mutex), read lock-free by the control thread through a LatestValue slot.
struct OperatingLimits {
  JointArray lower{}, upper{}, max_velocity{};
  double servo_timeout_s = 0.0;
};

// What the control thread publishes every tick.
struct RobotSnapshot {
  std::uint64_t tick = 0;
  double time = 0.0;
  std::uint32_t joints = 0;
  JointArray position{}, velocity{}, effort{}, setpoint{}, setpoint_velocity{};
  safety::OperatingState state = safety::OperatingState::kDisabled;
  bool estop = false;
  bool busy = false;  // a move is running, a servo stream is live, or drives are enabling
  bool drives_ready = false;
  std::array<canopen::Cia402State, kMaxJoints> drive_state{};
  std::array<bool, kMaxJoints> heartbeat_alive{};
  safety::FaultInfo fault{};
  safety::SafetySupervisor::LostControlRecord lost_control{};  // loop-timing record (SupervisorOptions)
  std::uint64_t estop_tick = 0;  // tick at which the last e-stop reached the control thread
  std::uint64_t commands_applied = 0;
  std::uint64_t mailbox_full = 0;
  ControlMode mode = ControlMode::joint;
  std::int32_t path_step = -1;    // last plan step reached (-1: none since the plan was loaded)
  std::int32_t path_target = -1;  // step being moved to (== path_step when not moving to one)
  // Steerable catheter (zeros otherwise).
  std::array<double, 2> spring_deflection{};  // mm, drive − carriage
  bool deflection_fresh = false;
  bool retraction_only = false;  // held after a limit: only insertion withdrawal may move
  safety::FaultCode hold_code = safety::FaultCode::kNone;
  std::array<double, 4> configuration_goal{};  // ψ goal of the configuration controller
  bool configuration_moving = false;
  std::uint8_t joystick_source = 0;  // JoystickSource
  bool joystick_deadman = false;
  bool joystick_conflict = false;  // more than one source held its deadman: no motion
  std::array<double, 4> joystick_axes{};
  bool relaxing = false;  // the bend drives are relaxing their springs while held
  RelaxOutcome relax_outcome = RelaxOutcome::none;
  bool withdrawing = false;  // held: the insertion is withdrawing by a requested distance
};

// Where telemanipulation velocities come from (operating_state "joystick.source").
enum class JoystickSource : std::uint8_t { none, console, evdev, analog };
const char* to_string(JoystickSource source) noexcept;

struct BusUnit {
  BusConfig config;
  std::string robot;
  std::unique_ptr<can::VirtualBus> virtual_bus;  // null for SocketCAN
  std::unique_ptr<can::Bus> master_endpoint;
  std::unique_ptr<canopen::CanopenMaster> master;
  std::vector<std::unique_ptr<can::Bus>> sim_endpoints;
  std::vector<std::unique_ptr<sim::SimulatedCia402Drive>> sim_drives;
  double load = 0.0;
  std::string load_breakdown;
  std::thread bus_thread;
  PeriodicThread sim_thread;
  // Other nodes on the bus (ADC nodes): every received frame also goes to these, on the bus thread.
  std::vector<std::function<void(const can::Frame&, std::chrono::steady_clock::time_point)>> frame_listeners;
  // Simulated physics stepped after the drives on the simulation thread (virtual buses only).
  std::vector<sim::Plant*> plants;
};

struct JointBinding {
  BusUnit* bus = nullptr;
  std::size_t drive = 0;                     // index in the bus master's drive list
  sim::SimulatedCia402Drive* sim = nullptr;  // when simulated
};

struct RobotUnit {
  RobotConfig config;
  std::unique_ptr<RobotKinematics> kinematics;
  std::unique_ptr<safety::SafetySupervisor> supervisor;
  std::unique_ptr<teleop::QuinticInterpolator> interpolator;
  std::vector<JointBinding> bindings;
  CommandMailbox<RobotCommand> mailbox{256};
  hardware::LatestValue<RobotSnapshot> snapshot;
  std::atomic<std::uint64_t> mailbox_full{0};
  std::size_t n = 0;
  JointArray max_velocity{}, max_acceleration{};
  std::mutex path_mutex;                                    // network threads only
  std::shared_ptr<const LoadedPath> path;                   // guarded by path_mutex
  hardware::LatestValue<OperatingLimits> operating_limits;  // see OperatingLimits
  std::mutex limits_write_mutex;                            // network threads only: read-modify-write
  std::unique_ptr<CatheterUnit> catheter;                   // steerable catheter robots only
  // Last refused mode switch, for operating_state (network threads only).
  std::mutex refusal_mutex;
  nlohmann::json mode_refusal;  // guarded by refusal_mutex; null when none
  ~RobotUnit();

  // Control-thread state (touched only by the control thread).
  struct ControlState {
    JointArray q{}, qd{}, effort{}, q_des{}, qd_des{}, qdd_des{}, servo_velocity{};
    bool servo_active = false;
    bool drives_ready = false;
    double enable_started = 0.0;
    bool enable_pending = false;
    bool goal_pending = false;  // move_jp received while the drives were still enabling
    JointArray pending_goal{};
    std::array<std::uint32_t, kMaxJoints> emcy_seen{};
    std::array<bool, kMaxJoints> heartbeat_was_alive{};
    std::array<bool, kMaxJoints> nmt_was_operational{};
    std::uint64_t estop_tick = 0;
    std::uint64_t commands_applied = 0;
    bool initialised = false;
    ControlMode mode = ControlMode::joint;
    std::int32_t path_step = -1, path_target = -1;
    JointArray path_goal{};
    OperatingLimits limits{};  // copy of operating_limits, refreshed when its version changes
    std::uint64_t limits_version = ~std::uint64_t{0};
    double last_servo_time = 0.0;
    // Console joystick stream (telemanipulation).
    std::array<double, 4> console_axes{};
    bool console_deadman = false;
    double console_time = -1.0;
    bool retraction_only = false;
    safety::FaultCode hold_code = safety::FaultCode::kNone;
    std::array<double, 2> spring_deflection{};
    bool deflection_fresh = false;
    std::uint8_t joystick_source = 0;
    bool joystick_deadman = false;
    bool joystick_conflict = false;
    std::array<double, 4> joystick_axes{};
    bool relaxing = false;
    double relax_started = 0.0;
    double relax_settled_s = 0.0;  // time both springs have been within the relax target
    bool withdrawing = false;      // held: insertion moving back to withdraw_to (mm)
    double withdraw_to = 0.0;
    RelaxOutcome relax_outcome = RelaxOutcome::none;
    // Whether the robot was moving when the last cycle ended (a move, a servo stream, a joystick,
    // or a setpoint that changed): what a stall before the next cycle interrupts.
    bool moving = false;
  } rt;
};

struct RuntimeImplBase {
  RuntimeOptions options;
  std::vector<std::unique_ptr<RobotUnit>> robots;
  std::vector<std::unique_ptr<BusUnit>> buses;
  std::map<std::string, RobotUnit*> by_name;
  PeriodicThread control_thread;
  std::atomic<bool> running{false};
  std::atomic<bool> stopping{false};
  std::atomic<std::uint64_t> ticks{0};
  std::chrono::steady_clock::time_point start_time{};
  std::chrono::steady_clock::time_point stepped_now{};
  double wall_offset = 0.0;  // unix time at start_time
  double period = 0.001;

  // Safety events drained from every supervisor, newest last; guarded by events_mutex.
  mutable std::mutex events_mutex;
  mutable std::deque<nlohmann::json> events;
  mutable std::uint64_t events_total = 0;
  // Topic cache for change detection.
  mutable std::mutex topic_mutex;
  mutable std::map<std::string, std::pair<std::string, std::uint64_t>> topic_cache;
};

struct RobotRuntime::Impl : RuntimeImplBase {
  // `lost`: time since the previous cycle ran beyond one period (s), see PeriodicThread::CycleTiming.
  void control_cycle(std::chrono::steady_clock::time_point now, double lost) noexcept;
  void control_robot(RobotUnit& r, double t, double lost) noexcept;
  // Stepped mode: runs the simulated nodes over `dt` and the buses at `now`, without the control cycle.
  void step_buses(std::chrono::steady_clock::time_point now, double dt);
  double stepped_lost = 0.0;      // stepped mode: control time the next step() reports lost
  double stepped_sim_lost = 0.0;  // stepped mode: simulated time the next step() catches up
  void apply_command(RobotUnit& r, const RobotCommand& c, double t) noexcept;
  // Steerable catheter parts of the control cycle (catheter_control.cpp).
  void catheter_sensors(RobotUnit& r, double t, safety::OperatingState state) noexcept;
  void catheter_mid_level(RobotUnit& r, double t) noexcept;
  void catheter_retraction(RobotUnit& r, double t) noexcept;
  // Held: the bend drives follow their springs (eqs. 4.24–4.26) until both deflections are within
  // the resume bound, the sensor goes stale, a drive reaches its limit or the relax times out.
  void catheter_relax(RobotUnit& r, double t) noexcept;
  void catheter_start_relax(RobotUnit& r, double t) noexcept;
  // False (and the refusal logged) when resuming would hold the robot again at once: the deflection
  // sensor is stale, or a spring is deflected beyond the resume bound after a deflection hold (beyond
  // the hold bound otherwise).
  bool catheter_may_resume(RobotUnit& r, double t) noexcept;
  bool holding(const RobotUnit& r, double t) const noexcept;
  std::int64_t now_ns = 0;  // control-cycle time on the steady clock (ns), for sensor freshness
  void run_bus(BusUnit& b);
  // What a blocking master exchange runs while it waits (steps simulated drives in stepped mode).
  std::function<void()> blocking_idle(BusUnit& bus) const;
  void collect_events() const;
};

}  // namespace tendril::server
