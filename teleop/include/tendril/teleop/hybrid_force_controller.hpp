// HybridPositionForceController: the ultrasound probe's task-space velocity controller of Heunis et al. 2021
// Appendix A (eqs. A1–A14), with its misprints corrected.
//
// A pure function of (arm model, arm data, controller state, inputs, dt): step() reads the measured
// joints, the target probe pose and the force sensor, and returns joint velocities through the damped
// least-squares inverse (A13–A14), clamped to the joint velocity and position limits. It never
// allocates, never throws and never returns a non-finite value: bad inputs give zero joint velocities
// and a status that says why.
//
// Phases (the article's free-space and contact modes; where it is silent, the switch is our choice):
//  * position — free space or pre-positioning: A1 → A9 with the full 3-D error towards the target
//    surface point s_i, A2–A8 for the orientation. The probe approaches the surface under position
//    control, and hands over to force control before it can push: the switch happens when the surface
//    point lies within `switch_distance` (5 mm) ahead along the surface normal, or as soon as a normal
//    force above `contact_detect_force` (0.1 N) is felt (a surface higher than planned). The paper zeroes
//    the normal error in free space instead ("2-D error"), which never brings the probe down unless it
//    was pre-positioned; the full error up to the switch distance does the same job and also works
//    from far away.
//  * force — A11: the position law sees only E_∥ = E_p − n̂(n̂·E_p), the error parallel to the surface;
//    along the normal n̂ (into the tissue) the explicit force law A10 runs: v[k] = K_p·(d_f − F_n) +
//    K_i·v[k−1] (mm/s), a leaky integrator whose steady state is K_p/(1 − K_i) = 1.67 (mm/s)/N: it
//    approaches at 1.33 mm/s in the air and settles on d_f = 0.8 N against a spring without overshoot
//    (the loop is first order, time constant 1/(1.67·k) — 0.3 s at 2 N/mm, 6 s at 0.1 N/mm). A12 sums
//    the two. On the switch v[k−1] starts from the normal velocity the position law was commanding, so
//    the approach speed decays to A10's over a few cycles (×0.7 per cycle) instead of dropping at once
//    from the position law's ≈ 9 mm/s at 5 mm to 0.4 mm/s. The force phase persists while the probe slides
//    from via-point to via-point; it returns to position only when no force is felt and the
//    target lies more than 2·switch_distance ahead (the tissue moved away or a new approach was planned).
//
// Caps: |V_e| ≤ V_d = 50 mm/s including the integral and force terms, with the normal
// (force) component served first and the lateral one scaled into what remains; |ω_e| ≤ ω_d = 0.1 rad/s;
// and the joint velocities are scaled so that the twist they produce, J·q̇, keeps both caps too.
//
// Force convention: `force` is the force the environment exerts on the probe, in the tool frame (the
// force sensor's frame, whose z axis is the probe axis pointing into the tissue), so pressing the
// tissue reads as negative z; F_n = −f_z is the normal force of the tissue against the transducer face.
//
// Acquisition gate: open when, in the force phase, |E_∥| < d_p (0.5 mm), E_θy < d_θ and
// E_θz < d_θ (0.01 rad) and |F_n − d_f| ≤ 0.1 N have all held for 100 ms (tolerance and hold are the
// our defaults). The position error the gate sees in contact is E_∥: along the normal
// the probe sits wherever the tissue balances d_f, not at the planned surface point.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>

#include "tendril/teleop/serial_arm_kinematics.hpp"
#include "tendril/teleop/task_space_velocity.hpp"

namespace tendril::teleop {

enum class ProbePhase : std::uint8_t { position, force };
const char* to_string(ProbePhase phase) noexcept;

enum class HybridControlStatus : std::uint8_t {
  ok,
  invalid_input,  // a non-finite joint, target, normal or force, a target rotation that is not one, dt ≤ 0
  force_lost,     // no valid force reading: hold (zero joint velocities), as the article's safety asks
};
const char* to_string(HybridControlStatus status) noexcept;

struct ForceControlParameters {
  double contact_force = 0.8;         // d_f (N), Table 1
  double proportional_gain = 0.5;     // K_p ((mm/s)/N), Table 1
  double integral_gain = 0.7;         // K_i (per control iteration, < 1), Table 1
  double switch_distance = 5.0;       // mm ahead along the normal where force control takes over (our choice)
  double contact_detect_force = 0.1;  // N of normal force that also switches to force control (our choice)
};

struct AcquisitionGateParameters {
  double position_setpoint = 0.5;      // d_p (mm), Table 1
  double orientation_setpoint = 0.01;  // d_θ (rad), Table 1
  double force_tolerance = 0.1;        // |F_n − d_f| (N) (our choice)
  double hold_time = 0.1;              // s (our choice)
};

struct HybridControlParameters {
  TaskSpaceGains task{};
  ForceControlParameters force{};
  AcquisitionGateParameters gate{};
};

struct HybridControlInputs {
  ArmVector q = ArmVector::Zero();  // measured joint positions (rad)
  // The probe pose at the surface point s_i (Δs_i after motion compensation), base frame: its z axis
  // points into the tissue, towards the arterial centroid (Algorithm 2).
  Eigen::Isometry3d target = Eigen::Isometry3d::Identity();
  // Unit surface normal into the tissue (x̂ of A11, base frame); zero uses the target's z axis .
  Eigen::Vector3d surface_normal = Eigen::Vector3d::Zero();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();  // N, on the probe, tool frame (see above)
  bool force_valid = false;                         // false (sensor lost or stale): hold
  bool contact_enabled = true;  // false: pre-positioning, pure pose control, never the force phase
};

// The controller's memory between cycles (one per arm); reset() before a new sweep.
struct HybridControlState {
  ProbePhase phase = ProbePhase::position;
  double force_velocity = 0.0;   // v[k−1] of A10 along the normal (mm/s)
  double normal_velocity = 0.0;  // the normal part of the last commanded V_e (mm/s)
  double gate_time = 0.0;        // how long the gate's conditions have held (s)
  bool gate_holding = false;     // the conditions held at the last cycle
  void reset() noexcept { *this = HybridControlState{}; }
};

struct HybridControlOutput {
  ArmVector joint_velocity = ArmVector::Zero();  // rad/s: what to command
  Twist twist = Twist::Zero();                   // V_s = [V_e; ω_e] after the caps (mm/s, rad/s)
  HybridControlStatus status = HybridControlStatus::invalid_input;
  ProbePhase phase = ProbePhase::position;
  Eigen::Vector3d position_error = Eigen::Vector3d::Zero();  // E_p of A1 (mm)
  double gate_position_error = 0.0;  // |E_p| in the position phase, |E_∥| in the force phase (mm)
  double normal_distance = 0.0;      // n̂·E_p (mm): how far ahead along the normal the surface point is
  OrientationError orientation{};    // E_θz, E_θy and their axes
  double normal_force = 0.0;         // F_n (N), positive when pressing
  double force_error = 0.0;          // d_f − F_n (N)
  bool acquire = false;              // the acquisition gate is open: take the ultrasound image
  bool twist_limited = false;        // a cap was reached
  bool velocity_limited = false;     // the joint velocity limits scaled the solution down
  bool position_limited = false;     // a joint was stopped at its position limit
  bool speed_limited = false;        // scaled so that the arm's tool twist J·q̇ stays within the caps
  double damping = 0.0;              // ρ of the damped inverse (SI)
};

class HybridPositionForceController {
 public:
  // Throws std::invalid_argument naming the parameter when one is out of range (gains not finite and
  // positive, K_i outside [0, 1), negative distances or tolerances).
  explicit HybridPositionForceController(const HybridControlParameters& parameters);

  const HybridControlParameters& parameters() const noexcept { return parameters_; }

  HybridControlOutput step(const SerialArmKinematics& model, SerialArmData& data, HybridControlState& state,
                           const HybridControlInputs& inputs, double dt) const noexcept;

 private:
  HybridControlParameters parameters_;
};

}  // namespace tendril::teleop
