#include "tendril/teleop/perception/tip_ekf.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <cmath>
#include <numbers>
#include <string>

namespace tendril::teleop::perception {

namespace {

constexpr double kSymmetryTolerance = 1e-9;

// Checks a covariance-like matrix; `what` names it for the message ("Q (process noise)", ...).
void validate_covariance(const Eigen::Matrix3d& m, const std::string& what) {
  if (!m.allFinite()) {
    throw TipEkfConfigError("tip EKF: " + what + " holds a NaN or infinite entry");
  }
  const double scale = m.cwiseAbs().maxCoeff();
  if (scale == 0.0) {
    throw TipEkfConfigError("tip EKF: " + what + " is all zeros; it must be positive definite");
  }
  if ((m - m.transpose()).cwiseAbs().maxCoeff() > kSymmetryTolerance * scale) {
    throw TipEkfConfigError("tip EKF: " + what + " is not symmetric");
  }
  // LLT succeeds on symmetric positive definite matrices; the eigenvalue check also refuses ones that
  // are positive definite only to round-off (a zero variance plus noise), which the filter's
  // inverse of P⁻ + R would otherwise have to survive.
  const Eigen::LLT<Eigen::Matrix3d> llt(m);
  const Eigen::Vector3d eigenvalues = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(m).eigenvalues();
  if (llt.info() != Eigen::Success || eigenvalues.minCoeff() <= 1e-12 * scale) {
    throw TipEkfConfigError("tip EKF: " + what +
                            " is not positive definite (every variance must be > 0 and the correlations "
                            "below 1); smallest eigenvalue " +
                            std::to_string(eigenvalues.minCoeff()));
  }
}

bool state_is_finite(const TipEkfState& state) noexcept {
  return state.pose.allFinite() && state.covariance.allFinite();
}

}  // namespace

const char* to_string(TipEkfStatus status) noexcept {
  switch (status) {
    case TipEkfStatus::ok:
      return "ok";
    case TipEkfStatus::invalid_step:
      return "invalid step: the insertion increment ds or the curvature kappa is not a finite number";
    case TipEkfStatus::invalid_measurement:
      return "invalid measurement: the segmented tip pose holds a NaN or infinite value";
    case TipEkfStatus::invalid_state:
      return "invalid state: the tip estimate passed in holds a NaN or infinite value";
    case TipEkfStatus::numerical_failure:
      return "numerical failure: the innovation covariance is not positive definite";
  }
  return "unknown tip EKF status";
}

TipEkfNoise TipEkfNoise::fine_scale() {
  TipEkfNoise noise;
  noise.process = Eigen::Vector3d(0.01 * 0.01, 0.01 * 0.01, 0.0175 * 0.0175).asDiagonal();
  noise.measurement = Eigen::Vector3d(0.25 * 0.25, 0.25 * 0.25, 0.0873 * 0.0873).asDiagonal();
  return noise;
}

TipEkfNoise TipEkfNoise::vessel_scale() {
  TipEkfNoise noise = fine_scale();
  noise.measurement = Eigen::Vector3d(2.0 * 2.0, 2.0 * 2.0, 0.175 * 0.175).asDiagonal();
  return noise;
}

double wrap_angle(double angle) noexcept {
  // std::remainder gives [−π, π]; −π is moved to π so the range is half-open and unique.
  const double wrapped = std::remainder(angle, 2.0 * std::numbers::pi);
  return wrapped <= -std::numbers::pi ? wrapped + 2.0 * std::numbers::pi : wrapped;
}

TipEkf::TipEkf(const TipEkfNoise& noise) : noise_(noise) {
  validate_covariance(noise_.process, "Q (process noise)");
  validate_covariance(noise_.measurement, "R (measurement noise)");
}

TipEkfState TipEkf::start_at(const Eigen::Vector3d& pose) const { return start_at(pose, noise_.measurement); }

TipEkfState TipEkf::start_at(const Eigen::Vector3d& pose, const Eigen::Matrix3d& covariance) const {
  if (!pose.allFinite()) {
    throw TipEkfConfigError("tip EKF: the initial tip pose holds a NaN or infinite value");
  }
  validate_covariance(covariance, "the initial covariance P0");
  TipEkfState state;
  state.pose = pose;
  state.pose.z() = wrap_angle(pose.z());
  state.covariance = covariance;
  return state;
}

Eigen::Vector3d TipEkf::process_model(const Eigen::Vector3d& pose, double ds, double kappa) noexcept {
  const double theta = pose.z();
  return pose + Eigen::Vector3d(std::cos(theta) * ds, std::sin(theta) * ds, kappa * ds);
}

Eigen::Matrix3d TipEkf::process_jacobian(const Eigen::Vector3d& pose, double ds) noexcept {
  const double theta = pose.z();
  Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
  a(0, 2) = -std::sin(theta) * ds;
  a(1, 2) = std::cos(theta) * ds;
  return a;
}

TipEkfStatus TipEkf::predict(TipEkfState& state, double ds, double kappa) const noexcept {
  if (!std::isfinite(ds) || !std::isfinite(kappa)) return TipEkfStatus::invalid_step;
  if (!state_is_finite(state)) return TipEkfStatus::invalid_state;
  // A_k at the previous estimate, before the pose moves.
  const Eigen::Matrix3d a = process_jacobian(state.pose, ds);
  Eigen::Vector3d pose = process_model(state.pose, ds, kappa);
  pose.z() = wrap_angle(pose.z());
  const Eigen::Matrix3d covariance = a * state.covariance * a.transpose() + noise_.process;
  // A huge but finite ds or κ can still overflow; never hand back a non-finite state.
  if (!pose.allFinite() || !covariance.allFinite()) return TipEkfStatus::invalid_step;
  state.pose = pose;
  state.covariance = covariance;
  return TipEkfStatus::ok;
}

TipEkfStatus TipEkf::update(TipEkfState& state, const Eigen::Vector3d& measurement) const noexcept {
  if (!measurement.allFinite()) return TipEkfStatus::invalid_measurement;
  if (!state_is_finite(state)) return TipEkfStatus::invalid_state;
  const Eigen::Matrix3d& p = state.covariance;
  const Eigen::Matrix3d innovation_covariance = p + noise_.measurement;  // H P Hᵀ + R with H = I
  const Eigen::LLT<Eigen::Matrix3d> llt(innovation_covariance);
  if (llt.info() != Eigen::Success) return TipEkfStatus::numerical_failure;
  // K = P S⁻¹; with P and S symmetric, Kᵀ = S⁻¹ P.
  const Eigen::Matrix3d gain = llt.solve(p).transpose();

  Eigen::Vector3d innovation = measurement - state.pose;
  innovation.z() = wrap_angle(innovation.z());
  Eigen::Vector3d pose = state.pose + gain * innovation;
  pose.z() = wrap_angle(pose.z());

  const Eigen::Matrix3d i_minus_k = Eigen::Matrix3d::Identity() - gain;
  Eigen::Matrix3d covariance =
      i_minus_k * p * i_minus_k.transpose() + gain * noise_.measurement * gain.transpose();
  covariance = 0.5 * (covariance + covariance.transpose()).eval();
  if (!pose.allFinite() || !covariance.allFinite()) return TipEkfStatus::numerical_failure;
  state.pose = pose;
  state.covariance = covariance;
  return TipEkfStatus::ok;
}

TipEkfStatus TipEkf::step(TipEkfState& state, double ds, double kappa,
                          const Eigen::Vector3d& measurement) const noexcept {
  // Check the measurement before predicting, so a bad one does not leave a predicted-only state.
  if (!measurement.allFinite()) return TipEkfStatus::invalid_measurement;
  TipEkfState next = state;
  const TipEkfStatus predicted = predict(next, ds, kappa);
  if (predicted != TipEkfStatus::ok) return predicted;
  const TipEkfStatus corrected = update(next, measurement);
  if (corrected != TipEkfStatus::ok) return corrected;
  state = next;
  return TipEkfStatus::ok;
}

}  // namespace tendril::teleop::perception
