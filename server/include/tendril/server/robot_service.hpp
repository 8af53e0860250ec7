// RobotService: what the robots offer the outside world, in typed commands, typed read-outs and typed
// errors. No JSON and no HTTP status codes here: the network edge (server/src/http) turns requests
// into these calls and their results into its protocol. Thread-safe; called from network threads and
// the DDS bridge. Implemented by RobotRuntime, which checks every command against the robot's limits
// and state, then hands it to the real-time thread through a lock-free mailbox.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/safety/limit_set.hpp"
#include "tendril/safety/safety_types.hpp"

namespace tendril::server {

// Why a command or a read-out was refused. The edge maps the kind onto its protocol (HTTP: 400, 404,
// 409, 422, 503); `code` is the API's snake_case code and `message` is written for a person.
enum class ErrorKind : std::uint8_t {
  malformed,      // the request does not have the expected shape
  not_found,      // no such robot, plan, step or parameter
  not_supported,  // the robot has no such capability
  conflict,       // the robot's state does not allow it now (not enabled, wrong mode, moving, e-stop)
  invalid,        // well formed but outside a limit or a precondition (limits, sizes, non-finite)
  forbidden,      // a read-only parameter
  busy,           // the control loop did not take the command in time
  internal,
};

struct ServiceError {
  ErrorKind kind = ErrorKind::internal;
  std::string code;
  std::string message;
};

// A value or the reason there is none.
template <class T>
class Result {
 public:
  Result(T value) : v_(std::move(value)) {}             // NOLINT(google-explicit-constructor)
  Result(ServiceError error) : v_(std::move(error)) {}  // NOLINT(google-explicit-constructor)
  bool ok() const noexcept { return v_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }
  const T& value() const { return std::get<0>(v_); }
  T& value() { return std::get<0>(v_); }
  const T& operator*() const { return value(); }
  const T* operator->() const { return &value(); }
  const ServiceError& error() const { return std::get<1>(v_); }

 private:
  std::variant<T, ServiceError> v_;
};
struct Done {};
using Status = Result<Done>;

inline ServiceError unknown_robot(const std::string& robot) {
  return {ErrorKind::not_found, "unknown_robot",
          "no robot named \"" + robot + "\"; GET /api/v1/robots lists them"};
}

// ---- read-outs ----
struct JointStateView {
  std::vector<std::string> name;
  std::vector<double> position, velocity, effort;
  double timestamp = 0.0;  // unix time, s
  std::uint64_t tick = 0;  // control tick of the snapshot (changes every tick)
};

struct PoseView {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // mm
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::string frame;
  double timestamp = 0.0;
};

struct ShapeView {
  std::vector<Eigen::Vector3d> points;  // mm
  std::string frame;
  double timestamp = 0.0;
};

struct FaultView {
  std::string code;     // safety::to_string(FaultCode)
  std::string message;  // for a person
  std::string joint;    // empty when not about one joint
};

// Why a PAUSED robot holds and the way out of it (the robot type fills in its own causes' details).
struct HoldView {
  std::string cause;    // "operator_pause" or the safety code of the limit that held it
  std::string message;  // for a person
  std::string joint;    // empty when not about one joint
  bool cleared = true;  // resume would be accepted now
  std::string next;     // what the operator can do now, for a person
  std::vector<std::string> allowed{"resume"};  // the commands that lead out of it
};

struct ModeRefusal {
  std::string mode, code, reason;
  double timestamp = 0.0;
};

// The loop-timing policy's record (safety::SupervisorOptions): lost control time beyond one period,
// and the bound that faults a moving robot.
struct LoopTimingView {
  double max_lost_control_ms = 0.0;  // the bound
  double lost_max_ms = 0.0;          // longest gap, in any state
  double lost_max_moving_ms = 0.0;   // longest gap while moving
  std::uint64_t stalls_over_bound = 0;
  std::uint64_t stalls_over_bound_at_rest = 0;
};

struct OperatingStateView {
  safety::OperatingState state = safety::OperatingState::kDisabled;
  std::string mode;
  bool busy = false;
  bool estop = false;
  bool drives_ready = false;
  std::optional<FaultView> fault;
  std::optional<HoldView> hold;
  std::optional<ModeRefusal> mode_refusal;
  LoopTimingView loop_timing;
  double timestamp = 0.0;
};

struct BusView {
  std::string name, interface;
  bool simulated = false;
  double load = 0.0;  // worst-case fraction of the bitrate
};

struct ModeView {
  std::string name;
  std::string description;
};

struct RobotDescription {
  std::string name, kind, description;
  std::vector<safety::JointLimit> joints;
  std::vector<ModeView> modes;
  std::vector<BusView> buses;
  std::vector<std::string> commands;  // the robot type's own commands (besides the CRTK ones)
  int command_timeout_ms = 0;
  bool cartesian = false;  // measured_cp, move_cp, servo_cp, servo_cv are served
  // Where a vessel's start sits in the robot's frame (RobotPlugin::vessel_entry); plans come in the
  // insertion frame, which this maps into the robot's.
  std::optional<Eigen::Isometry3d> vessel_entry;
};

struct SafetyEventView {
  double time = 0.0;
  std::string robot, kind, code, from, to, message, joint;
};

struct PathView {
  bool loaded = false;
  std::string plan;
  std::int32_t steps = 0;
  std::int32_t step = -1;
  std::int32_t target = -1;
  bool moving = false;
  std::string mode;
  std::vector<Eigen::Vector3d> vessel;  // for the scene (may be empty)
  std::vector<Eigen::Vector3d> tips;    // planned tip of each step (may be empty)
};

// The control loop's timing and what it commands, for plots.
struct DiagnosticsView {
  double timestamp = 0.0;
  double nominal_period_us = 0.0;
  double period_error_p50_us = 0.0, period_error_p99_us = 0.0, period_error_max_us = 0.0;
  double work_p50_us = 0.0, work_p99_us = 0.0, work_max_us = 0.0;
  std::uint64_t overruns = 0;
  std::uint64_t late_cycles = 0;  // cycles that started a full period or more late
  double lost_max_us = 0.0;       // longest time without a cycle beyond one period
  double bus_load = 0.0;          // the largest of the robot's buses
  std::vector<double> setpoint, measured;
};

struct Parameter {
  std::string name;
  double value = 0.0;
  bool writable = false;
};
struct ParameterChange {
  std::string name;
  std::optional<double> value;  // nullopt: back to the configured value
};

// A plan for path following: joint configurations per insertion step, each checked at load.
struct PathPlan {
  std::string id;  // job id, empty for an inline plan
  std::vector<std::vector<double>> steps;
  std::vector<Eigen::Vector3d> vessel;  // for the scene, may be empty
  std::vector<Eigen::Vector3d> tips;    // planned tip of each step, may be empty
};

// Cartesian goals and streams (CRTK move_cp, servo_cp, servo_cv) for robot types that support them.
struct CartesianPose {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // mm, robot base frame
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
};
struct CartesianTwist {
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();   // mm/s
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();  // rad/s
};
struct TwistView {
  CartesianTwist twist;
  std::string frame;
  double timestamp = 0.0;
};
struct WrenchView {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();  // N
  std::string frame;
  double timestamp = 0.0;
};

enum class StateRequest : std::uint8_t { enable, disable, pause, resume, home };

class RobotService {
 public:
  virtual ~RobotService() = default;

  virtual std::vector<RobotDescription> robots() const = 0;
  virtual bool has_robot(const std::string& robot) const = 0;

  virtual Result<JointStateView> measured_js(const std::string& robot) const = 0;
  virtual Result<JointStateView> setpoint_js(const std::string& robot) const = 0;
  virtual Result<PoseView> measured_cp(const std::string& robot) const = 0;
  virtual Result<TwistView> measured_cv(const std::string& robot) const = 0;
  virtual Result<WrenchView> measured_cf(const std::string& robot) const = 0;
  virtual Result<ShapeView> shape(const std::string& robot) const = 0;
  virtual Result<OperatingStateView> operating_state(const std::string& robot) const = 0;
  virtual Result<DiagnosticsView> diagnostics(const std::string& robot) const = 0;

  // The state the robot is expected in once the control loop applied the request.
  virtual Result<OperatingStateView> state_command(const std::string& robot, StateRequest request) = 0;
  virtual Status mode(const std::string& robot, const std::string& mode) = 0;
  // The duration of the move in s.
  virtual Result<double> move_jp(const std::string& robot, std::span<const double> goal) = 0;
  virtual Status servo_jv(const std::string& robot, std::span<const double> velocity) = 0;
  virtual Result<double> move_cp(const std::string& robot, const CartesianPose& goal) = 0;
  virtual Status servo_cp(const std::string& robot, const CartesianPose& goal) = 0;
  virtual Status servo_cv(const std::string& robot, const CartesianTwist& twist) = 0;
  // `actor` names who pressed it, for the event log.
  virtual Status estop(const std::string& actor) = 0;
  virtual Status estop_reset(const std::string& actor) = 0;
  // The connection of the holder of `robot`'s lease went away while streaming: its streams stop and
  // it holds. Other robots, maybe commanded by someone else, go on.
  virtual void operator_lost(const std::string& robot) = 0;
  // Logs a warning about `robot` in its safety event log (EventKind::kWarning: seen by the operator,
  // no state change), from any thread but the control thread; `text` is cut to the event's 95
  // characters. False for an unknown robot or a full command queue (the warning is then lost, and
  // counted as a dropped command).
  virtual bool report_warning(const std::string& robot, safety::FaultCode code, const std::string& text) = 0;

  virtual std::vector<SafetyEventView> faults(std::size_t max_events) const = 0;
  // The events logged after the first `since` (oldest first); `total` = how many were logged so far.
  virtual std::vector<SafetyEventView> events_since(std::uint64_t since, std::uint64_t& total) const = 0;
  virtual std::string metrics() const = 0;  // Prometheus text exposition

  virtual Status load_path(const std::string& robot, PathPlan plan) = 0;
  // Moves to plan step `step` (absolute) or by `advance` steps; the duration in s.
  virtual Result<std::pair<std::int32_t, double>> path_step(const std::string& robot,
                                                            std::optional<std::int32_t> step,
                                                            std::int32_t advance) = 0;
  virtual Result<PathView> path_following(const std::string& robot) const = 0;

  virtual std::vector<Parameter> parameters() const = 0;
  virtual Result<std::vector<Parameter>> set_parameters(const std::vector<ParameterChange>& changes) = 0;
};

}  // namespace tendril::server
