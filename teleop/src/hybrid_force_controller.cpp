#include "tendril/teleop/hybrid_force_controller.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {

namespace {

void require(bool ok, const std::string& name, double value, const char* expected) {
  if (!ok) {
    throw std::invalid_argument("hybrid position/force controller: " + name + " must be " + expected +
                                " (got " + std::to_string(value) + ")");
  }
}

bool is_rotation(const Eigen::Matrix3d& r) noexcept {
  return r.allFinite() && (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         r.determinant() > 0.0;
}

// Hold: zero motion, forget the force recursion and the gate (they describe a contact we no longer see).
void hold(HybridControlState& state, HybridControlOutput& out) noexcept {
  out.joint_velocity.setZero();
  out.twist.setZero();
  state.force_velocity = 0.0;
  state.normal_velocity = 0.0;
  state.gate_holding = false;
  state.gate_time = 0.0;
  out.phase = state.phase;
}

}  // namespace

const char* to_string(ProbePhase phase) noexcept {
  switch (phase) {
    case ProbePhase::position:
      return "position";
    case ProbePhase::force:
      return "force";
  }
  return "unknown";
}

const char* to_string(HybridControlStatus status) noexcept {
  switch (status) {
    case HybridControlStatus::ok:
      return "ok";
    case HybridControlStatus::invalid_input:
      return "invalid input";
    case HybridControlStatus::force_lost:
      return "force sensor lost";
  }
  return "unknown";
}

HybridPositionForceController::HybridPositionForceController(const HybridControlParameters& parameters)
    : parameters_(parameters) {
  validate(parameters.task);
  const ForceControlParameters& f = parameters.force;
  require(std::isfinite(f.contact_force) && f.contact_force > 0.0, "force.contact_force (d_f)",
          f.contact_force, "finite and positive");
  require(std::isfinite(f.proportional_gain) && f.proportional_gain > 0.0, "force.proportional_gain (K_p)",
          f.proportional_gain, "finite and positive");
  require(f.integral_gain >= 0.0 && f.integral_gain < 1.0, "force.integral_gain (K_i)", f.integral_gain,
          "in [0, 1) for the recursion of A10 to converge");
  require(std::isfinite(f.switch_distance) && f.switch_distance >= 0.0, "force.switch_distance",
          f.switch_distance, "finite and >= 0");
  require(std::isfinite(f.contact_detect_force) && f.contact_detect_force > 0.0, "force.contact_detect_force",
          f.contact_detect_force, "finite and positive");
  const AcquisitionGateParameters& g = parameters.gate;
  require(std::isfinite(g.position_setpoint) && g.position_setpoint > 0.0, "gate.position_setpoint (d_p)",
          g.position_setpoint, "finite and positive");
  require(std::isfinite(g.orientation_setpoint) && g.orientation_setpoint > 0.0,
          "gate.orientation_setpoint (d_theta)", g.orientation_setpoint, "finite and positive");
  require(std::isfinite(g.force_tolerance) && g.force_tolerance > 0.0, "gate.force_tolerance",
          g.force_tolerance, "finite and positive");
  require(std::isfinite(g.hold_time) && g.hold_time >= 0.0, "gate.hold_time", g.hold_time, "finite and >= 0");
}

HybridControlOutput HybridPositionForceController::step(const SerialArmKinematics& model, SerialArmData& data,
                                                        HybridControlState& state,
                                                        const HybridControlInputs& in,
                                                        double dt) const noexcept {
  const TaskSpaceGains& gains = parameters_.task;
  const ForceControlParameters& fp = parameters_.force;
  const AcquisitionGateParameters& gp = parameters_.gate;
  HybridControlOutput out;

  const bool inputs_finite = std::isfinite(dt) && dt > 0.0 && in.q.allFinite() &&
                             in.target.translation().allFinite() && is_rotation(in.target.linear()) &&
                             in.surface_normal.allFinite() && (!in.force_valid || in.force.allFinite());
  if (!inputs_finite || !model.update(in.q, data)) {
    out.status = HybridControlStatus::invalid_input;
    hold(state, out);
    return out;
  }
  if (!in.force_valid) {
    out.status = HybridControlStatus::force_lost;
    hold(state, out);
    return out;
  }

  // A1 and the quantities every phase needs.
  const Eigen::Vector3d probe_position = data.tool.translation();
  const double normal_length = in.surface_normal.norm();
  const Eigen::Vector3d normal = normal_length > 1e-9 ? Eigen::Vector3d(in.surface_normal / normal_length)
                                                      : Eigen::Vector3d(in.target.linear().col(2));
  out.position_error = in.target.translation() - probe_position;
  out.normal_distance = normal.dot(out.position_error);
  out.normal_force = -in.force.z();
  out.force_error = fp.contact_force - out.normal_force;

  // Phase switches.
  const bool touching = out.normal_force >= fp.contact_detect_force;
  const bool approach_done = touching || out.normal_distance <= fp.switch_distance;
  const bool moved_away = !touching && out.normal_distance > 2.0 * fp.switch_distance;
  if (!in.contact_enabled || (state.phase == ProbePhase::force && moved_away)) {
    state.phase = ProbePhase::position;
  } else if (state.phase == ProbePhase::position && approach_done) {
    state.phase = ProbePhase::force;
    state.force_velocity = state.normal_velocity;  // A10 continues from what was commanded
  }
  out.phase = state.phase;

  Eigen::Vector3d linear;
  if (state.phase == ProbePhase::position) {
    linear = linear_velocity(out.position_error, gains, dt);  // A9
    out.gate_position_error = out.position_error.norm();
    state.force_velocity = 0.0;
  } else {
    const Eigen::Vector3d parallel = out.position_error - normal * out.normal_distance;  // A11
    out.gate_position_error = parallel.norm();
    // A10 along the normal, kept within V_d (the recursion then cannot wind up past the cap).
    const double v_force =
        std::clamp(fp.proportional_gain * out.force_error + fp.integral_gain * state.force_velocity,
                   -gains.max_linear_speed, gains.max_linear_speed);
    state.force_velocity = v_force;
    // A9 on E_∥ (it has no normal component), scaled into the speed the force term leaves (A12 + cap).
    Eigen::Vector3d lateral = linear_velocity(parallel, gains, dt);
    const double budget =
        std::sqrt(std::max(0.0, gains.max_linear_speed * gains.max_linear_speed - v_force * v_force));
    const double lateral_speed = lateral.norm();
    if (lateral_speed > budget) {
      lateral *= budget / lateral_speed;
      out.twist_limited = true;
    }
    linear = lateral + v_force * normal;  // A12
  }

  out.orientation = orientation_error(data.tool.linear(), in.target.linear());  // A2–A5
  out.twist.head<3>() = linear;
  out.twist.tail<3>() = angular_velocity(out.orientation, gains);  // A6–A8
  out.twist_limited =
      limit_twist(out.twist, gains.max_linear_speed, gains.max_angular_speed) || out.twist_limited;
  state.normal_velocity = normal.dot(out.twist.head<3>());

  // A13–A14 and the joint limits.
  const JointVelocityResult joints =
      resolve_twist(model, data, out.twist, gains.max_linear_speed, gains.max_angular_speed, dt);
  out.damping = joints.damping;
  out.velocity_limited = joints.velocity_limited;
  out.position_limited = joints.position_limited;
  out.speed_limited = joints.speed_limited;
  if (!joints.valid) {
    out.status = HybridControlStatus::invalid_input;
    hold(state, out);
    return out;
  }
  out.joint_velocity = joints.joint_velocity;
  out.status = HybridControlStatus::ok;

  // The acquisition gate.
  const bool conditions =
      state.phase == ProbePhase::force && out.gate_position_error < gp.position_setpoint &&
      out.orientation.about_y < gp.orientation_setpoint &&
      out.orientation.about_z < gp.orientation_setpoint && std::abs(out.force_error) <= gp.force_tolerance;
  if (!conditions) {
    state.gate_holding = false;
    state.gate_time = 0.0;
  } else if (!state.gate_holding) {
    state.gate_holding = true;  // the hold starts now; it has lasted for no time yet
    state.gate_time = 0.0;
  } else {
    state.gate_time += dt;
  }
  // A tolerance of a nanosecond so that hold_time/dt cycles of dt open it despite rounding.
  out.acquire = state.gate_holding && state.gate_time >= gp.hold_time - 1e-9;
  return out;
}

}  // namespace tendril::teleop
