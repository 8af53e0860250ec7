// Catheter tip tracking in one image plane (Abah 2022, §4.9.3): an extended Kalman
// filter on the tip pose x = [x, y, θ] (mm, mm, rad; θ measured from the plane's x axis towards its
// y axis), stepped once per insertion increment ds with the vessel's curvature κ(s) as the prior on
// how the heading turns (κ from the empty-vessel centerline: see planar_curvature.hpp).
//
//   predict (4.41)  x⁻ = f(x, u) = x + [cos θ·ds, sin θ·ds, κ·ds]ᵀ,   u = [ds, κ]
//           (4.42)  A = ∂f/∂x = [[1, 0, −sin θ·ds], [0, 1, cos θ·ds], [0, 0, 1]],   P⁻ = A P Aᵀ + Q
//   correct         H = I:  K = P⁻ (P⁻ + R)⁻¹,  x = x⁻ + K·(z − x⁻),  P = (I − K) P⁻
//
// The heading innovation z_θ − x⁻_θ is wrapped to (−π, π], so a tip pointing along ±π is not pulled
// the long way round; the state's heading is kept in (−π, π] too. The covariance update uses the
// Joseph form (I − K) P⁻ (I − K)ᵀ + K R Kᵀ, equal to (I − K) P⁻ for this K but symmetric and positive
// definite in floating point over thousands of steps.
//
// Model/data split: TipEkf is immutable after construction (Q and R, validated there; a bad matrix
// throws TipEkfConfigError); TipEkfState is the caller's data. predict/update/step are noexcept,
// never allocate (fixed-size 3×3 Eigen), and on a non-finite input return an error status and leave
// the state exactly as it was.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <stdexcept>

namespace tendril::teleop::perception {

// Thrown at set-up for a noise matrix or initial covariance that cannot be used (non-finite, not
// symmetric, not positive definite), or a non-finite initial pose.
class TipEkfConfigError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

enum class TipEkfStatus : std::uint8_t {
  ok,
  invalid_step,         // ds or κ is NaN or infinite
  invalid_measurement,  // a component of the measured pose is NaN or infinite
  invalid_state,        // the state passed in holds a non-finite value (the filter never produces one)
  numerical_failure,    // P⁻ + R is not positive definite (only from a covariance the filter did not make)
};
const char* to_string(TipEkfStatus status) noexcept;

// Process noise Q and measurement noise R, both 3×3 in the state's units (mm², mm², rad²).
struct TipEkfNoise {
  Eigen::Matrix3d process = Eigen::Matrix3d::Identity();      // Q
  Eigen::Matrix3d measurement = Eigen::Matrix3d::Identity();  // R

  // (4.43), the dissertation's hand-drawn curve: Q = diag(0.01², 0.01², 0.0175²) (σ 0.01 mm, 1°),
  // R = diag(0.25², 0.25², 0.0873²) (σ 0.25 mm, 5°).
  static TipEkfNoise fine_scale();
  // (4.44), the dissertation's ICA fluoroscopy projection: Q as in (4.43), R = diag(2², 2², 0.175²)
  // (σ 2 mm, 10°).
  static TipEkfNoise vessel_scale();
};

// The filter's data: the estimate and its covariance. Plain values; copy freely.
struct TipEkfState {
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();  // [x mm, y mm, θ rad], θ in (−π, π]
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
};

// Wraps an angle to (−π, π]. NaN stays NaN.
double wrap_angle(double angle) noexcept;

class TipEkf {
 public:
  // Throws TipEkfConfigError naming the matrix (Q or R) and what is wrong with it when a matrix is not
  // finite, not symmetric (to 1e-9 relative) or not positive definite.
  explicit TipEkf(const TipEkfNoise& noise);

  const Eigen::Matrix3d& process_noise() const noexcept { return noise_.process; }
  const Eigen::Matrix3d& measurement_noise() const noexcept { return noise_.measurement; }

  // A state at `pose` (heading wrapped) with covariance R: the natural start when the pose is the
  // first segmented tip, whose uncertainty is the measurement's. Throws TipEkfConfigError if the pose is
  // not finite.
  TipEkfState start_at(const Eigen::Vector3d& pose) const;
  // A state at `pose` with the given covariance. Throws TipEkfConfigError if either is not finite or the
  // covariance is not symmetric positive definite.
  TipEkfState start_at(const Eigen::Vector3d& pose, const Eigen::Matrix3d& covariance) const;

  // Prediction (4.41) with (4.42) over one insertion increment ds (mm, in the image plane; negative
  // for a retraction) with the vessel's curvature κ (rad/mm) over that increment — pass
  // PlanarCurvatureProfile::mean_curvature(s, s + ds) so that the heading turns exactly as the prior
  // curve does over the step.
  TipEkfStatus predict(TipEkfState& state, double ds, double kappa) const noexcept;
  // Correction with a segmented tip pose z = [x, y, θ] (H = I).
  TipEkfStatus update(TipEkfState& state, const Eigen::Vector3d& measurement) const noexcept;
  // predict then update, all or nothing: on any error the state is left as it was (not half-stepped).
  TipEkfStatus step(TipEkfState& state, double ds, double kappa,
                    const Eigen::Vector3d& measurement) const noexcept;

  // f of (4.41), without the wrap of the heading (so that it is differentiable everywhere).
  static Eigen::Vector3d process_model(const Eigen::Vector3d& pose, double ds, double kappa) noexcept;
  // A_k of (4.42): ∂f/∂x at `pose` (independent of κ).
  static Eigen::Matrix3d process_jacobian(const Eigen::Vector3d& pose, double ds) noexcept;

 private:
  TipEkfNoise noise_;
};

}  // namespace tendril::teleop::perception
