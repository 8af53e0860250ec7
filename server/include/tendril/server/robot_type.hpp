// The robot seam: how a kind of robot plugs into the server; the core names no robot.
//
//   robot file "kind" ──► RobotType (registered under that name) ──► RobotPlugin per robot:
//     its settings (checked against its JSON Schema), kinematic model, modes and their controllers
//     (RobotController, on the control thread), simulated plant and devices (through RobotAssembly),
//     and its part of the API (RobotApiExtension, at the network edge).
//
// The core (runtime, control cycle, safety, HTTP/WebSocket) names no robot: it runs the generic joint
// modes (joint: move_jp/servo_jv; path_following: a loaded plan step by step) and calls the plug-in
// for everything else. A new robot is a robot file, a folder under server/src/robots/ and its tests.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/hardware/joint_interface.hpp"
#include "tendril/safety/operating_limits.hpp"
#include "tendril/safety/safety_supervisor.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_kinematics.hpp"
#include "tendril/server/robot_service.hpp"
#include "tendril/server/topic_source.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::sim {
struct DriveParameters;
class Plant;
class SimulatedCia402Drive;
}  // namespace tendril::sim

namespace tendril::server {

class RobotApiExtension;
class PlanningApi;
class ImageFeedback;

inline constexpr std::size_t kMaxJoints = safety::kMaxJoints;
inline constexpr std::size_t kCommandValues = 16;

// Mode ids: the core's two modes, then the robot type's own (index into RobotPlugin::modes() + 2).
using ModeId = std::uint8_t;
inline constexpr ModeId kJointMode = 0;
inline constexpr ModeId kPathFollowingMode = 1;
inline constexpr ModeId kFirstPluginMode = 2;

// A command of a robot type for its controller: parsed and checked on a network thread by the type's
// API extension, carried to the control thread in the fixed-size mailbox entry.
struct PluginCommand {
  std::uint16_t id = 0;  // the type's own numbering
  std::uint8_t count = 0;
  std::int32_t flag = 0;
  std::array<double, kCommandValues> values{};
};

// What the control thread gives a robot type's controller each tick. Joint arrays have the robot's n
// entries. Plug-in controllers write the setpoint (q_des, qd_des) in their own modes, and in
// while_held() for the motions that reduce a hold's cause.
class ControlContext {
 public:
  virtual ~ControlContext() = default;
  std::size_t n = 0;
  double period = 0.001;
  double t = 0.0;           // control time, s
  std::int64_t now_ns = 0;  // steady clock, for sensor freshness
  // Time the loop went without a cycle before this one, beyond one period (s; 0 on time, always 0 in
  // simulated time): a device watchdog's text says whether the loop kept time while the device was silent.
  double lost = 0.0;
  safety::OperatingState state = safety::OperatingState::kDisabled;
  bool drives_ready = false;
  ModeId mode = kJointMode;
  std::span<const double> q, qd, effort;
  std::span<double> q_des, qd_des;
  const safety::OperatingLimits* limits = nullptr;
  safety::SafetySupervisor* supervisor = nullptr;

  // The operator's servo_jv stream: live (refreshed within the timeout), and its velocities.
  virtual bool servo_live() const noexcept = 0;
  virtual std::span<const double> servo_velocity() const noexcept = 0;
  virtual void stop_servo() noexcept = 0;
  // Holds the robot (ENABLED -> PAUSED) with a cause; every stream stops. False when it was not ENABLED.
  virtual bool hold(safety::FaultCode code, int joint, const char* detail) noexcept = 0;
  // The current hold's cause (kNone when not held by a limit).
  virtual safety::FaultCode hold_cause() const noexcept = 0;
  // After a controller moved q_des: the joint interpolator restarts from there (no jump back).
  virtual void setpoint_moved() noexcept = 0;
};

// A robot type's part in the control cycle. Every method runs on the control thread: no allocation,
// no locks, no blocking, no exceptions.
class RobotController {
 public:
  virtual ~RobotController() = default;
  // Reads the type's sensors; may hold the robot (ctx.hold). Before the mid-level controller.
  virtual void sense(ControlContext& ctx) noexcept { (void)ctx; }
  // The mid-level controller of one of the type's own modes (ctx.mode >= kFirstPluginMode), while
  // ENABLED with the drives ready: writes ctx.q_des / ctx.qd_des.
  virtual void control(ControlContext& ctx) noexcept { (void)ctx; }
  // While PAUSED: the motions that lead out of a hold (writes q_des / qd_des). True when the setpoint
  // may move now (the core then keeps it inside the limits).
  virtual bool while_held(ControlContext& ctx) noexcept {
    (void)ctx;
    return false;
  }
  // A command of the type (its API extension posted it).
  virtual void apply(ControlContext& ctx, const PluginCommand& command) noexcept {
    (void)ctx;
    (void)command;
  }
  // The control loop lost `lost` seconds (a stall) while the robot moved, within the loop-timing bound:
  // the type's running trajectories wait that long, so that the setpoint continues from where it stood
  // instead of jumping ahead (the core delays its joint interpolator the same way).
  virtual void delay(ControlContext& ctx, double lost) noexcept {
    (void)ctx;
    (void)lost;
  }
  // The setpoint was set from outside the type's controllers (enable, pause, resume, a mode switch,
  // following the measurement while disabled, a clamp): restart internal trajectories from ctx.q_des.
  virtual void reset(ControlContext& ctx) noexcept { (void)ctx; }
  // A state command (enable, disable, pause, resume) was applied; ctx.state is the state after it.
  virtual void state_command(ControlContext& ctx, safety::StateCommand command) noexcept {
    (void)ctx;
    (void)command;
  }
  // The operator's connection went away: let go of everything it held (a console joystick).
  virtual void operator_lost(ControlContext& ctx) noexcept { (void)ctx; }
  // Whether the type's own inputs move the robot now (a held deadman, a running move).
  virtual bool moving(const ControlContext& ctx) const noexcept {
    (void)ctx;
    return false;
  }
  // Whether a servo_jv stream may move the robot in the current mode / hold (the core allows it in
  // joint mode while ENABLED). `velocity` has n entries.
  virtual bool servo_allowed(const ControlContext& ctx, std::span<const double> velocity) const noexcept {
    (void)ctx;
    (void)velocity;
    return false;
  }
  // Whether resume may end the pause now (a hold's cause has cleared, or resuming would not hold the
  // robot again at once); when not and `why` is given, a sentence for the event log says why.
  virtual bool hold_cleared(const ControlContext& ctx, char* why, std::size_t why_size) const noexcept {
    (void)ctx;
    (void)why;
    (void)why_size;
    return true;
  }
  // The hold ended (resume, disable, e-stop reset).
  virtual void hold_ended(ControlContext& ctx) noexcept { (void)ctx; }
  // The type's safety filter on every motion: after the mid-level controller of whatever mode runs (the
  // core's joint mode with move_jp and servo_jv included) and before the limit clamp, while ENABLED or
  // while a held motion moves the setpoint. It may shorten the setpoint's step from `before` (the
  // setpoint the cycle started from) and returns the fraction of the step it kept, in [0, 1] (1:
  // unchanged). A sensor-based speed law that must hold in every mode (proximity speed scaling) sits
  // here. The core then delays its joint interpolator by the time the factor withheld, so a move_jp
  // runs slower along the same path instead of being cut short.
  virtual double limit_step(ControlContext& ctx, std::span<const double> before) noexcept {
    (void)ctx;
    (void)before;
    return 1.0;
  }
  // End of the tick: publish the type's state for its API extension (its own LatestValue slots).
  virtual void publish(const ControlContext& ctx) noexcept { (void)ctx; }
};

// What the core offers a plug-in while the robots are assembled (before any thread starts).
class RobotAssembly {
 public:
  virtual ~RobotAssembly() = default;
  // A bus the robot's file names: its endpoint for the type's own nodes, and whether it is virtual.
  struct BusAccess {
    std::string name;
    bool simulated = false;
    // Sends on the bus (from the bus thread or at start-up only).
    std::function<bool(const can::Frame&)> send;
    // Every received frame, on the bus thread.
    std::function<void(std::function<void(const can::Frame&, std::chrono::steady_clock::time_point)>)> listen;
    // A virtual bus only: a new endpoint for a simulated node.
    std::function<std::unique_ptr<can::Bus>(const std::string& name)> attach;
    // A virtual bus only: physics stepped after the simulated drives, at 1 kHz.
    std::function<void(sim::Plant*)> add_plant;
    // Worst-case bits per second the type's own nodes add (counted in the bus budget).
    std::function<void(double bits_per_second, const std::string& what)> add_load;
    // Runs once the bus is up (e.g. NMT start of the type's nodes).
    std::function<void(std::function<void()>)> on_start;
    // Claims a node id for one of the type's own nodes: throws ConfigError naming `key` (the file's
    // key) when a drive or another robot's node has it. Robots that share the bus share its node ids.
    std::function<void(int node_id, const std::string& key, const std::string& what)> claim_node;
  };
  virtual BusAccess bus(const std::string& name) = 0;
  // The joints' JointInterface when the core built it from the robot file's drives (CANopen), or
  // null when the joints have no drive section: the type then provides them (provide_joints).
  virtual hardware::JointInterface* joints() = 0;
  virtual void provide_joints(hardware::JointInterface& joints) = 0;
  // The simulated CiA 402 drive behind joint `joint` when its bus is virtual, else null; and the
  // name of the joint's bus (empty when the joint has no drive).
  virtual sim::SimulatedCia402Drive* simulated_drive(std::size_t joint) = 0;
  virtual std::string joint_bus(std::size_t joint) const = 0;
  // A link or device the core starts before the control loop and stops after it.
  virtual void add_component(std::unique_ptr<hardware::HardwareComponent> component) = 0;
  // A SIMULATED device with no thread of its own: a live server's control thread steps it
  // (step(now, period, false)) right before each cycle; stepped mode steps it with the others. For a
  // simulated sensor whose own thread, starved on a shared host, would go silent where the real sensor
  // (its own electronics) does not. Its step() must be real-time safe: no allocation, lock or block.
  virtual void add_component_in_control_thread(std::unique_ptr<hardware::HardwareComponent> component) = 0;
  virtual bool stepped() const = 0;
  virtual double control_period() const = 0;
  // The server's scene vessel (the server file's "scene"), in the vessel file's own frame; empty when
  // the server has none. A type that simulates contact places it at its vessel_entry().
  virtual const std::vector<teleop::CenterlinePolyline>& scene_vessel() const = 0;
};

struct ModeInfo {
  std::string name;
  std::string description;
};

// One robot of a type, built from its robot file.
class RobotPlugin {
 public:
  virtual ~RobotPlugin() = default;
  virtual const RobotKinematics& kinematics() const = 0;
  // The type's own modes (the core adds "joint" and, when plans apply, "path_following").
  virtual std::vector<ModeInfo> modes() const { return {}; }
  // Whether the shape-error planner's plans apply (path_following is offered).
  virtual bool path_following() const { return false; }
  virtual RobotController& controller() = 0;
  // Joint values for the display model from measured positions (by default the positions).
  virtual void display_positions(std::span<const double> measured, std::span<double> out) const;
  // A servo_jv stream in the current mode or hold: nullopt when the type has no say (the core then
  // allows it in joint mode only), else allowed (ok) or refused with the reason. The control thread
  // checks again with RobotController::servo_allowed.
  virtual std::optional<Status> check_servo(ModeId mode, const OperatingStateView& state,
                                            std::span<const double> velocity) const {
    (void)mode;
    (void)state;
    (void)velocity;
    return std::nullopt;
  }
  // The answer to a resume refused because the hold's cause persists (naming the cause and what to
  // do), or nullopt for the core's general wording.
  virtual std::optional<ServiceError> resume_refusal(const OperatingStateView& state) const {
    (void)state;
    return std::nullopt;
  }
  // Why a switch to `mode` is refused now (nullopt: allowed), given the robot's operating state.
  virtual std::optional<ServiceError> refuse_mode(ModeId mode, const OperatingStateView& state) const {
    (void)mode;
    (void)state;
    return std::nullopt;
  }
  // Cartesian commands (CRTK move_cp, servo_cp, servo_cv) for types that support them: checked and
  // encoded for the controller, with the move's duration (s; 0 for streams). Default: not supported.
  enum class CartesianKind : std::uint8_t { move_cp, servo_cp, servo_cv };
  virtual bool cartesian() const { return false; }
  virtual Result<std::pair<PluginCommand, double>> cartesian_command(CartesianKind kind,
                                                                     const CartesianPose& pose,
                                                                     const CartesianTwist& twist,
                                                                     const OperatingStateView& state) const;
  // The tool's twist from joint positions and velocities, and the measured contact force; nullopt when
  // the type has no such measure.
  virtual std::optional<CartesianTwist> measured_cv(std::span<const double> q,
                                                    std::span<const double> qd) const {
    (void)q;
    (void)qd;
    return std::nullopt;
  }
  virtual std::optional<Eigen::Vector3d> measured_cf() const { return std::nullopt; }
  // Starts and stops the type's own threads and devices (e.g. an evdev joystick).
  virtual void start() {}
  virtual void stop() {}
  // Where a vessel's start sits in the robot's frame {0}, with the vessel's first tangent as its z (a
  // catheter's insertion point); nullopt for a robot that does not enter vessels. The scene's vessel is
  // placed there for everyone (teleop::placement_at_entry), and plans made in the insertion frame are
  // shown in the robot's frame through it.
  virtual std::optional<Eigen::Isometry3d> vessel_entry() const { return std::nullopt; }
  // The type's use of the bi-plane imaging (image_feedback.hpp): null for a type that does not close a
  // loop on images. Owned by the plug-in; lives as long as it.
  virtual ImageFeedback* image_feedback() { return nullptr; }
  // WebSocket topics of the type's own (maps, images, scene entities, transforms), published by the
  // front end beside the core's and recorded with them. Asked once, after the runtime has started;
  // the sources are filled from the type's own threads (never the control thread's hot path).
  virtual std::vector<std::shared_ptr<TopicSource>> topic_sources() { return {}; }
  // The type's part of the network API; `service` reaches the runtime, `post` hands a PluginCommand to
  // this robot's control thread (false: the mailbox is full).
  virtual std::unique_ptr<RobotApiExtension> api(RobotService& service,
                                                 std::function<bool(const PluginCommand&)> post) = 0;
};

// A kind of robot. Registered once (robot_types.hpp); creates a RobotPlugin per robot file.
class RobotType {
 public:
  virtual ~RobotType() = default;
  virtual std::string kind() const = 0;
  virtual std::string description() const = 0;
  // JSON Schema (draft 2020-12 subset, see config_schema.hpp) of the type's own sections of a robot
  // file: an object schema whose "properties" and "required" are added to the core robot schema.
  virtual nlohmann::json settings_schema() const = 0;
  // Drive parameters of a simulated CiA 402 drive for `preset` (from a joint's "simulation"), or
  // nullopt when the type has no such preset (the core then simulates a generic axis).
  virtual std::optional<sim::DriveParameters> simulated_drive(const std::string& preset,
                                                              const JointConfig& joint) const;
  // Jobs the type offers over REST for its robots (plans, designs, calibrations: planning_api.hpp), or
  // null. `robots` are the configured robots of this type.
  // Defined where PlanningApi is complete (gcc instantiates the unique_ptr's deleter here otherwise).
  virtual std::unique_ptr<PlanningApi> planning_service(const std::vector<RobotConfig>& robots) const;
  // Parses and checks the type's settings (throws ConfigError naming file and key) and builds the robot.
  virtual std::unique_ptr<RobotPlugin> create(const RobotConfig& config, RobotAssembly& assembly) const = 0;
};

}  // namespace tendril::server
