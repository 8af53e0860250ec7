// The steerable robotic microcatheter (SRMC, Abah 2022, ch. 4) as a robot type ("steerable_catheter"):
// its configuration-space model and controller, the spring-deflection and joystick inputs (CAN ADC
// nodes, evdev), its modes (configuration, active compliance, telemanipulation), the ways out of its
// holds, and on a virtual bus the SIMULATED series-elastic plant in its vessel with simulated ADC nodes.
//
// Threads: the bus thread decodes the ADC nodes' PDOs into LatestValue slots; the control thread runs
// CatheterController and publishes CatheterSnapshot; network threads read the immutable model and
// settings, the published snapshot and the simulation's published state (catheter_api.cpp).
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "steerable_catheter/catheter_settings.hpp"
#include "tendril/drivers/canopen/analog_input_node.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/input/evdev_joystick.hpp"
#include "tendril/server/robot_type.hpp"
#include "tendril/teleop/catheter_configuration.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"
#include "tendril/teleop/vessel_shaft.hpp"

namespace tendril::sim {
class SimulatedAnalogJoystick;
class SimulatedAnalogInputNode;
}  // namespace tendril::sim

namespace tendril::server {

class SteerableCatheter;

// The type's modes, after the core's joint and path_following.
inline constexpr ModeId kConfigurationMode = kFirstPluginMode;
inline constexpr ModeId kActiveComplianceMode = kFirstPluginMode + 1;
inline constexpr ModeId kTelemanipulationMode = kFirstPluginMode + 2;
inline constexpr ModeId kImageGuidedMode = kFirstPluginMode + 3;

// image_guided: without a new replanned target for this long (control time) the tracking is lost:
// the bends hold and the operator is warned (issue 15).
inline constexpr double kTrackingLostS = 0.5;

// The type's commands (PluginCommand::id).
enum class CatheterCommand : std::uint16_t { move_configuration, joystick, relax, withdraw };

// Where telemanipulation velocities come from (operating_state "joystick.source").
enum class JoystickSource : std::uint8_t { none, console, evdev, analog };
const char* to_string(JoystickSource source) noexcept;

// How the last relax of the springs ended (operating_state "hold.relax").
enum class RelaxOutcome : std::uint8_t { none, running, relaxed, timed_out, at_limit, sensor_stale, stopped };
const char* to_string(RelaxOutcome outcome) noexcept;

struct DeflectionReading {
  std::array<double, 2> mm{};  // proximal, distal: drive − carriage
  std::int64_t stamp_ns = 0;   // steady clock
  bool valid = false;          // false: never read, or a wiring fault on a channel
};

// What the control thread publishes every tick for the type's API (trivially copyable).
struct CatheterSnapshot {
  std::uint64_t tick = 0;
  safety::OperatingState state = safety::OperatingState::kDisabled;
  bool drives_ready = false;
  ModeId mode = kJointMode;
  safety::FaultCode hold_code = safety::FaultCode::kNone;
  std::array<double, 4> position{}, setpoint{};
  std::array<double, 2> spring_deflection{};  // mm, drive − carriage
  bool deflection_fresh = false;
  bool retraction_only = false;  // held after a limit: insertion may withdraw
  std::array<double, 4> configuration_goal{};
  bool configuration_moving = false;
  JoystickSource joystick_source = JoystickSource::none;
  bool joystick_deadman = false;
  bool joystick_conflict = false;  // more than one source held its deadman: no motion
  std::array<double, 4> joystick_axes{};
  bool relaxing = false;
  RelaxOutcome relax_outcome = RelaxOutcome::none;
  // With relax_outcome at_limit: which bend drive (2 proximal, 3 distal), which side, and the limit the
  // setpoint is held at (mm: the joint limit less its soft margin, or the operating limit).
  int relax_limit_joint = -1;
  bool relax_limit_upper = false;
  double relax_limit_mm = 0.0;
  bool withdrawing = false;
  bool guidance_lost = false;    // image_guided: no replanned target for kTrackingLostS
  double guidance_age_s = -1.0;  // image_guided: control time since the last target taken (-1: none)
};

// What the simulation shows the API (any thread).
struct CatheterSimulationView {
  bool present = false;
  double contact_force_n = 0.0;      // total wall force on the catheter now
  double max_contact_force_n = 0.0;  // largest since start
  double tip_bend_rad = 0.0;         // true total bend of the simulated catheter
  bool true_catheter = false;        // catheter.simulation.true_catheter: the plant differs from the model
  double true_insertion_mm = 0.0;    // with it: the arc length that reached the vessel (after slack, slip)
};

// The type's part of the control cycle (control thread only).
class CatheterController final : public RobotController {
 public:
  explicit CatheterController(SteerableCatheter& robot) : robot_(robot) {}
  void sense(ControlContext& ctx) noexcept override;
  void control(ControlContext& ctx) noexcept override;
  bool while_held(ControlContext& ctx) noexcept override;
  void apply(ControlContext& ctx, const PluginCommand& command) noexcept override;
  void delay(ControlContext& ctx, double lost) noexcept override;
  void reset(ControlContext& ctx) noexcept override;
  void state_command(ControlContext& ctx, safety::StateCommand command) noexcept override;
  void operator_lost(ControlContext& ctx) noexcept override;
  bool moving(const ControlContext& ctx) const noexcept override;
  bool servo_allowed(const ControlContext& ctx, std::span<const double> velocity) const noexcept override;
  bool hold_cleared(const ControlContext& ctx, char* why, std::size_t why_size) const noexcept override;
  void hold_ended(ControlContext& ctx) noexcept override;
  void publish(const ControlContext& ctx) noexcept override;

 private:
  std::int64_t reading_age_ns(std::int64_t stamp_ns, std::int64_t now_ns) const noexcept;
  void joystick_velocity(const ControlContext& ctx, std::array<double, 4>& v) noexcept;
  double operator_insertion_velocity(ControlContext& ctx) noexcept;
  void retraction(ControlContext& ctx) noexcept;
  void start_relax(ControlContext& ctx) noexcept;
  void relax(ControlContext& ctx) noexcept;
  void image_guided(ControlContext& ctx) noexcept;

  SteerableCatheter& robot_;
  ModeId last_mode_ = kJointMode;
  std::array<double, 4> console_axes_{};
  bool console_deadman_ = false;
  double console_time_ = -1.0;
  bool retraction_only_ = false;
  std::array<double, 2> spring_deflection_{};
  bool deflection_fresh_ = false;
  JoystickSource joystick_source_ = JoystickSource::none;
  bool joystick_deadman_ = false;
  bool joystick_conflict_ = false;
  std::array<double, 4> joystick_axes_{};
  bool relaxing_ = false;
  double relax_started_ = 0.0;
  double relax_settled_s_ = 0.0;  // time both springs have been within the relax target
  bool withdrawing_ = false;      // held: insertion moving back to withdraw_to_ (mm)
  double withdraw_to_ = 0.0;
  RelaxOutcome relax_outcome_ = RelaxOutcome::none;
  int relax_limit_joint_ = -1;
  bool relax_limit_upper_ = false;
  double relax_limit_mm_ = 0.0;
  std::uint64_t guided_sequence_ = 0;  // the last replanned target taken
  double guided_fix_t_ = 0.0;          // control time it was taken (or the mode entered)
  bool guidance_lost_ = false;
};

struct CatheterSimulation;  // catheter_simulation.cpp
class ImageGuidance;        // image_guidance.hpp

class SteerableCatheter final : public RobotPlugin {
 public:
  // Parses and checks the catheter settings and builds the model, controller, inputs and (on a
  // virtual bus) the simulation. Throws ConfigError naming the file and the key.
  SteerableCatheter(const RobotConfig& config, RobotAssembly& assembly);
  ~SteerableCatheter() override;

  const RobotKinematics& kinematics() const override { return *display_; }
  std::vector<ModeInfo> modes() const override;
  bool path_following() const override { return true; }
  RobotController& controller() override { return controller_; }
  void display_positions(std::span<const double> measured, std::span<double> out) const override;
  std::optional<Status> check_servo(ModeId mode, const OperatingStateView& state,
                                    std::span<const double> velocity) const override;
  std::optional<ServiceError> resume_refusal(const OperatingStateView& state) const override;
  std::optional<ServiceError> refuse_mode(ModeId mode, const OperatingStateView& state) const override;
  void start() override;
  void stop() override;
  std::unique_ptr<RobotApiExtension> api(RobotService& service,
                                         std::function<bool(const PluginCommand&)> post) override;
  ImageFeedback* image_feedback() override;
  const ImageGuidance& guidance() const noexcept { return *guidance_; }
  // The SIMULATED true catheter's backbone (world mm) when catheter.simulation.true_catheter is on, and
  // the arc length that reached the vessel; false / nullopt otherwise. Any thread.
  bool true_backbone(std::vector<Eigen::Vector3d>& out) const;
  std::optional<double> true_insertion_mm() const noexcept;
  // The SIMULATED plant's backbone (world mm: the true catheter's with one, else the plant's own shape
  // at its drives and carriages); false without a simulation. Any thread (tests, measurements).
  bool simulated_backbone(std::vector<Eigen::Vector3d>& out) const;

  const RobotConfig& config() const noexcept { return config_; }
  const CatheterSettings& settings() const noexcept { return settings_; }
  const teleop::CatheterConfigurationMap& map() const noexcept { return *map_; }
  const Eigen::Vector4d& psi_max_velocity() const noexcept { return psi_max_velocity_; }
  const Eigen::Vector4d& psi_max_acceleration() const noexcept { return psi_max_acceleration_; }
  CatheterSnapshot snapshot() const noexcept { return published_.load(); }
  CatheterSimulationView simulation_view() const noexcept;
  const std::vector<Eigen::Vector3d>& vessel() const noexcept { return vessel_; }
  // The insertion point: where the tip is at zero insertion, (0, 0, L1 + L2) with the insertion axis
  // +z — the origin of the path planner's insertion frame (shape_error_planner.hpp).
  std::optional<Eigen::Isometry3d> vessel_entry() const override;
  double lumen_radius_mm() const noexcept { return lumen_radius_mm_; }
  // The passive shaft along the scene's vessel (issue 31), when the catheter is in it: the scene has a
  // vessel and the simulation (if any) touches that one. Null: the shaft is straight (free space, or a
  // robot file's own channel).
  const teleop::VesselShaft* shaft() const noexcept { return shaft_ ? &*shaft_ : nullptr; }
  bool has_evdev() const noexcept { return evdev_ != nullptr; }
  bool has_analog_joystick() const noexcept { return joystick_receiver_ != nullptr; }
  // The SIMULATED ADC nodes on a virtual bus (for tests), else null.
  sim::SimulatedAnalogJoystick* simulated_analog_joystick() noexcept;
  sim::SimulatedAnalogInputNode* simulated_spring_sensor() noexcept;

 private:
  friend class CatheterController;
  void attach_simulation(RobotAssembly& assembly, RobotAssembly::BusAccess& bus);

  RobotConfig config_;
  CatheterSettings settings_;
  std::unique_ptr<RobotKinematics> display_;
  std::array<double, 2> display_gains_{1.0, 1.0};
  // With a calibrated shape: the assembled model the display draws (display_ wraps the same shape).
  std::optional<teleop::ModalCatheterKinematics> modal_display_;
  std::unique_ptr<teleop::CatheterConfigurationMap> map_;
  std::unique_ptr<teleop::ConfigurationSpaceController> configuration_;  // control thread
  Eigen::Vector4d psi_max_velocity_, psi_max_acceleration_;              // its quintic's bounds in ψ
  std::unique_ptr<canopen::AnalogInputReceiver> deflection_receiver_;    // bus thread
  std::unique_ptr<input::AnalogJoystickReceiver> joystick_receiver_;     // bus thread
  hardware::LatestValue<DeflectionReading> deflection_;
  hardware::LatestValue<input::JoystickState> analog_joystick_;
  // When the bus thread last handled any frame on the ADC nodes' bus (steady clock ns): the readings'
  // ages are measured against it, so that a stalled thread, which delays every frame alike, never
  // makes a sensor look silent (CatheterController::reading_age_ns).
  std::atomic<std::int64_t> bus_heard_ns_{0};
  std::unique_ptr<input::EvdevJoystick> evdev_;
  std::array<int, 4> evdev_output_{-1, -1, -1, -1};  // joint → output index of the evdev mapping
  std::unique_ptr<CatheterSimulation> simulation_;
  std::vector<Eigen::Vector3d> vessel_;  // simulated vessel centerline (mm), empty without one
  std::optional<teleop::VesselShaft> shaft_;
  double lumen_radius_mm_ = 0.0;
  std::unique_ptr<ImageGuidance> guidance_;
  RobotService* service_ = nullptr;  // for the loaded plan, when image_guided is entered (network threads)
  CatheterController controller_{*this};
  hardware::LatestValue<CatheterSnapshot> published_;
};

// The display model of the robot file's "kinematics" (constant curvature; catheter_display_model.cpp).
// The calibrated model's display (the assembled modal shape the plant bends with;
// catheter_display_model.cpp).
std::unique_ptr<RobotKinematics> make_modal_catheter_display_model(
    const teleop::ModalCatheterParameters& assembled, const nlohmann::json& kinematics);
std::unique_ptr<RobotKinematics> make_catheter_display_model(const nlohmann::json& kinematics,
                                                             std::size_t joints, const std::string& file);
// `inner` drawn on the passive shaft along the vessel (its shaft_display_length_mm along the vessel).
std::unique_ptr<RobotKinematics> make_shaft_display_model(std::unique_ptr<RobotKinematics> inner,
                                                          teleop::VesselShaft shaft,
                                                          const nlohmann::json& kinematics);

// The type's part of the network API (catheter_api.cpp).
std::unique_ptr<RobotApiExtension> make_catheter_api(SteerableCatheter& robot, RobotService& service,
                                                     std::function<bool(const PluginCommand&)> post);

}  // namespace tendril::server
