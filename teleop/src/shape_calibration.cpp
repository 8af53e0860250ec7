#include "tendril/teleop/shape_calibration.hpp"

#include <Eigen/QR>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

void validate_orders(const ShapeFitOptions& options) {
  require(options.modal_order >= 1 && options.modal_order <= 6,
          "fit_shape_matrix: modal_order n must be in [1, 6], got " + std::to_string(options.modal_order));
  require(options.actuation_order >= 1 && options.actuation_order <= 6,
          "fit_shape_matrix: actuation_order m must be in [1, 6], got " +
              std::to_string(options.actuation_order));
}

// Linear interpolation of a polyline (points with cumulative parameter t, increasing) at uniform
// steps h from t = 0 to the end.
std::vector<Eigen::Vector2d> resample_uniform(const std::vector<Eigen::Vector2d>& points,
                                              const std::vector<double>& t, double h) {
  std::vector<Eigen::Vector2d> out;
  const double total = t.back();
  const auto count = static_cast<std::size_t>(std::floor(total / h)) + 1;
  out.reserve(count);
  std::size_t segment = 0;
  for (std::size_t i = 0; i < count; ++i) {
    const double ti = static_cast<double>(i) * h;
    while (segment + 2 < t.size() && t[segment + 1] < ti) ++segment;
    const double span = t[segment + 1] - t[segment];
    const double w = span > 0.0 ? std::clamp((ti - t[segment]) / span, 0.0, 1.0) : 0.0;
    out.push_back((1.0 - w) * points[segment] + w * points[segment + 1]);
  }
  return out;
}

std::vector<double> cumulative_length(const std::vector<Eigen::Vector2d>& points) {
  std::vector<double> t(points.size(), 0.0);
  for (std::size_t i = 1; i < points.size(); ++i) t[i] = t[i - 1] + (points[i] - points[i - 1]).norm();
  return t;
}

// Whittaker–Henderson smoother with third differences: (I + λ·DᵀD)·f = y, D the (M−3)×M third
// difference operator. Banded and symmetric positive definite, so a sparse LDLᵀ is exact and cheap.
Eigen::MatrixX2d whittaker_smooth(const std::vector<Eigen::Vector2d>& points, double lambda) {
  const auto M = static_cast<Eigen::Index>(points.size());
  Eigen::MatrixX2d y(M, 2);
  for (Eigen::Index i = 0; i < M; ++i) y.row(i) = points[static_cast<std::size_t>(i)].transpose();
  if (M < 4 || lambda <= 0.0) return y;
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(static_cast<std::size_t>(4 * (M - 3)));
  const double stencil[4] = {-1.0, 3.0, -3.0, 1.0};
  for (Eigen::Index r = 0; r + 3 < M; ++r) {
    for (int k = 0; k < 4; ++k) triplets.emplace_back(r, r + k, stencil[k]);
  }
  Eigen::SparseMatrix<double> D(M - 3, M);
  D.setFromTriplets(triplets.begin(), triplets.end());
  Eigen::SparseMatrix<double> I(M, M);
  I.setIdentity();
  Eigen::SparseMatrix<double> system = I + lambda * Eigen::SparseMatrix<double>(D.transpose() * D);
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(system);
  require(solver.info() == Eigen::Success, "extract_tangent_angles: smoother factorisation failed");
  return solver.solve(y);
}

struct TangentSamples {
  std::vector<double> smoothed_arc_length;  // arc length of each smoothed (input-indexed) point
  std::vector<double> s_mid;                // forward-difference midpoints on the uniform curve
  std::vector<double> theta;
};

// Smooth uniformly spaced points, resample by the smoothed arc length (the raw chord length is
// inflated by pixel noise, the smoothed one is not), then forward differences: θ between samples
// i and i+1 belongs to the midpoint s = (i + ½)·h.
TangentSamples smooth_and_differentiate(const std::vector<Eigen::Vector2d>& uniform, double h,
                                        double lambda) {
  const Eigen::MatrixX2d smoothed_matrix = whittaker_smooth(uniform, lambda);
  std::vector<Eigen::Vector2d> smoothed(static_cast<std::size_t>(smoothed_matrix.rows()));
  for (std::size_t i = 0; i < smoothed.size(); ++i) {
    smoothed[i] = smoothed_matrix.row(static_cast<Eigen::Index>(i)).transpose();
  }
  TangentSamples out;
  out.smoothed_arc_length = cumulative_length(smoothed);
  const auto curve = resample_uniform(smoothed, out.smoothed_arc_length, h);
  require(curve.size() >= 4, "extract_tangent_angles: smoothed outline is too short");
  out.s_mid.reserve(curve.size() - 1);
  out.theta.reserve(curve.size() - 1);
  for (std::size_t i = 0; i + 1 < curve.size(); ++i) {
    const Eigen::Vector2d d = curve[i + 1] - curve[i];
    double angle = std::atan2(d.y(), d.x());
    if (!out.theta.empty()) {  // unwrap so bends past ±π stay continuous
      while (angle - out.theta.back() > std::numbers::pi) angle -= 2.0 * std::numbers::pi;
      while (angle - out.theta.back() < -std::numbers::pi) angle += 2.0 * std::numbers::pi;
    }
    out.s_mid.push_back((static_cast<double>(i) + 0.5) * h);
    out.theta.push_back(angle);
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

ShapeFitResult fit_shape_matrix(std::span<const ShapeSample> samples, const ShapeFitOptions& options) {
  validate_orders(options);
  const int n = options.modal_order, m = options.actuation_order;
  const auto unknowns = static_cast<std::size_t>(n) * static_cast<std::size_t>(m);
  require(samples.size() >= unknowns, "fit_shape_matrix: " + std::to_string(samples.size()) +
                                          " samples cannot determine the " + std::to_string(unknowns) +
                                          " entries of a " + std::to_string(n) + "×" + std::to_string(m) +
                                          " shape matrix; take more images or points along s");
  double s_scale = 0.0, q_scale = 0.0;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    const auto& sample = samples[k];
    require(std::isfinite(sample.arc_length) && std::isfinite(sample.actuation) &&
                std::isfinite(sample.tangent_angle),
            "fit_shape_matrix: sample " + std::to_string(k) + " has a NaN or infinite value");
    s_scale = std::max(s_scale, std::abs(sample.arc_length));
    q_scale = std::max(q_scale, std::abs(sample.actuation));
  }
  // Regress on s/s_scale and q/q_scale so all regressors are O(1), then undo the scaling in A.
  if (s_scale == 0.0) s_scale = 1.0;
  if (q_scale == 0.0) q_scale = 1.0;

  const auto rows = static_cast<Eigen::Index>(samples.size());
  Eigen::MatrixXd design(rows, n * m);
  Eigen::VectorXd phi(rows);
  for (Eigen::Index r = 0; r < rows; ++r) {
    const auto& sample = samples[static_cast<std::size_t>(r)];
    const double s = sample.arc_length / s_scale, q = sample.actuation / q_scale;
    // Row of Γᵀ ⊗ Ω for this sample: entry (j·n + i) = q^j·s^i, matching column-major Vec(A).
    double q_power = 1.0;
    for (int j = 0; j < m; ++j) {
      double s_power = 1.0;
      for (int i = 0; i < n; ++i) {
        design(r, j * n + i) = q_power * s_power;
        s_power *= s;
      }
      q_power *= q;
    }
    phi(r) = sample.tangent_angle;
  }
  const Eigen::VectorXd column_norms = design.colwise().norm().transpose();
  for (Eigen::Index c = 0; c < design.cols(); ++c) {
    if (column_norms(c) > 0.0) design.col(c) /= column_norms(c);
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(design);
  qr.setThreshold(1e-10);
  require(qr.rank() == design.cols(),
          "fit_shape_matrix: the samples determine only " + std::to_string(qr.rank()) + " of the " +
              std::to_string(design.cols()) + " shape-matrix entries (rank deficient): need at least " +
              std::to_string(n) + " distinct arc lengths and " + std::to_string(m) +
              " distinct actuation values, or lower n/m");
  const Eigen::VectorXd scaled_solution = qr.solve(phi);

  ShapeFitResult result;
  result.shape_matrix.resize(n, m);
  for (int j = 0; j < m; ++j) {
    for (int i = 0; i < n; ++i) {
      const Eigen::Index c = j * n + i;
      const double normalised = column_norms(c) > 0.0 ? scaled_solution(c) / column_norms(c) : 0.0;
      result.shape_matrix(i, j) = normalised / (std::pow(s_scale, i) * std::pow(q_scale, j));
    }
  }
  for (Eigen::Index c = 0; c < design.cols(); ++c) design.col(c) *= column_norms(c);
  Eigen::VectorXd unnormalised(design.cols());
  for (Eigen::Index c = 0; c < design.cols(); ++c) {
    unnormalised(c) = column_norms(c) > 0.0 ? scaled_solution(c) / column_norms(c) : 0.0;
  }
  const Eigen::VectorXd residual = (design * unnormalised - phi).cwiseAbs() * kRadToDeg;
  result.sample_count = samples.size();
  result.mean_abs_error_deg = residual.mean();
  result.max_abs_error_deg = residual.maxCoeff();
  result.rms_error_deg = std::sqrt(residual.squaredNorm() / static_cast<double>(rows));
  return result;
}

ShapeFitResult fit_shape_matrix(const Eigen::VectorXd& arc_lengths, const Eigen::VectorXd& actuations,
                                const Eigen::MatrixXd& tangent_angles, const ShapeFitOptions& options) {
  require(tangent_angles.rows() == arc_lengths.size() && tangent_angles.cols() == actuations.size(),
          "fit_shape_matrix: Φ must be r×z = " + std::to_string(arc_lengths.size()) + "×" +
              std::to_string(actuations.size()) + " (arc lengths × actuations), got " +
              std::to_string(tangent_angles.rows()) + "×" + std::to_string(tangent_angles.cols()));
  std::vector<ShapeSample> samples;
  samples.reserve(static_cast<std::size_t>(tangent_angles.size()));
  for (Eigen::Index k = 0; k < actuations.size(); ++k) {
    for (Eigen::Index j = 0; j < arc_lengths.size(); ++j) {
      samples.push_back({arc_lengths(j), actuations(k), tangent_angles(j, k)});
    }
  }
  return fit_shape_matrix(std::span<const ShapeSample>(samples), options);
}

// ---------------------------------------------------------------------------------------------

TangentProfile extract_tangent_angles(std::span<const Eigen::Vector2d> outline,
                                      const TangentExtractionOptions& options) {
  require(std::isfinite(options.sample_spacing) && options.sample_spacing > 0.0,
          "extract_tangent_angles: sample_spacing must be > 0 mm");
  require(std::isfinite(options.smoothing_length) && options.smoothing_length >= 0.0,
          "extract_tangent_angles: smoothing_length must be >= 0 mm");
  require(std::isfinite(options.straight_tolerance) && options.straight_tolerance > 0.0,
          "extract_tangent_angles: straight_tolerance must be > 0 rad");
  require(std::isnan(options.base_arc_length) ||
              (std::isfinite(options.base_arc_length) && options.base_arc_length >= 0.0),
          "extract_tangent_angles: base_arc_length must be >= 0 mm (or NaN to detect it)");
  require(outline.size() >= 8,
          "extract_tangent_angles: need at least 8 outline points, got " + std::to_string(outline.size()));
  for (std::size_t i = 0; i < outline.size(); ++i) {
    require(outline[i].allFinite(),
            "extract_tangent_angles: outline point " + std::to_string(i) + " is not finite");
  }

  // 1. Order: start at the proximal end (smallest z, the catheter enters along +z), then greedy
  //    nearest neighbour. O(N²) is fine for the few thousand pixels of one segment.
  std::vector<Eigen::Vector2d> remaining(outline.begin(), outline.end());
  std::vector<Eigen::Vector2d> ordered;
  ordered.reserve(remaining.size());
  auto start = std::min_element(remaining.begin(), remaining.end(),
                                [](const auto& a, const auto& b) { return a.y() < b.y(); });
  std::iter_swap(start, remaining.end() - 1);
  ordered.push_back(remaining.back());
  remaining.pop_back();
  while (!remaining.empty()) {
    auto nearest = std::min_element(remaining.begin(), remaining.end(), [&](const auto& a, const auto& b) {
      return (a - ordered.back()).squaredNorm() < (b - ordered.back()).squaredNorm();
    });
    std::iter_swap(nearest, remaining.end() - 1);
    ordered.push_back(remaining.back());
    remaining.pop_back();
  }
  // Greedy ordering strands the odd noisy pixel and jumps back for it at the end; cut the chain
  // at the first step far longer than the typical one and drop those stragglers.
  std::vector<double> steps;
  steps.reserve(ordered.size() - 1);
  for (std::size_t i = 1; i < ordered.size(); ++i) steps.push_back((ordered[i] - ordered[i - 1]).norm());
  std::vector<double> sorted_steps = steps;
  std::nth_element(sorted_steps.begin(),
                   sorted_steps.begin() + static_cast<std::ptrdiff_t>(sorted_steps.size() / 2),
                   sorted_steps.end());
  const double typical_step = sorted_steps[sorted_steps.size() / 2];
  for (std::size_t i = 0; i < steps.size(); ++i) {
    if (typical_step > 0.0 && steps[i] > 10.0 * typical_step) {
      require(i + 1 >= (9 * ordered.size()) / 10, "extract_tangent_angles: the outline has a gap (step " +
                                                      std::to_string(steps[i]) + " mm vs typical " +
                                                      std::to_string(typical_step) +
                                                      " mm) before 90% of its points; pass one "
                                                      "connected segment outline");
      ordered.resize(i + 1);
      break;
    }
  }

  const double h = options.sample_spacing;
  const auto raw_t = cumulative_length(ordered);
  require(raw_t.back() > 8.0 * h, "extract_tangent_angles: outline is shorter than a few sample spacings");
  const auto uniform = resample_uniform(ordered, raw_t, h);
  const double lambda = std::pow(options.smoothing_length / h, 6.0);

  // 2. Pass 1 over the whole outline (straight part included) only to find where the bend starts.
  const TangentSamples whole = smooth_and_differentiate(uniform, h, lambda);
  const double half_pi = std::numbers::pi / 2.0;
  //    A noisy blip on the straight part is short; the bend is a sustained departure, so the first
  //    bent sample starts a run of at least `run` samples all beyond the tolerance.
  const double window = std::max(2.0 * options.smoothing_length, 4.0 * h);
  const auto run = static_cast<std::size_t>(std::ceil(window / h));
  std::size_t first_bent = 0, run_length = 0;
  for (std::size_t i = 0; i < whole.theta.size() && run_length < run; ++i) {
    if (std::abs(whole.theta[i] - half_pi) < options.straight_tolerance) {
      run_length = 0;
    } else if (run_length++ == 0) {
      first_bent = i;
    }
  }
  const bool base_given = !std::isnan(options.base_arc_length);
  require(base_given || (run_length >= run && first_bent + 2 < whole.theta.size()),
          "extract_tangent_angles: the outline is straight within straight_tolerance; no bent segment to "
          "measure");
  //    The smoother rounds the straight-to-bent corner over about smoothing_length, so fit a line
  //    to θ(s) just past that rounding and extrapolate it back to θ = π/2 (exact for a
  //    constant-curvature start, first order otherwise).
  double base = base_given ? options.base_arc_length : 0.0;
  if (!base_given && first_bent > 0) {
    const double from = whole.s_mid[first_bent] + options.smoothing_length;
    double sum_s = 0, sum_t = 0, sum_ss = 0, sum_st = 0;
    int count = 0;
    for (std::size_t i = first_bent; i < whole.theta.size() && whole.s_mid[i] <= from + window; ++i) {
      if (whole.s_mid[i] < from) continue;
      sum_s += whole.s_mid[i];
      sum_t += whole.theta[i];
      sum_ss += whole.s_mid[i] * whole.s_mid[i];
      sum_st += whole.s_mid[i] * whole.theta[i];
      ++count;
    }
    const double denominator = count * sum_ss - sum_s * sum_s;
    base = whole.s_mid[first_bent - 1];
    if (count >= 2 && std::abs(denominator) > 0.0) {
      const double slope = (count * sum_st - sum_s * sum_t) / denominator;
      const double intercept = (sum_t - slope * sum_s) / count;
      if (std::abs(slope) > 0.0) base = std::clamp((half_pi - intercept) / slope, 0.0, from);
    }
  }

  // 3. Pass 2 smooths only the bent part, so the corner is not rounded into θ(s). The raw samples
  //    start at the one nearest the base found on the pass-1 curve; the profile's s is shifted by
  //    the leftover offset so s = 0 stays at the base.
  TangentProfile profile;
  profile.base_arc_length = base;
  std::size_t bent_start = 0;
  double start_offset = 0.0;  // pass-1 arc length of the starting raw sample minus base
  if (base > 0.0) {
    const auto& smoothed_t = whole.smoothed_arc_length;
    bent_start = static_cast<std::size_t>(std::lower_bound(smoothed_t.begin(), smoothed_t.end(), base) -
                                          smoothed_t.begin());
    bent_start = std::min(bent_start, smoothed_t.size() - 1);
    if (bent_start > 0 && base - smoothed_t[bent_start - 1] < smoothed_t[bent_start] - base) --bent_start;
    start_offset = smoothed_t[bent_start] - base;
  }
  require(uniform.size() - bent_start >= 8, "extract_tangent_angles: the bent part is too short to measure");
  const std::vector<Eigen::Vector2d> bent(uniform.begin() + static_cast<std::ptrdiff_t>(bent_start),
                                          uniform.end());
  const TangentSamples tip_part = smooth_and_differentiate(bent, h, lambda);
  for (std::size_t i = 0; i < tip_part.theta.size(); ++i) {
    const double s = tip_part.s_mid[i] + start_offset;
    if (s <= 0.0) continue;
    profile.arc_length.push_back(s);
    profile.tangent_angle.push_back(tip_part.theta[i]);
  }
  return profile;
}

void append_shape_samples(const TangentProfile& profile, double actuation, std::vector<ShapeSample>& out) {
  require(profile.arc_length.size() == profile.tangent_angle.size(),
          "append_shape_samples: profile arc_length and tangent_angle differ in size");
  for (std::size_t i = 0; i < profile.arc_length.size(); ++i) {
    out.push_back({profile.arc_length[i], actuation, profile.tangent_angle[i]});
  }
}

// ---------------------------------------------------------------------------------------------

double ActuationLoss::nominal_angle(double assembled) const {
  require(std::isfinite(slope) && slope != 0.0,
          "ActuationLoss: slope must be non-zero to invert the loss line");
  return (assembled - offset) / slope;
}

ConfigurationRateMap::ConfigurationRateMap(const ConfigurationRateParameters& parameters)
    : parameters_(parameters) {
  const auto& p = parameters;
  require(std::isfinite(p.proximal_loss.slope) && p.proximal_loss.slope != 0.0 &&
              std::isfinite(p.distal_loss.slope) && p.distal_loss.slope != 0.0,
          "ConfigurationRateMap: loss slopes a1, a2 must be finite and non-zero");
  require(std::isfinite(p.proximal_outer_radius) && p.proximal_outer_radius >= 0.0,
          "ConfigurationRateMap: proximal_outer_radius r1 must be >= 0 mm");
  require(std::isfinite(p.plane_offset), "ConfigurationRateMap: plane_offset δ2 must be finite");
  coupling_ = p.coupling_enabled ? -p.proximal_outer_radius * std::cos(p.plane_offset) : 0.0;
}

bool ConfigurationRateMap::configuration_rates_to_joint_rates(const Vector4& configuration_rates,
                                                              double proximal_tip_rate,
                                                              double distal_tip_rate,
                                                              Vector4& joint_rates) const noexcept {
  const double proximal_gain = parameters_.proximal_loss.slope * proximal_tip_rate;  // a1·∂θ_L1/∂q3
  const double distal_gain = parameters_.distal_loss.slope * distal_tip_rate;        // a2·∂θ_L2/∂q4
  if (!configuration_rates.allFinite() || !std::isfinite(proximal_gain) || !std::isfinite(distal_gain) ||
      std::abs(proximal_gain) < 1e-12 || std::abs(distal_gain) < 1e-12) {
    joint_rates.setZero();
    return false;
  }
  // (A_loss·J_ψq)⁻¹ is diagonal; A_coupling adds only q̇4 += c·θ̇_L1.
  joint_rates[0] = configuration_rates[0];
  joint_rates[1] = configuration_rates[1];
  joint_rates[2] = configuration_rates[2] / proximal_gain;
  joint_rates[3] = configuration_rates[3] / distal_gain + coupling_ * configuration_rates[2];
  return true;
}

}  // namespace tendril::teleop
