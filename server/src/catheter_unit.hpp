// The steerable-catheter parts of a robot in the runtime: its configuration-space model and
// controller, the spring-deflection and joystick inputs (CAN ADC nodes, evdev), and, on a virtual
// bus, the SIMULATED series-elastic plant in its vessel with simulated ADC nodes.
//
// Threads: the bus thread decodes the ADC nodes' PDOs into the LatestValue slots; the control thread
// reads those slots and owns `configuration`; network threads only read the immutable model, the
// settings and the simulation's published state.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "catheter_settings.hpp"
#include "tendril/drivers/canopen/analog_input_node.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/input/evdev_joystick.hpp"
#include "tendril/server/control_api.hpp"
#include "tendril/teleop/catheter_configuration.hpp"

namespace tendril::server {

struct BusUnit;
struct JointBinding;

struct DeflectionReading {
  std::array<double, 2> mm{};  // proximal, distal: drive − carriage
  std::int64_t stamp_ns = 0;   // steady clock
  bool valid = false;          // false: never read, or a wiring fault on a channel
};

// What the simulation shows the API (any thread).
struct CatheterSimulationView {
  bool present = false;
  double contact_force_n = 0.0;      // total wall force on the catheter now
  double max_contact_force_n = 0.0;  // largest since start
  double tip_bend_rad = 0.0;         // true total bend of the simulated catheter
};

struct CatheterSimulation;  // catheter_simulation.cpp

struct CatheterUnit {
  CatheterSettings settings;
  std::unique_ptr<teleop::CatheterConfigurationMap> map;
  std::unique_ptr<teleop::ConfigurationSpaceController> configuration;  // control thread
  Eigen::Vector4d psi_max_velocity, psi_max_acceleration;               // its quintic's bounds in ψ
  std::unique_ptr<canopen::AnalogInputReceiver> deflection_receiver;    // bus thread
  std::unique_ptr<input::AnalogJoystickReceiver> joystick_receiver;     // bus thread
  hardware::LatestValue<DeflectionReading> deflection;
  hardware::LatestValue<input::JoystickState> analog_joystick;
  // When the bus thread last handled any frame on this bus (steady clock ns): the readings' ages are
  // measured against it, so that a stalled thread, which delays every frame alike, never makes a
  // sensor look silent (reading_age_ns in catheter_control.cpp).
  std::atomic<std::int64_t> bus_heard_ns{0};
  std::unique_ptr<input::EvdevJoystick> evdev;
  std::array<int, 4> evdev_output{-1, -1, -1, -1};  // joint → output index of the evdev mapping
  std::unique_ptr<CatheterSimulation> simulation;
  std::vector<Eigen::Vector3d> vessel;  // simulated vessel centerline (mm), empty without one
  double lumen_radius_mm = 0.0;

  CatheterUnit();
  ~CatheterUnit();
  CatheterUnit(const CatheterUnit&) = delete;
  CatheterUnit& operator=(const CatheterUnit&) = delete;

  CatheterSimulationView simulation_view() const noexcept;
};

// Builds the catheter unit of a 4-joint robot: model, controller, receivers on `bus` (the bus of its
// bend drives), the evdev joystick (started with the runtime), and on a virtual bus the simulated
// plant, vessel and ADC nodes, registered as plants and endpoints of that bus. Throws ConfigError.
std::unique_ptr<CatheterUnit> make_catheter_unit(const RobotConfig& rc, BusUnit& bus,
                                                 const std::vector<JointBinding>& bindings);

// On a virtual bus: the simulated plant, vessel and ADC nodes (catheter_simulation.cpp).
void attach_catheter_simulation(CatheterUnit& c, const RobotConfig& rc, BusUnit& bus,
                                const std::vector<JointBinding>& bindings);

// NMT start for the ADC nodes (they send PDOs only when operational).
void start_catheter_nodes(CatheterUnit& c, BusUnit& bus);

struct RobotUnit;
struct RobotSnapshot;
// API read-out (catheter_api.cpp, network threads).
void catheter_robot_json(const RobotUnit& r, nlohmann::json& robot);
void catheter_state_json(const RobotUnit& r, const RobotSnapshot& s, nlohmann::json& out);
// The simulated vessel as a scene entity (a line as thick as the lumen).
void add_catheter_entities(const RobotUnit& r, nlohmann::json& scene);
// Joint values for the display model: bend entries are the assembled tip bend angles (from the
// effective actuation q − deflection through the configuration map) divided by the display model's
// bend gains, so the drawn shape shows the bend the sensors imply.
std::vector<double> catheter_display_positions(const RobotUnit& r, const RobotSnapshot& s);

// The ways out of a hold (network threads). The "hold" object of operating_state while PAUSED, for a
// catheter: its cause, whether it has cleared, what the operator can do now and what to do next.
void catheter_hold_json(const RobotUnit& r, const RobotSnapshot& s, nlohmann::json& hold);
// 409 naming the cause and what to do when resuming now would hold the robot again at once; nullopt
// when resume may go ahead.
std::optional<ApiResult> catheter_resume_refusal(const RobotUnit& r, const RobotSnapshot& s);
// state_command "relax": the bend drives follow their springs while the robot is held (PAUSED).
ApiResult relax_springs(RobotUnit& r, const RobotSnapshot& s);
// state_command "withdraw" {"distance_mm": d}: held with retraction allowed, the insertion moves back
// by d (0 < d <= 10 mm) at the joystick's full insertion speed.
ApiResult withdraw_catheter(RobotUnit& r, const RobotSnapshot& s, const nlohmann::json& body);

}  // namespace tendril::server
