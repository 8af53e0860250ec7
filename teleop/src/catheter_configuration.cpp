#include "tendril/teleop/catheter_configuration.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <span>
#include <stdexcept>

namespace tendril::teleop {
namespace {

// Cells per side of q = 0 in the root scan of solve_bend (0.25 mm with the 50 mm range).
constexpr int kScanCells = 200;

std::span<double> as_span(CatheterConfigurationMap::Vector4& v) noexcept { return {v.data(), 4}; }
std::span<const double> as_span(const CatheterConfigurationMap::Vector4& v) noexcept { return {v.data(), 4}; }

}  // namespace

CatheterConfigurationMap::CatheterConfigurationMap(const ModalCatheterParameters& nominal,
                                                   const ConfigurationRateParameters& rates)
    : nominal_(nominal),
      rate_map_(rates),
      // ConfigurationRateMap stores A_coupling(4,3) = −r1·cos δ2 (0 when disabled); the physical shift
      // of the distal actuation is its negative.
      coupling_(-rate_map_.coupling()) {}

double CatheterConfigurationMap::nominal_bend(CatheterSegment segment, double actuation) const noexcept {
  return std::numbers::pi / 2.0 - nominal_.tip_angle(segment, actuation);
}

double CatheterConfigurationMap::nominal_bend_rate(CatheterSegment segment, double actuation) const noexcept {
  return -nominal_.tip_angle_rate(segment, actuation);
}

CatheterConfigurationMap::Vector4 CatheterConfigurationMap::configuration(const Vector4& q) const noexcept {
  const ConfigurationRateParameters& p = rate_map_.parameters();
  Vector4 psi;
  psi[0] = q[0];
  psi[1] = q[1];
  psi[2] = p.proximal_loss.assembled_angle(nominal_bend(CatheterSegment::kProximal, q[2]));
  // The distal tube sees its carriage displacement plus the proximal bend's share (4.15).
  psi[3] = p.distal_loss.assembled_angle(nominal_bend(CatheterSegment::kDistal, q[3] + coupling_ * psi[2]));
  return psi;
}

bool CatheterConfigurationMap::solve_bend(CatheterSegment segment, double target,
                                          double& actuation) const noexcept {
  if (!std::isfinite(target)) return false;
  auto residual = [&](double q) { return nominal_bend(segment, q) - target; };
  // Scan cells outward from q = 0 (alternating sides) for the first sign change, so the root nearest
  // the straight pose wins when a higher-order model has several.
  constexpr double kStep = kActuationSearchRange / kScanCells;
  double lo = 0.0, hi = 0.0, f_lo = 0.0, f_hi = 0.0;
  bool bracketed = false;
  const double f0 = residual(0.0);
  if (f0 == 0.0) {
    actuation = 0.0;
    return true;
  }
  for (int k = 0; k < kScanCells && !bracketed; ++k) {
    for (const double side : {1.0, -1.0}) {
      const double a = side * k * kStep, b = side * (k + 1) * kStep;
      const double fa = residual(a), fb = residual(b);
      if (!std::isfinite(fa) || !std::isfinite(fb)) return false;
      if (fb == 0.0) {
        actuation = b;
        return true;
      }
      if ((fa < 0.0) != (fb < 0.0)) {
        lo = std::min(a, b);
        hi = std::max(a, b);
        f_lo = a < b ? fa : fb;
        f_hi = a < b ? fb : fa;
        bracketed = true;
        break;
      }
    }
  }
  if (!bracketed) return false;
  // Newton inside the bracket; a step that leaves it (or a flat slope) falls back to bisection.
  double q = f_lo == f_hi ? 0.5 * (lo + hi) : lo - f_lo * (hi - lo) / (f_hi - f_lo);
  for (int i = 0; i < 100; ++i) {
    const double f = residual(q);
    if (std::abs(f) <= 1e-14 * std::max(1.0, std::abs(target)) ||
        hi - lo <= 1e-15 * std::max(1.0, std::abs(q))) {
      break;
    }
    if ((f < 0.0) == (f_lo < 0.0)) {
      lo = q;
      f_lo = f;
    } else {
      hi = q;
    }
    const double slope = nominal_bend_rate(segment, q);
    double next = slope != 0.0 ? q - f / slope : lo - 1.0;
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    q = next;
  }
  actuation = q;
  return true;
}

bool CatheterConfigurationMap::joints(const Vector4& psi, Vector4& q) const noexcept {
  if (!psi.allFinite()) return false;
  const ConfigurationRateParameters& p = rate_map_.parameters();
  // Inverse loss lines θ̃* = (θ_L − b)/a (the slopes are non-zero: checked by ConfigurationRateMap).
  const double proximal_target = (psi[2] - p.proximal_loss.offset) / p.proximal_loss.slope;
  const double distal_target = (psi[3] - p.distal_loss.offset) / p.distal_loss.slope;
  double q3 = 0.0, q4_effective = 0.0;
  if (!solve_bend(CatheterSegment::kProximal, proximal_target, q3) ||
      !solve_bend(CatheterSegment::kDistal, distal_target, q4_effective)) {
    return false;
  }
  // Subtract the coupling shift of the proximal bend the solved q3 actually produces, so that
  // configuration(q) reproduces θ_L2 to solver precision.
  const double theta_l1 = p.proximal_loss.assembled_angle(nominal_bend(CatheterSegment::kProximal, q3));
  q = Vector4(psi[0], psi[1], q3, q4_effective - coupling_ * theta_l1);
  return true;
}

bool CatheterConfigurationMap::joint_rates(const Vector4& q, const Vector4& psi_rate,
                                           Vector4& q_rate) const noexcept {
  if (!q.allFinite()) {
    q_rate.setZero();
    return false;
  }
  const double theta_l1 = configuration(q)[2];
  // ∂θ̃*_i/∂q = −∂θ_i(L_i, q)/∂q; the distal one at the effective actuation the tube sees.
  const double proximal_rate = nominal_bend_rate(CatheterSegment::kProximal, q[2]);
  const double distal_rate = nominal_bend_rate(CatheterSegment::kDistal, q[3] + coupling_ * theta_l1);
  return rate_map_.configuration_rates_to_joint_rates(psi_rate, proximal_rate, distal_rate, q_rate);
}

ConfigurationSpaceController::ConfigurationSpaceController(const CatheterConfigurationMap& map,
                                                           const Vector4& psi_max_velocity,
                                                           const Vector4& psi_max_acceleration)
    : map_(map), interpolator_(4), max_velocity_(psi_max_velocity), max_acceleration_(psi_max_acceleration) {
  if (!psi_max_velocity.allFinite() || !(psi_max_velocity.array() > 0.0).all()) {
    throw std::invalid_argument(
        "ConfigurationSpaceController: every configuration velocity limit must be finite and > 0");
  }
  if (!psi_max_acceleration.allFinite() || !(psi_max_acceleration.array() > 0.0).all()) {
    throw std::invalid_argument(
        "ConfigurationSpaceController: every configuration acceleration limit must be finite and > 0");
  }
}

void ConfigurationSpaceController::reset(double t, const Vector4& q_des) noexcept {
  const Vector4 psi = map_.configuration(q_des);
  armed_ = std::isfinite(t) && psi.allFinite();
  if (armed_) interpolator_.reset(as_span(psi), t);
}

bool ConfigurationSpaceController::retarget(double t, const Vector4& psi_goal) noexcept {
  if (!armed_ || !std::isfinite(t) || !psi_goal.allFinite()) return false;
  Vector4 q_goal;
  if (!map_.joints(psi_goal, q_goal)) return false;
  // kLimitsUnreachable still starts a (least-violating) segment from the continuous state; only a
  // rejected argument leaves the old segment in place.
  return interpolator_.retarget(t, as_span(psi_goal), as_span(max_velocity_), as_span(max_acceleration_)) !=
         RetargetStatus::kInvalidArgument;
}

bool ConfigurationSpaceController::step(double t, double dt, Vector4& q_des, Vector4& qd_des) noexcept {
  auto hold = [&]() {
    qd_des.setZero();
    return false;
  };
  if (!armed_ || !std::isfinite(t) || !std::isfinite(dt) || dt <= 0.0 || !q_des.allFinite()) return hold();
  Vector4 psi_end, psi_mid, psi_rate_mid, unused_rate, unused_acceleration;
  interpolator_.sample(t, as_span(psi_end), as_span(unused_rate), as_span(unused_acceleration));
  interpolator_.sample(t - 0.5 * dt, as_span(psi_mid), as_span(psi_rate_mid), as_span(unused_acceleration));
  // Feed-forward ψ̇_des plus the drift correction (see the header): the part of ψ_des(t) that the
  // feed-forward alone would miss from where q_des is now. Measured at the tick's end because ψ_des(t)
  // is continuous across a retarget at t, while the old segment's ψ_des(t − dt) is gone by then.
  // The roll error is not wrapped: q2 is a joint position, not an orientation.
  const double gain = std::min(kDriftCorrectionRate, 1.0 / dt);
  const Vector4 miss = psi_end - map_.configuration(q_des) - psi_rate_mid * dt;
  const Vector4 psi_rate = psi_rate_mid + gain * miss;
  // Midpoint rule (RK2) in q as well: (4.21) again halfway along the tick, so a model whose J_ψq
  // varies with q (m > 2) does not lag by the Euler error. For m = 2 both evaluations agree.
  Vector4 q_rate_start, q_rate;
  if (!map_.joint_rates(q_des, psi_rate, q_rate_start) ||
      !map_.joint_rates(q_des + 0.5 * dt * q_rate_start, psi_rate, q_rate) || !q_rate.allFinite()) {
    return hold();
  }
  q_des += q_rate * dt;
  qd_des = q_rate;
  return true;
}

bool ConfigurationSpaceController::done(double t) const noexcept { return armed_ && interpolator_.done(t); }

ConfigurationSpaceController::Vector4 ConfigurationSpaceController::goal() const noexcept {
  const std::span<const double> g = interpolator_.goal();
  return {g[0], g[1], g[2], g[3]};
}

ConfigurationSpaceController::Vector4 ConfigurationSpaceController::desired_configuration(
    double t) const noexcept {
  Vector4 psi, rate, acceleration;
  interpolator_.sample(t, as_span(psi), as_span(rate), as_span(acceleration));
  return psi;
}

}  // namespace tendril::teleop
