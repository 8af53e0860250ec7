#include "tendril/teleop/perception/planar_curvature.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include "tendril/teleop/perception/tip_ekf.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop::perception {

namespace {

using teleop::VesselInputError;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

void check_spacing(double spacing) {
  if (!std::isfinite(spacing) || spacing <= 0.0) {
    throw VesselInputError("curvature profile: sample spacing must be a positive number of mm, got " +
                           std::to_string(spacing));
  }
}

// Index i of the sample interval [i·h, (i+1)·h] holding s (0 ≤ s ≤ length), and the fraction within it.
struct Bracket {
  std::size_t index;
  double fraction;
};

Bracket bracket(double s, double spacing, std::size_t samples) noexcept {
  const double position = s / spacing;
  const auto last_interval = static_cast<double>(samples - 2);
  const double index = std::min(std::floor(position), last_interval);
  return {static_cast<std::size_t>(index), position - index};
}

}  // namespace

PlanarCurvatureProfile PlanarCurvatureProfile::from_polyline(std::span<const Eigen::Vector2d> points,
                                                             double spacing) {
  check_spacing(spacing);
  std::vector<Eigen::Vector2d> planar;
  planar.reserve(points.size());
  for (const Eigen::Vector2d& p : points) {
    if (!p.allFinite())
      throw VesselInputError("curvature profile: a point holds a NaN or infinite coordinate");
    if (planar.empty() || p != planar.back()) planar.push_back(p);
  }
  std::vector<double> arc(planar.size(), 0.0);
  for (std::size_t i = 1; i < planar.size(); ++i) arc[i] = arc[i - 1] + (planar[i] - planar[i - 1]).norm();
  return build(planar, arc, spacing);
}

PlanarCurvatureProfile PlanarCurvatureProfile::from_projection(std::span<const Eigen::Vector3d> points,
                                                               const Eigen::Vector3d& x_axis,
                                                               const Eigen::Vector3d& y_axis,
                                                               double spacing) {
  check_spacing(spacing);
  if (!x_axis.allFinite() || !y_axis.allFinite() || std::abs(x_axis.norm() - 1.0) > 1e-6 ||
      std::abs(y_axis.norm() - 1.0) > 1e-6 || std::abs(x_axis.dot(y_axis)) > 1e-6) {
    throw VesselInputError("curvature profile: the projection plane's axes must be orthonormal unit vectors");
  }
  // Drop repeated 3D points only: a stretch seen end-on keeps its vessel length but has none in the plane,
  // which is what the vessel-to-plane arc-length map has to record.
  std::vector<Eigen::Vector2d> planar;
  std::vector<double> vessel_arc;
  planar.reserve(points.size());
  vessel_arc.reserve(points.size());
  const Eigen::Vector3d* previous = nullptr;
  for (const Eigen::Vector3d& p : points) {
    if (!p.allFinite())
      throw VesselInputError("curvature profile: a point holds a NaN or infinite coordinate");
    if (previous != nullptr && p == *previous) continue;
    vessel_arc.push_back(previous == nullptr ? 0.0 : vessel_arc.back() + (p - *previous).norm());
    planar.emplace_back(p.dot(x_axis), p.dot(y_axis));
    previous = &p;
  }
  return build(planar, vessel_arc, spacing);
}

PlanarCurvatureProfile PlanarCurvatureProfile::build(std::span<const Eigen::Vector2d> planar,
                                                     std::span<const double> vessel_arc, double spacing) {
  PlanarCurvatureProfile profile;
  profile.vessel_arc_.assign(vessel_arc.begin(), vessel_arc.end());
  profile.plane_arc_.assign(planar.size(), 0.0);
  std::size_t distinct = planar.empty() ? 0 : 1;
  for (std::size_t i = 1; i < planar.size(); ++i) {
    const double step = (planar[i] - planar[i - 1]).norm();
    profile.plane_arc_[i] = profile.plane_arc_[i - 1] + step;
    if (step > 0.0) ++distinct;
  }
  if (distinct < 3) {
    throw VesselInputError("curvature profile: needs at least 3 distinct points in the plane, got " +
                           std::to_string(distinct) + " (a vessel seen end-on has no in-plane length)");
  }
  const double length = profile.plane_arc_.back();
  if (length > VesselCenterline::kMaximumPlausibleLengthMm) {
    throw VesselInputError("curvature profile: the curve is " + std::to_string(length) +
                           " mm long in the plane; over 10 m is not a vessel (wrong units?)");
  }
  // The spacing is shrunk to L / ceil(L/h) so that the samples reach the curve's end exactly.
  const double intervals = std::ceil(length / spacing - 1e-9);
  if (intervals + 1.0 > static_cast<double>(VesselCenterline::kMaximumSamples)) {
    throw VesselInputError("curvature profile: sample spacing " + std::to_string(spacing) +
                           " mm gives too many samples for a curve of " + std::to_string(length) + " mm");
  }
  if (length < 2.0 * spacing) {
    throw VesselInputError("curvature profile: the curve is " + std::to_string(length) +
                           " mm long in the plane, shorter than two sample spacings of " +
                           std::to_string(spacing) + " mm");
  }
  profile.spacing_ = length / intervals;

  // Resample along the planar polyline (segments of zero length are passed over).
  const auto count = static_cast<std::size_t>(intervals) + 1;
  profile.points_.reserve(count);
  std::size_t segment = 1;
  for (std::size_t i = 0; i < count; ++i) {
    const double s = std::min(static_cast<double>(i) * profile.spacing_, length);
    while (segment + 1 < planar.size() && profile.plane_arc_[segment] < s) ++segment;
    const double s0 = profile.plane_arc_[segment - 1];
    const double s1 = profile.plane_arc_[segment];
    const double t = s1 > s0 ? std::clamp((s - s0) / (s1 - s0), 0.0, 1.0) : 1.0;
    profile.points_.push_back(planar[segment - 1] + t * (planar[segment] - planar[segment - 1]));
  }

  // Headings from central chords, unwrapped to a continuous θ(s); at the ends the second-order
  // one-sided difference (−3·f₀ + 4·f₁ − f₂) / 2h, so the end values are not half a sample late.
  const std::vector<Eigen::Vector2d>& p = profile.points_;
  const std::size_t n = count - 1;
  profile.headings_.resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    Eigen::Vector2d tangent;
    if (i == 0) {
      tangent = -3.0 * p[0] + 4.0 * p[1] - p[2];
    } else if (i == n) {
      tangent = 3.0 * p[n] - 4.0 * p[n - 1] + p[n - 2];
    } else {
      tangent = p[i + 1] - p[i - 1];
    }
    const double raw = std::atan2(tangent.y(), tangent.x());
    profile.headings_[i] =
        i == 0 ? raw : profile.headings_[i - 1] + wrap_angle(raw - profile.headings_[i - 1]);
  }
  // κ = dθ/ds by central differences, the same one-sided form at the ends.
  const std::vector<double>& theta = profile.headings_;
  profile.curvatures_.resize(count);
  const double two_h = 2.0 * profile.spacing_;
  for (std::size_t i = 0; i < count; ++i) {
    if (i == 0) {
      profile.curvatures_[i] = (-3.0 * theta[0] + 4.0 * theta[1] - theta[2]) / two_h;
    } else if (i == n) {
      profile.curvatures_[i] = (3.0 * theta[n] - 4.0 * theta[n - 1] + theta[n - 2]) / two_h;
    } else {
      profile.curvatures_[i] = (theta[i + 1] - theta[i - 1]) / two_h;
    }
  }
  return profile;
}

Eigen::Vector2d PlanarCurvatureProfile::point_at(double s) const noexcept {
  if (std::isnan(s)) return {kNaN, kNaN};
  if (s <= 0.0) {
    const double theta = headings_.front();
    return points_.front() + s * Eigen::Vector2d(std::cos(theta), std::sin(theta));
  }
  if (s >= length()) {
    const double theta = headings_.back();
    return points_.back() + (s - length()) * Eigen::Vector2d(std::cos(theta), std::sin(theta));
  }
  const Bracket b = bracket(s, spacing_, points_.size());
  return points_[b.index] + b.fraction * (points_[b.index + 1] - points_[b.index]);
}

double PlanarCurvatureProfile::heading_at(double s) const noexcept {
  if (std::isnan(s)) return kNaN;
  if (s <= 0.0) return headings_.front();
  if (s >= length()) return headings_.back();
  const Bracket b = bracket(s, spacing_, headings_.size());
  return headings_[b.index] + b.fraction * (headings_[b.index + 1] - headings_[b.index]);
}

double PlanarCurvatureProfile::curvature_at(double s) const noexcept {
  if (std::isnan(s)) return kNaN;
  if (s < 0.0 || s > length()) return 0.0;
  const Bracket b = bracket(s, spacing_, curvatures_.size());
  return curvatures_[b.index] + b.fraction * (curvatures_[b.index + 1] - curvatures_[b.index]);
}

double PlanarCurvatureProfile::mean_curvature(double s0, double s1) const noexcept {
  if (s0 == s1) return curvature_at(s0);
  return (heading_at(s1) - heading_at(s0)) / (s1 - s0);
}

double PlanarCurvatureProfile::in_plane_arc_length(double vessel_arc_length) const noexcept {
  if (std::isnan(vessel_arc_length)) return kNaN;
  if (vessel_arc_length <= 0.0) return 0.0;
  if (vessel_arc_length >= vessel_arc_.back()) return plane_arc_.back();
  // First vertex at or beyond the given length; the one before it starts the segment.
  const auto it = std::lower_bound(vessel_arc_.begin(), vessel_arc_.end(), vessel_arc_length);
  const auto i = static_cast<std::size_t>(it - vessel_arc_.begin());
  const double v0 = vessel_arc_[i - 1];
  const double v1 = vessel_arc_[i];
  const double t = (vessel_arc_length - v0) / (v1 - v0);
  return plane_arc_[i - 1] + t * (plane_arc_[i] - plane_arc_[i - 1]);
}

}  // namespace tendril::teleop::perception
