// Vessel centerlines for the pre-operative path planner (Abah 2022, §4.4.2): CSV loading, branch
// splitting, equidistant arc-length resampling, local tangents and the yaw/pitch angles α, β of
// eqs. 4.1–4.3, plus a deterministic synthetic ICA-like path for tests and benchmarks.
//
// Units: millimetres. Resampling is piecewise-linear along the input polyline (the input is expected
// to be a dense, already-smoothed centerline, e.g. the spline of §4.4.2 exported densely);
// tangents are central differences of the resampled points (three-point one-sided at the ends),
// which is second-order accurate where the forward difference of eq. 4.1 would lag by ds/2.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string_view>
#include <vector>

namespace tendril::teleop {

// Thrown for any unusable centerline input (empty, non-finite, degenerate, too short, wrong units).
class VesselInputError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// An ordered polyline as read from a file; radii is empty when the input had no radius column.
struct CenterlinePolyline {
  std::vector<Eigen::Vector3d> points;
  std::vector<double> radii;
};

// Parses "x,y,z[,radius]" lines (mm). A non-numeric first line is taken as a header; blank lines and
// lines starting with '#' are skipped. Consecutive points further apart than branch_jump_factor ×
// the median point spacing start a new branch. Throws VesselInputError on empty input, malformed or
// non-finite numbers, or a mix of 3- and 4-column rows.
std::vector<CenterlinePolyline> parse_centerline_csv(std::string_view csv_text,
                                                     double branch_jump_factor = 5.0);

// Index of the branch with an end point nearest to point. Throws VesselInputError if branches is empty.
std::size_t nearest_branch(const std::vector<CenterlinePolyline>& branches, const Eigen::Vector3d& point);

// Returns the branch oriented so that its end nearest to point comes first.
CenterlinePolyline orient_from(const CenterlinePolyline& branch, const Eigen::Vector3d& point);

class VesselCenterline {
 public:
  // Total polyline lengths below this look like metres, not millimetres (a 150 mm ICA in metres is
  // 0.15): no catheterised vessel is shorter than 1 mm, so such input is rejected as a unit mismatch.
  static constexpr double kMinimumPlausibleLengthMm = 1.0;
  // Upper bounds that keep memory bounded on hostile input: no vessel is 10 m long, and 10⁶ samples
  // is 0.5 km at ds = 0.5 mm.
  static constexpr double kMaximumPlausibleLengthMm = 10'000.0;
  static constexpr std::size_t kMaximumSamples = 1'000'000;

  // Resamples the polyline every ds mm from its first point; the last sample is at floor(L/ds)·ds (a length
  // within 1e-4·ds of the next multiple counts as reaching it, so chord round-off does not lose it).
  // Consecutive duplicate points are dropped first. Throws VesselInputError if fewer than 3 distinct
  // points remain, a value is not finite, ds is not positive, the length looks like metres (or is
  // over 10 m), the resampled path has fewer than 3 samples (too short for the given ds) or more
  // than kMaximumSamples.
  static VesselCenterline from_polyline(const CenterlinePolyline& polyline, double ds);

  // parse_centerline_csv + branch by index (throws VesselInputError when out of range).
  static VesselCenterline from_csv(std::string_view csv_text, double ds, std::size_t branch_index = 0,
                                   double branch_jump_factor = 5.0);
  // parse_centerline_csv + the branch whose end is nearest to start_point, starting at that end.
  static VesselCenterline from_csv_nearest(std::string_view csv_text, double ds,
                                           const Eigen::Vector3d& start_point,
                                           double branch_jump_factor = 5.0);

  std::size_t size() const noexcept { return points_.size(); }
  double spacing() const noexcept { return ds_; }
  double length() const noexcept { return ds_ * static_cast<double>(points_.size() - 1); }
  double arc_length(std::size_t i) const noexcept { return ds_ * static_cast<double>(i); }
  bool has_radius() const noexcept { return !radii_.empty(); }

  const std::vector<Eigen::Vector3d>& points() const noexcept { return points_; }
  const std::vector<Eigen::Vector3d>& tangents() const noexcept { return tangents_; }  // unit vectors
  const std::vector<double>& radii() const noexcept { return radii_; }                 // empty if none
  // Eq. 4.3 (two-argument atan2): yaw α about ẑ₀ and pitch β about ŷ₁ with ⁰R₂ = e^{α[ẑ×]}e^{β[ŷ×]}
  // having the tangent as its z axis. Where the tangent is parallel to ẑ₀, eq. 4.2 is undefined and α
  // keeps the previous sample's value (0 at the start).
  const std::vector<double>& yaw() const noexcept { return yaw_; }
  const std::vector<double>& pitch() const noexcept { return pitch_; }
  Eigen::Matrix3d local_frame(std::size_t i) const noexcept;

  // Rigid transform x ↦ R·x + t (R must be a rotation).
  VesselCenterline transformed(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation) const;
  // Copy moved so that its first point is the origin and its first tangent is +z (insertion frame).
  VesselCenterline aligned_to_insertion() const;
  // The rigid transform aligned_to_insertion() applies: x ↦ R·(x − p₀), R turning the first tangent to +z.
  Eigen::Isometry3d insertion_alignment() const;

 private:
  VesselCenterline() = default;
  void compute_tangents_and_angles();

  double ds_ = 0.0;
  std::vector<Eigen::Vector3d> points_;
  std::vector<Eigen::Vector3d> tangents_;
  std::vector<double> radii_;
  std::vector<double> yaw_;
  std::vector<double> pitch_;
};

// Where a vessel lies in a robot's frame when its start is placed at the robot's vessel entry (a
// catheter's insertion point, with the insertion direction as z): entry · insertion_alignment(). The
// path planner's insertion frame is this with the entry at the origin, so a plan's geometry maps into
// the robot's frame by the entry alone. `ds` resamples the polyline for its first tangent.
Eigen::Isometry3d placement_at_entry(const CenterlinePolyline& vessel, const Eigen::Isometry3d& entry,
                                     double ds = 0.5);
// The polyline moved by `placement` (radii unchanged).
CenterlinePolyline transformed(const CenterlinePolyline& vessel, const Eigen::Isometry3d& placement);

struct SyntheticIcaOptions {
  double length = 150.0;         // mm of path
  double min_bend_radius = 5.0;  // mm
  double max_bend_radius = 15.0;
  double min_vessel_radius = 2.0;  // mm (lumen radius along the path)
  double max_vessel_radius = 3.0;
  double point_spacing = 0.1;  // mm between generated points
};

// ICA-like centerline: straight runs alternating with circular bends of 5–15 mm radius in randomly
// rolled planes (siphon-like), a smoothly varying lumen radius, starting at the origin along +z.
// Deterministic for a given seed on every platform (own uniform mapping of std::mt19937 output).
CenterlinePolyline make_synthetic_ica(std::uint32_t seed, const SyntheticIcaOptions& options = {});

}  // namespace tendril::teleop
