// Image-free parts of the SRMC calibration (Abah 2022, §4.5.2–4.5.3, §4.7.2):
//  * fit_shape_matrix: least-squares characteristic shape matrix A of θ(s, q) = Ψ(s)ᵀ·A·η(q)
//    (eq. 4.10–4.12), from a full r×z grid or scattered (s, q, θ) samples;
//  * extract_tangent_angles: θ(s) from a segment outline given as 2D points in the bending plane
//    (the image path of §4.5.2 after thresholding);
//  * ActuationLoss / ConfigurationRateMap: loss lines (4.13–4.14), coupling (4.15) and the
//    configuration-space rate law (4.21) with the reconstructed (4.22).
// Set-up functions throw std::invalid_argument with a readable message; the rate map is noexcept.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <limits>
#include <span>
#include <vector>

namespace tendril::teleop {

// ---------------------------------------------------------------------------------------------
// Shape-matrix fit (4.10–4.12)

struct ShapeSample {
  double arc_length;     // s (mm) from the segment base
  double actuation;      // q (mm)
  double tangent_angle;  // θ (rad) from x̂ in the bending plane
};

struct ShapeFitOptions {
  int modal_order = 4;      // n: powers of s (1 ≤ n ≤ 6)
  int actuation_order = 2;  // m: powers of q (1 ≤ m ≤ 6)
};

struct ShapeFitResult {
  Eigen::MatrixXd shape_matrix;  // A, n×m, in the units of the inputs (s and q in mm)
  std::size_t sample_count = 0;
  double mean_abs_error_deg = 0.0;  // mean |θ_fit − θ| over the samples (degrees)
  double max_abs_error_deg = 0.0;
  double rms_error_deg = 0.0;
};

// Grid form: Φ(j, k) = θ(s_j, q_k), Φ is r×z. Solves Vec(A) = (Γᵀ ⊗ Ω)⁺·Vec(Φ) by column-pivoting
// QR on column-scaled regressors (s and q are normalised internally so s³ and q⁵ do not wreck the
// conditioning). Throws std::invalid_argument on size mismatch, non-finite data, fewer samples
// than n·m unknowns, or a rank-deficient design (e.g. fewer distinct s than n or q than m).
ShapeFitResult fit_shape_matrix(const Eigen::VectorXd& arc_lengths, const Eigen::VectorXd& actuations,
                                const Eigen::MatrixXd& tangent_angles, const ShapeFitOptions& options = {});

// Scattered form: each sample contributes the row (η(q)ᵀ ⊗ Ψ(s)ᵀ) of the same system.
ShapeFitResult fit_shape_matrix(std::span<const ShapeSample> samples, const ShapeFitOptions& options = {});

// ---------------------------------------------------------------------------------------------
// Tangent-angle extraction from an outline (§4.5.2 image path, minus image I/O)

struct TangentExtractionOptions {
  // Resampling step along the arc (mm). Forward differences use this step.
  double sample_spacing = 0.05;
  // Smoother length scale (mm). The smoother is a discrete Whittaker–Henderson penalised least
  // squares, min Σ(f − y)² + λ·Σ(Δ³f)², applied to x(s) and z(s) separately with
  // λ = (smoothing_length / sample_spacing)⁶. Third differences (rather than the second differences
  // that mimic a cubic smoothing spline) leave quadratics untouched, so a bend is not flattened;
  // the noise cut-off is roughly smoothing_length. Two passes: the first (whole outline) locates
  // the bend start, the second smooths only the bent part so the straight-to-bent corner is not
  // rounded into θ(s). With ~0.6 px noise at 0.02 mm/px, 0.5 mm gave the best θ(s) in our tests;
  // the remaining error is dominated by where s = 0 is placed (Δθ ≈ κ·Δs).
  double smoothing_length = 0.5;
  // The straight proximal part is cut: the bend starts where θ leaves π/2 by more than this (rad)
  // for a sustained run; s = 0 is placed by extrapolating θ(s) just past the start back to π/2.
  double straight_tolerance = 0.02;
  // When the rig fixes where the segment starts (e.g. a known visible length of straight tube),
  // pass that arc length from the proximal end of the outline (mm) to skip the detection above;
  // detection is weak for small bends, whose start barely shows. NaN = detect.
  double base_arc_length = std::numeric_limits<double>::quiet_NaN();
};

struct TangentProfile {
  double base_arc_length = 0.0;       // arc length along the smoothed outline where the bend starts
  std::vector<double> arc_length;     // s from the bend start (mm), at forward-difference midpoints
  std::vector<double> tangent_angle;  // θ(s) (rad) from x̂, π/2 when straight along +z
};

// outline: points (x, z) in mm in the bending plane, in any order; the catheter enters along +z,
// so ordering starts at the point with the smallest z and proceeds by nearest neighbour; stragglers
// after a jump of more than 10× the median step are dropped. Throws std::invalid_argument for fewer
// than 8 points, non-finite points, bad options, a gap before 90% of the points, or when no bent
// part remains after truncation.
TangentProfile extract_tangent_angles(std::span<const Eigen::Vector2d> outline,
                                      const TangentExtractionOptions& options = {});

// Converts a profile into fit samples at actuation q (for the scattered fit_shape_matrix).
void append_shape_samples(const TangentProfile& profile, double actuation, std::vector<ShapeSample>& out);

// ---------------------------------------------------------------------------------------------
// Actuation loss (4.13–4.14), coupling (4.15) and the configuration rate law (4.21–4.23)

// θ_L = slope·θ*_L + offset, θ*_L the tip-only calibrated model's tip angle (rad, as the dissertation's
// GAP note assumes).
struct ActuationLoss {
  double slope = 1.0;
  double offset = 0.0;
  double assembled_angle(double nominal_angle) const noexcept { return slope * nominal_angle + offset; }
  // Inverse loss map θ* = (θ − b)/a, for absolute commands. Throws std::invalid_argument if slope = 0.
  double nominal_angle(double assembled_angle) const;
};

struct ConfigurationRateParameters {
  ActuationLoss proximal_loss{0.063, -0.049};  // (4.13)
  ActuationLoss distal_loss{0.17, 0.019};      // (4.14)
  double proximal_outer_radius = 0.6;          // r1 (mm), 1.2 mm outer tube
  double plane_offset = -0.44;                 // δ2 (rad)
  bool coupling_enabled = true;
};

// q̇_des = (A_coupling + (A_loss·J_ψq)⁻¹)·ψ̇_des, ψ = [q1, q2, θ_L1, θ_L2], q = [q1, q2, q3, q4]:
//   A_loss = diag(1, 1, a1, a2), J_ψq = diag(1, 1, ∂θ_L1/∂q3, ∂θ_L2/∂q4),
//   A_coupling = 0 except (4,3) = −r1·cos δ2 (1-based), i.e. q̇4 += −r1·cos δ2·θ̇_L1.
// Sign choice: we take (4.15) as the feed-forward the controller must add. Bending the proximal
// segment is modelled as shifting the distal actuation line's effective displacement by
// +r1·cos δ2·Δθ_L1 (the line runs at radius r1 at angle δ2 from the proximal bending plane); the
// −r1·cos δ2 term cancels that shift so the distal bend does not move. The physical sign (which
// side of the neutral axis the distal line runs on) still has to be checked on hardware; flip
// plane_offset by π if it turns out reversed.
class ConfigurationRateMap {
 public:
  using Vector4 = Eigen::Matrix<double, 4, 1>;
  // Throws std::invalid_argument for a zero or non-finite slope, negative radius or non-finite δ2.
  explicit ConfigurationRateMap(const ConfigurationRateParameters& parameters);

  const ConfigurationRateParameters& parameters() const noexcept { return parameters_; }
  double coupling() const noexcept { return coupling_; }  // A_coupling(4,3) = −r1·cos δ2

  // proximal_tip_rate = ∂θ_L1/∂q3 and distal_tip_rate = ∂θ_L2/∂q4 (rad/mm) of the calibrated model.
  // Returns false and writes zero rates (hold still) when a_i·∂θ_Li/∂q is not invertible
  // (|·| < 1e-12) or any input is not finite.
  bool configuration_rates_to_joint_rates(const Vector4& configuration_rates, double proximal_tip_rate,
                                          double distal_tip_rate, Vector4& joint_rates) const noexcept;

 private:
  ConfigurationRateParameters parameters_;
  double coupling_;
};

}  // namespace tendril::teleop
