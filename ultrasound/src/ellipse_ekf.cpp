// Ellipse EKF + star algorithm (Heunis et al. 2021, Appendix B); see the header for the algorithm and
// choices.
#include "tendril/ultrasound/ellipse_ekf.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>

namespace tendril::ultrasound {
namespace {

constexpr double kPi = 3.14159265358979323846;

void require_positive(double value, const char* name) {
  if (!std::isfinite(value) || value <= 0.0) {
    throw UltrasoundSetupError(std::string("ellipse EKF: ") + name + " must be positive and finite, got " +
                               std::to_string(value));
  }
}

}  // namespace

double ellipse_radius(const Eigen::Vector3d& x, double theta) noexcept {
  const double c = std::cos(theta - x.z()), s = std::sin(theta - x.z());
  const double f = x.x(), h = x.y();
  return f * h / std::sqrt(h * h * c * c + f * f * s * s);
}

Eigen::Vector3d ellipse_radius_jacobian(const Eigen::Vector3d& x, double theta) noexcept {
  const double c = std::cos(theta - x.z()), s = std::sin(theta - x.z());
  const double f = x.x(), h = x.y();
  const double w = h * h * c * c + f * f * s * s;
  const double w32 = w * std::sqrt(w);
  return {h * h * h * c * c / w32, f * f * f * s * s / w32, f * h * s * c * (f * f - h * h) / w32};
}

EllipseSliceSegmenter::EllipseSliceSegmenter(const BModeGeometry& geometry,
                                             const EllipseEkfParameters& parameters)
    : geometry_(geometry), parameters_(parameters) {
  geometry_.validate();
  const auto& p = parameters_;
  if (p.rays < 3 || p.rays > 360) {
    throw UltrasoundSetupError("ellipse EKF: rays (N) must lie in 3..360, got " + std::to_string(p.rays));
  }
  if (p.candidates < 2 || p.candidates > 1000) {
    throw UltrasoundSetupError("ellipse EKF: candidates (M) must lie in 2..1000, got " +
                               std::to_string(p.candidates));
  }
  require_positive(p.max_radius, "max_radius");
  require_positive(p.nominal_radius, "nominal_radius");
  for (int i = 0; i < 3; ++i) {
    require_positive(p.initial_variance[i], "initial_variance");
    require_positive(p.process_noise[i], "process_noise");
  }
  require_positive(p.measurement_noise, "measurement_noise");
  require_positive(p.blur_sigma, "blur_sigma");
  require_positive(p.edge_step, "edge_step");
  require_positive(p.edge_threshold, "edge_threshold");
  require_positive(p.tolerance, "tolerance");
  if (p.max_iterations < 1 || p.max_iterations > 1000) {
    throw UltrasoundSetupError("ellipse EKF: max_iterations must lie in 1..1000, got " +
                               std::to_string(p.max_iterations));
  }
  if (p.nominal_radius >= p.max_radius) {
    throw UltrasoundSetupError("ellipse EKF: nominal_radius must be below max_radius");
  }
  const int half = std::max(1, static_cast<int>(std::ceil(3.0 * p.blur_sigma)));
  if (half > 64) throw UltrasoundSetupError("ellipse EKF: blur_sigma above 21 pixels");
  kernel_.resize(2 * static_cast<std::size_t>(half) + 1);
  double sum = 0.0;
  for (int i = -half; i <= half; ++i) {
    const double w = std::exp(-0.5 * i * i / (p.blur_sigma * p.blur_sigma));
    kernel_[static_cast<std::size_t>(i) + static_cast<std::size_t>(half)] = static_cast<float>(w);
    sum += w;
  }
  for (float& w : kernel_) w = static_cast<float>(w / sum);
  scratch_.resize(geometry_.pixel_count());
  blurred_.resize(geometry_.pixel_count());
  result_.contour.resize(static_cast<std::size_t>(p.rays));
  result_.measured_radius.resize(static_cast<std::size_t>(p.rays));
}

void EllipseSliceSegmenter::blur(const BModeImage& image) noexcept {
  const int w = geometry_.columns, h = geometry_.rows;
  const int half = static_cast<int>(kernel_.size() / 2);
  // Separable: rows into scratch_, then columns into blurred_, clamping at the borders.
  for (int r = 0; r < h; ++r) {
    const float* in = &image.pixels[static_cast<std::size_t>(r) * static_cast<std::size_t>(w)];
    float* out = &scratch_[static_cast<std::size_t>(r) * static_cast<std::size_t>(w)];
    for (int c = 0; c < w; ++c) {
      float acc = 0.0f;
      for (std::size_t j = 0; j < kernel_.size(); ++j) {
        acc += kernel_[j] * in[std::clamp(c + static_cast<int>(j) - half, 0, w - 1)];
      }
      out[c] = acc;
    }
  }
  for (int r = 0; r < h; ++r) {
    float* out = &blurred_[static_cast<std::size_t>(r) * static_cast<std::size_t>(w)];
    for (int c = 0; c < w; ++c) {
      float acc = 0.0f;
      for (std::size_t j = 0; j < kernel_.size(); ++j) {
        const int row = std::clamp(r + static_cast<int>(j) - half, 0, h - 1);
        acc += kernel_[j] * scratch_[static_cast<std::size_t>(row) * static_cast<std::size_t>(w) +
                                     static_cast<std::size_t>(c)];
      }
      out[c] = acc;
    }
  }
}

// Bilinear sample of the blurred image at (y, z) mm; 0 outside (no echo beyond the field of view).
double EllipseSliceSegmenter::sample(double y, double z) const noexcept {
  const Eigen::Vector2d px = geometry_.pixel_of({y, z});
  if (!(px.x() >= 0.0 && px.y() >= 0.0 && px.x() <= geometry_.columns - 1 && px.y() <= geometry_.rows - 1)) {
    return 0.0;
  }
  const int c0 = std::min(static_cast<int>(px.x()), geometry_.columns - 2);
  const int r0 = std::min(static_cast<int>(px.y()), geometry_.rows - 2);
  const double fc = px.x() - c0, fr = px.y() - r0;
  const std::size_t w = static_cast<std::size_t>(geometry_.columns);
  const std::size_t i = static_cast<std::size_t>(r0) * w + static_cast<std::size_t>(c0);
  return (1 - fr) * ((1 - fc) * blurred_[i] + fc * blurred_[i + 1]) +
         fr * ((1 - fc) * blurred_[i + w] + fc * blurred_[i + w + 1]);
}

void EllipseSliceSegmenter::run_contour(const Eigen::Vector2d& centre, Eigen::Vector3d& x) noexcept {
  const auto& p = parameters_;
  Eigen::Matrix3d P = p.initial_variance.asDiagonal();
  const Eigen::Matrix3d Q = p.process_noise.asDiagonal();
  const double spacing = p.max_radius / p.candidates;
  for (int q = 0; q < p.rays; ++q) {
    const double theta = 2.0 * kPi * q / p.rays;
    const double cy = std::cos(theta), cz = std::sin(theta);
    P += Q;                                             // random-walk prediction
    const double predicted = ellipse_radius(x, theta);  // A15
    const Eigen::Vector3d J = ellipse_radius_jacobian(x, theta);
    const double S = J.dot(P * J) + p.measurement_noise;  // innovation covariance
    double weight_sum = 0.0, weighted_radius = 0.0;
    for (int j = 1; j <= p.candidates; ++j) {
      const double r = j * spacing;
      const double rise = sample(centre.x() + (r + p.edge_step) * cy, centre.y() + (r + p.edge_step) * cz) -
                          sample(centre.x() + (r - p.edge_step) * cy, centre.y() + (r - p.edge_step) * cz);
      const double edge = std::clamp(rise, 0.0, p.edge_threshold) / p.edge_threshold;  // F_e
      const double d = r - predicted;
      const double likelihood = edge * edge * std::exp(-d * d / (2.0 * S));  // A21 (exponent squared)
      weight_sum += likelihood;
      weighted_radius += likelihood * r;  // A19–A20
    }
    double measured = predicted;
    if (weight_sum > 1e-12) {
      measured = weighted_radius / weight_sum;
      const Eigen::Vector3d G = P * J / S;  // A17
      x += G * (measured - predicted);      // A16
      P -= G * S * G.transpose();           // A18
      // Keep the ellipse meaningful: semi-axes inside (0, r_max], tilt wrapped to (−π, π].
      x.x() = std::clamp(x.x(), 0.05 * p.nominal_radius, p.max_radius);
      x.y() = std::clamp(x.y(), 0.05 * p.nominal_radius, p.max_radius);
      x.z() = std::remainder(x.z(), 2.0 * kPi);
    }
    const double radius = ellipse_radius(x, theta);  // posterior D(x̂_q|q)
    result_.measured_radius[static_cast<std::size_t>(q)] = measured;
    result_.contour[static_cast<std::size_t>(q)] = centre + radius * Eigen::Vector2d(cy, cz);
  }
}

const SliceSegmentation& EllipseSliceSegmenter::segment(const BModeImage& image,
                                                        const Eigen::Vector2d& seed) noexcept {
  result_.valid = false;
  result_.converged = false;
  result_.iterations = 0;
  result_.final_shift = 0.0;
  const Eigen::Vector2d seed_px = geometry_.pixel_of(seed);
  if (image.geometry.columns != geometry_.columns || image.geometry.rows != geometry_.rows ||
      image.pixels.size() != geometry_.pixel_count() || !seed.allFinite() || seed_px.x() < 0.0 ||
      seed_px.y() < 0.0 || seed_px.x() > geometry_.columns - 1 || seed_px.y() > geometry_.rows - 1) {
    return result_;
  }
  blur(image);
  Eigen::Vector3d state(parameters_.nominal_radius, parameters_.nominal_radius, 0.0);
  Eigen::Vector2d centre = seed;
  for (int iteration = 1; iteration <= parameters_.max_iterations; ++iteration) {
    run_contour(centre, state);
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& point : result_.contour) mean += point;
    mean /= static_cast<double>(result_.contour.size());
    result_.final_shift = (mean - centre).norm();
    result_.iterations = iteration;
    centre = mean;
    if (result_.final_shift < parameters_.tolerance) {
      result_.converged = true;
      break;
    }
  }
  // The contour belongs to the last centre it was traced from; report that centre's star mean.
  result_.centre = centre;
  result_.ellipse = state;
  result_.valid = true;
  return result_;
}

void EllipseSliceSegmenter::lumen_mask(const SliceSegmentation& result, LumenMask& mask) const {
  mask.assign(geometry_.pixel_count(), 0);
  if (!result.valid || result.contour.size() < 3) return;
  // Even–odd rule per pixel centre inside the polygon's bounding box.
  double y_min = result.contour[0].x(), y_max = y_min, z_min = result.contour[0].y(), z_max = z_min;
  for (const auto& v : result.contour) {
    y_min = std::min(y_min, v.x());
    y_max = std::max(y_max, v.x());
    z_min = std::min(z_min, v.y());
    z_max = std::max(z_max, v.y());
  }
  const Eigen::Vector2d lo = geometry_.pixel_of({y_min, z_min}), hi = geometry_.pixel_of({y_max, z_max});
  const int c0 = std::max(0, static_cast<int>(std::floor(lo.x()))),
            c1 = std::min(geometry_.columns - 1, static_cast<int>(std::ceil(hi.x())));
  const int r0 = std::max(0, static_cast<int>(std::floor(lo.y()))),
            r1 = std::min(geometry_.rows - 1, static_cast<int>(std::ceil(hi.y())));
  const std::size_t n = result.contour.size();
  for (int r = r0; r <= r1; ++r) {
    for (int c = c0; c <= c1; ++c) {
      const Eigen::Vector2d pt = geometry_.plane_point(c, r);
      bool inside = false;
      for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
        const Eigen::Vector2d& a = result.contour[i];
        const Eigen::Vector2d& b = result.contour[j];
        if ((a.y() > pt.y()) != (b.y() > pt.y()) &&
            pt.x() < (b.x() - a.x()) * (pt.y() - a.y()) / (b.y() - a.y()) + a.x()) {
          inside = !inside;
        }
      }
      if (inside)
        mask[static_cast<std::size_t>(r) * static_cast<std::size_t>(geometry_.columns) +
             static_cast<std::size_t>(c)] = 1;
    }
  }
}

}  // namespace tendril::ultrasound
