// Configuration-space control of the steerable microcatheter (Abah 2022, §4.7.2,
// with three misprints corrected).
//
// Configuration ψ = [q1 insertion (mm), q2 roll (rad), θ_L1, θ_L2], θ_Li the ASSEMBLED tip bend angle
// of segment i (rad, 0 = straight). From the tip-only modal model (ModalCatheterKinematics):
//   nominal bend   θ̃*_i(q) = π/2 − θ_i(L_i, q)           (θ is the tangent angle from x̂)
//   loss (4.13–14) θ_Li     = a_i·θ̃*_i + b_i
//   coupling (4.15) the distal tube sees q4_eff = q4 + c·θ_L1, c = r1·cos δ2 (mm/rad), so
//                  θ_L2 = a2·θ̃*_2(q4 + c·θ_L1(q3)) + b2.
// With coupling disabled (ConfigurationRateParameters::coupling_enabled = false) the map models an
// uncoupled catheter (c = 0) in the forward, inverse and rate maps alike, so they stay consistent.
//
// Rates (4.21)–(4.23), via ConfigurationRateMap: ∂θ_Li/∂q = a_i·∂θ̃*_i/∂q = −a_i·∂θ_i(L_i, q)/∂q
// (the bend grows as the tangent angle falls), and q̇4 = θ̇_L2/(a2·∂θ̃*_2/∂q) − c·θ̇_L1.
#pragma once

#include <Eigen/Core>

#include "tendril/teleop/modal_catheter_kinematics.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"
#include "tendril/teleop/shape_calibration.hpp"

namespace tendril::teleop {

class CatheterConfigurationMap {
 public:
  using Vector4 = Eigen::Matrix<double, 4, 1>;

  // The inverse looks for bend actuations in [−kActuationSearchRange, +kActuationSearchRange] mm, a
  // few times the longest carriage stroke (seed: q3 ∈ [−6, 10] mm, |q4| ≤ 5 mm); a bend that needs
  // more than this is treated as unreachable.
  static constexpr double kActuationSearchRange = 50.0;

  // Throws std::invalid_argument when either parameter set is invalid (see ModalCatheterKinematics
  // and ConfigurationRateMap).
  CatheterConfigurationMap(const ModalCatheterParameters& nominal, const ConfigurationRateParameters& rates);

  // ψ(q) including loss and coupling. Non-finite q gives a non-finite ψ.
  Vector4 configuration(const Vector4& q) const noexcept;

  // Inverse of configuration(): q1, q2 pass through; each bend solves θ̃*_i(q) = (θ_Li − b_i)/a_i for
  // the root closest to q = 0 (the tip angle is a polynomial in q; for the dissertation's m = 2 it is linear
  // and the root is unique). Returns false (q untouched) when ψ is not finite or a bend has no root
  // in the search range. Two roots closer together than the scan step (range/200) can be missed.
  bool joints(const Vector4& psi, Vector4& q) const noexcept;

  // q̇ from ψ̇ at q, eq. (4.21)–(4.23). Returns false and writes q̇ = 0 when q or ψ̇ is not finite or
  // a bend is singular there (a_i·∂θ̃*_i/∂q ≈ 0).
  bool joint_rates(const Vector4& q, const Vector4& psi_rate, Vector4& q_rate) const noexcept;

  // c = r1·cos δ2 (mm/rad) when coupling is enabled, else 0.
  double coupling() const noexcept { return coupling_; }
  const ModalCatheterKinematics& nominal() const noexcept { return nominal_; }
  const ConfigurationRateMap& rate_map() const noexcept { return rate_map_; }

 private:
  // Nominal bend θ̃*_i(q) and its derivative.
  double nominal_bend(CatheterSegment segment, double actuation) const noexcept;
  double nominal_bend_rate(CatheterSegment segment, double actuation) const noexcept;
  // q with θ̃*_i(q) = target closest to 0; false if none in range.
  bool solve_bend(CatheterSegment segment, double target, double& actuation) const noexcept;

  ModalCatheterKinematics nominal_;
  ConfigurationRateMap rate_map_;
  double coupling_;
};

// Data flow per tick: a quintic in ψ (4 dims) gives ψ_des(t) and ψ̇_des(t); (4.21) maps ψ̇_des to q̇_des
// at the current q_des; q_des = ∫ q̇_des dt. Real-time safe: fixed storage, no
// allocation, every per-tick call noexcept. Not thread-safe (one control thread owns it).
class ConfigurationSpaceController {
 public:
  using Vector4 = CatheterConfigurationMap::Vector4;

  // Gain (1/s) of the drift correction in step(): a residual ψ error decays with τ = 50 ms. Slow
  // enough that a q_des the caller clamped is pulled back smoothly rather than in one tick.
  static constexpr double kDriftCorrectionRate = 20.0;

  // Limits per ψ component (mm/s, rad/s, rad/s, rad/s and the same per s): finite and > 0, else
  // std::invalid_argument. The map is copied (it is immutable and copying does not allocate).
  ConfigurationSpaceController(const CatheterConfigurationMap& map, const Vector4& psi_max_velocity,
                               const Vector4& psi_max_acceleration);

  // Hold at ψ(q_des) from time t; the next step() leaves q_des where it is, so there is no jump. A
  // non-finite q_des or t leaves the controller unarmed: step() then holds and returns false.
  void reset(double t, const Vector4& q_des) noexcept;

  // New quintic from the ψ_des state sampled at t (position, velocity and acceleration continuous) to
  // psi_goal. Returns false, changing nothing, when not armed by reset(), when t or the goal is not
  // finite, or when no joint vector reaches the goal (joints() fails).
  bool retarget(double t, const Vector4& psi_goal) noexcept;

  // Advances q_des over the tick (t − dt, t]: on return q_des is the command for time t and qd_des
  // the joint rate used over the tick. Integrator: explicit midpoint rule (RK2), q_des += q̇·dt with
  // q̇ = (4.21) applied to the ψ̇_des sampled at the tick's middle, evaluated at the q_des predicted
  // for the tick's middle (an Euler half step). With the dissertation's m = 2 model ψ(q) is affine and the
  // map constant, so only the time quadrature errs (O(dt³) per tick).
  // Drift correction: the ψ error the step would leave at t, ψ_des(t) − ψ(q_des) − ψ̇_des·dt, is added
  // as a rate kDriftCorrectionRate·error (at most error/dt) through the same map, i.e. a gradual
  // correction toward joints(ψ_des(t)) that also pulls back a q_des the caller has changed (clamped).
  // Returns false with qd_des = 0 and q_des unchanged (hold) when unarmed, dt is not > 0 or not
  // finite, q_des is not finite, or the map is singular at q_des.
  bool step(double t, double dt, Vector4& q_des, Vector4& qd_des) noexcept;

  // Shifts the quintic `dt` later (see QuinticInterpolator::delay).
  void delay(double dt) noexcept { interpolator_.delay(dt); }
  // Whether the quintic has reached its goal by t (false when unarmed).
  bool done(double t) const noexcept;
  // ψ goal of the current segment (ψ at reset while holding).
  Vector4 goal() const noexcept;
  // ψ_des(t) of the quintic.
  Vector4 desired_configuration(double t) const noexcept;
  double duration() const noexcept { return interpolator_.duration(); }
  const CatheterConfigurationMap& map() const noexcept { return map_; }

 private:
  CatheterConfigurationMap map_;
  QuinticInterpolator interpolator_;
  Vector4 max_velocity_;
  Vector4 max_acceleration_;
  bool armed_ = false;
};

}  // namespace tendril::teleop
