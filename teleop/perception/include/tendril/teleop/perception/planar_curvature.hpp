// κ(s) for the tip EKF (Abah 2022, §4.9.3–4.9.4): the curvature of the empty vessel's centerline as seen
// in one image plane, as a function of the in-plane arc length s, known a priori (4.40).
//
// How it is computed (the dissertation gives only "κ_curve = dθ/ds" of a spline through the thinned vessel):
// the planar polyline is resampled every `spacing` mm (or a little less) of in-plane arc length (linear along
// the polyline, which is expected to be dense and smooth, e.g. a spline exported densely or
// teleop::VesselCenterline's points); the heading θ_i is the direction of the central chord
// p_{i+1} − p_{i−1} (second-order one-sided at the ends), unwrapped so that it is continuous, and κ_i
// is the central difference of θ. A 3D centerline is first projected orthogonally onto the plane spanned
// by two axes (parallel projection: the fluoroscope's cone beam magnifies by SID/depth, which the
// caller folds into its mm-per-pixel scale).
//
// Arc length in the plane is not arc length along the vessel: a vessel inclined to the plane is
// foreshortened. The EKF's ds is the in-plane increment; in_plane_arc_length() maps vessel (insertion)
// arc length to it for a profile built by projection, so the catheter's 3 mm insertion steps become
// ds = s_plane(q₁ + 3) − s_plane(q₁).
//
// The plane's coordinates must be the ones the segmented tip is measured in (θ from the first axis
// towards the second): a mirrored frame flips the sign of κ, and using the same coordinates for
// both keeps it right.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <span>
#include <vector>

namespace tendril::teleop::perception {

class PlanarCurvatureProfile {
 public:
  // mm between samples of θ and κ; the spacing used is at most this, L / ceil(L / spacing), so that the
  // last sample is the curve's end.
  static constexpr double kDefaultSpacing = 0.25;

  // From a planar polyline (mm) ordered from the insertion end. Consecutive duplicate points are
  // dropped. Throws teleop::VesselInputError if a value is not finite, spacing is not positive, fewer
  // than 3 distinct points remain, or the curve is shorter than 2·spacing.
  static PlanarCurvatureProfile from_polyline(std::span<const Eigen::Vector2d> points,
                                              double spacing = kDefaultSpacing);
  // From a 3D polyline (mm) projected onto the plane through the origin spanned by `x_axis` and
  // `y_axis` (plane coordinates p·x_axis, p·y_axis). The axes must be orthonormal (to 1e-6); the
  // other checks are from_polyline's, applied to the projection (a vessel seen end-on has no length in
  // the plane and is refused).
  static PlanarCurvatureProfile from_projection(std::span<const Eigen::Vector3d> points,
                                                const Eigen::Vector3d& x_axis, const Eigen::Vector3d& y_axis,
                                                double spacing = kDefaultSpacing);

  double length() const noexcept { return spacing_ * static_cast<double>(points_.size() - 1); }
  double spacing() const noexcept { return spacing_; }
  // Length of the input polyline itself (3D for from_projection): the vessel's insertion length.
  double vessel_length() const noexcept { return vessel_arc_.back(); }

  // Values at in-plane arc length s, linearly interpolated between samples; no allocation. Outside
  // [0, length()] the curve is taken as continuing straight: point_at extrapolates along the end
  // tangent, heading_at holds the end heading and curvature_at is 0. A NaN s gives NaN.
  Eigen::Vector2d point_at(double s) const noexcept;
  double heading_at(double s) const noexcept;    // continuous (unwrapped), rad
  double curvature_at(double s) const noexcept;  // rad/mm, positive turning from x towards y
  // (θ(s1) − θ(s0)) / (s1 − s0): the κ to give one EKF step from s0 to s1, so that its predicted heading
  // turns exactly as the curve does over the step; curvature_at(s0) when s1 == s0.
  double mean_curvature(double s0, double s1) const noexcept;

  // In-plane arc length at vessel arc length s (monotone, piecewise linear; clamped to the ends; the
  // identity for from_polyline). NaN gives NaN.
  double in_plane_arc_length(double vessel_arc_length) const noexcept;

  // The samples, every spacing() mm of in-plane arc length from the first point.
  const std::vector<Eigen::Vector2d>& points() const noexcept { return points_; }
  const std::vector<double>& headings() const noexcept { return headings_; }
  const std::vector<double>& curvatures() const noexcept { return curvatures_; }

 private:
  PlanarCurvatureProfile() = default;
  static PlanarCurvatureProfile build(std::span<const Eigen::Vector2d> planar,
                                      std::span<const double> vessel_arc, double spacing);

  double spacing_ = 0.0;
  std::vector<Eigen::Vector2d> points_;
  std::vector<double> headings_;
  std::vector<double> curvatures_;
  // Arc length of each distinct input vertex, in the plane and along the input curve.
  std::vector<double> plane_arc_;
  std::vector<double> vessel_arc_;
};

}  // namespace tendril::teleop::perception
