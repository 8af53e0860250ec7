// Settings of a steerable catheter robot (the "catheter" object of its robot file, Abah 2022, ch. 4):
// the nominal shape model with losses and coupling for configuration control, the spring-deflection
// sensors and their bound, active compliance, telemanipulation speeds and joystick inputs, and the
// simulated plant (springs, vessel, ADC nodes) used when its bus is virtual.
// Parsed at start-up; every mistake throws ConfigError naming the file and the key.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "tendril/drivers/input/analog_joystick.hpp"
#include "tendril/drivers/input/evdev_joystick.hpp"
#include "tendril/server/config.hpp"
#include "tendril/teleop/active_compliance.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"
#include "tendril/teleop/shape_calibration.hpp"

namespace tendril::server {

struct SpringDeflectionSensorSettings {
  std::uint8_t node_id = 0x31;  // CiA 401 ADC node with the two linear potentiometers
  double volts_per_mm = 0.5;    // potentiometer gain around the 2.5 V centre (±5 mm over 0–5 V)
  double limit_mm = 1.5;        // |deflection| beyond this holds the robot
  double stale_ms = 100.0;      // no reading for this long: the sensor is stale (hold)
  // The way out of a deflection hold: resume is accepted once both springs are within resume_mm
  // (hysteresis below the hold bound, so resuming does not hold again at the next bump); "relax" runs
  // active compliance on the bend drives until both are within half of it for 100 ms (so the spring
  // settling after the drives stop stays under resume_mm). Default: half the hold bound.
  double resume_mm = 0.75;
  double relax_timeout_s = 10.0;  // a relax that has not got there by then stops and says so
};

struct VesselTubeSettings {
  // The server's scene vessel ("centerline": "scene", placed at the catheter's insertion point, radii
  // from its file), a centerline file (CSV x,y,z in mm, the frame of the catheter base) or an arc channel.
  bool from_scene = false;
  std::string centerline_file;
  double lead_in_mm = 20.0;  // arc channel: straight part along +z from z = 0
  double bend_radius_mm = 25.0;
  double turn_deg = 90.0;
  double lumen_radius_mm = 1.5875;  // the dissertation's phantom tubing, ID 3.175 mm
};

// catheter.simulation.true_catheter: a SIMULATED plant that differs from the model the robot plans and
// controls with (off by default: the plant is the model). The dissertation gives no values; these are the
// mismatches its §4.11 high-level controller is there to absorb.
struct TrueCatheterSettings {
  bool enabled = false;
  double bend_scale = 1.0;            // the true bend (from straight) per the model's: 0.85 = 15 % weaker
  double distal_length_factor = 1.0;  // the true distal segment's length per the model's
  double slack_mm = 0.0;              // insertion dead band: drive travel that does not move the catheter
  // Stick-slip in the introducer: the shaft sticks and buckles until `stick_mm` of drive travel is
  // stored in it, then slips forward by slip_fraction of it (0: no stick-slip).
  double stick_mm = 0.0;
  double slip_fraction = 1.0;
};

struct CatheterSimulationSettings {
  double spring_stiffness_n_per_mm = 0.2;
  double tube_stiffness_n_per_mm = 0.0;
  double potentiometer_noise_mm = 0.005;
  double wall_stiffness_n_per_mm = 0.01;      // per backbone point: a compliant vessel wall
  double carriage_damping_n_s_per_mm = 0.02;  // tendon and rail friction, viscous
  double catheter_outer_radius_mm = 0.6;
  std::optional<VesselTubeSettings> vessel;  // none: the catheter moves in free space
  bool analog_joystick_node = true;          // simulate the ADC joystick node as well
  TrueCatheterSettings true_catheter;
};

struct CatheterSettings {
  // Tip-only model of the two bending segments (constant curvature k = nominal_bend_gain, or the
  // calibrated <segment>_shape_matrix) and the assembled-catheter loss lines.
  teleop::ModalCatheterParameters nominal;
  bool calibrated_shape = false;  // a <segment>_shape_matrix replaced constant curvature
  teleop::ConfigurationRateParameters rates;
  SpringDeflectionSensorSettings deflection;
  teleop::ActiveComplianceParameters compliance;
  std::array<double, 4> telemanipulation_max_speed{2.0, 0.5, 1.0, 1.0};  // per joint, at full stick
  bool retraction_only_while_held = true;
  double max_contact_force_n = 0.1;  // bound the spring limit keeps the tip force under (reported)
  std::optional<input::AnalogJoystickCalibration> analog_joystick;
  std::optional<input::EvdevJoystickOptions> evdev_joystick;
  CatheterSimulationSettings simulation;
};

// Parses rc.catheter (must be an object) for a 4-joint robot; relative paths resolve against the
// robot file's folder.
CatheterSettings parse_catheter_settings(const RobotConfig& rc);

// The assembled catheter's shape for the simulated plant and the display: the tip-only model through
// the loss lines (tip bend a_i·θ*_L + b_i), so that the plant bends as the configuration map predicts.
teleop::ModalCatheterParameters assembled_shape(const CatheterSettings& settings);

// The true catheter's shape (catheter.simulation.true_catheter) from the assembled one: the bend from
// straight scaled by bend_scale along both segments, the distal segment's length scaled.
teleop::ModalCatheterParameters true_shape(const teleop::ModalCatheterParameters& assembled,
                                           const TrueCatheterSettings& truth);

// The vessel centerline of the simulation (mm): loaded or built as an arc channel.
std::vector<Eigen::Vector3d> vessel_centerline(const VesselTubeSettings& vessel);

}  // namespace tendril::server
