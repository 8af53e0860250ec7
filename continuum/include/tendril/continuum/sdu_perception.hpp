// Perception from sensing disk units (Abah 2022, §3.3–3.5): ToF ranges to points in the base frame {0}
// through the disk poses, an accumulated point map with voxel down-sampling, RANSAC plane extraction
// (40 mm inlier distance, optional reference normal), the bracing check (an admissible planar patch of
// at least 150 × 150 mm), and the Hall path: start-up unbiasing, force F = ΔB_z / 0.26 mT/N, contact
// detection and localisation by disk and angular slot, and the slope calibration of §3.3.1.
//
// Real-time contract: sample_points(), VoxelMap::insert(), hall_forces() and locate_contact() never
// allocate (the map's storage is reserved at construction). Plane fitting and bracing run on a worker.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_segment.hpp"

namespace tendril::continuum {

// --- points ---------------------------------------------------------------------------------------

// The point a range d of ToF slot j measures: ⁰H_d·ᵈH_s·[0, 0, d, 1]ᵀ.
Eigen::Vector3d tof_point(const SduSegmentModel& model, const Eigen::Isometry3d& disk_pose, std::size_t slot,
                          double range_mm) noexcept;
// Writes the points of a sample's valid ranges (finite, 0 ≤ d ≤ max_range) into out; returns how many.
std::size_t sample_points(const SduSegmentModel& model, const Eigen::Isometry3d& disk_pose,
                          const SduSample& sample, double max_range_mm,
                          std::span<Eigen::Vector3d> out) noexcept;

// --- the map ----------------------------------------------------------------------------------------

enum class MapInsert : std::uint8_t { kNewVoxel, kMerged, kFull, kRejected };

// A voxel-down-sampled point map: each occupied voxel keeps the mean of the points that fell in it.
// Capacity is fixed at construction; when full, new voxels are refused and counted and nothing that was
// mapped is lost. Points that are not finite are refused.
class VoxelMap {
 public:
  // Throws std::invalid_argument for a voxel size that is not positive and finite or a zero capacity.
  VoxelMap(double voxel_mm, std::size_t capacity);
  MapInsert insert(const Eigen::Vector3d& point) noexcept;
  std::size_t size() const noexcept { return used_; }
  std::size_t capacity() const noexcept { return capacity_; }
  std::uint64_t refused_full() const noexcept { return refused_full_; }
  std::uint64_t refused_invalid() const noexcept { return refused_invalid_; }
  std::uint64_t points_in() const noexcept { return points_in_; }
  double voxel_mm() const noexcept { return voxel_mm_; }
  // The voxels' mean points (allocates; not for the control thread).
  std::vector<Eigen::Vector3d> points() const;

 private:
  struct Cell {
    std::int64_t key = 0;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    std::uint32_t count = 0;
  };
  double voxel_mm_;
  std::size_t capacity_;
  std::vector<std::int64_t> table_;  // open addressing: index into cells_ + 1, 0 = empty
  std::vector<Cell> cells_;
  std::size_t used_ = 0;
  std::uint64_t refused_full_ = 0, refused_invalid_ = 0, points_in_ = 0;
};

// --- planes and bracing --------------------------------------------------------------------------------

enum class MapError : std::uint8_t {
  kNoPoints,      // the map is empty: nothing was mapped yet (or every reading was invalid)
  kTooFewPoints,  // fewer than three points, or fewer than the minimum inliers
  kNoPlaneFound,  // no plane with enough inliers (within the reference-normal bound)
  kInvalidInput,  // non-finite parameters
};
const char* to_string(MapError error) noexcept;

struct Plane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit
  double offset_mm = 0.0;                             // normal·x = offset on the plane
  double distance(const Eigen::Vector3d& x) const noexcept { return normal.dot(x) - offset_mm; }
};

struct RansacParameters {
  double inlier_distance_mm = 40.0;                 // Abah 2022, §3.5
  std::optional<Eigen::Vector3d> reference_normal;  // MATLAB pcfitplane's referenceVector
  double max_angle_rad = 0.2617993877991494;        // 15° from the reference (sign ignored)
  std::size_t iterations = 500;
  std::size_t min_inliers = 30;
  std::uint64_t seed = 1;
};

struct PlaneFit {
  Plane plane;
  std::vector<std::size_t> inliers;  // indices into the points given
  double rms_mm = 0.0;               // of the inliers' orthogonal residuals
};

// RANSAC over three-point samples, then a least-squares refit on the inliers (the normal's sign follows
// the reference normal when one is given).
std::variant<PlaneFit, MapError> fit_plane_ransac(std::span<const Eigen::Vector3d> points,
                                                  const RansacParameters& p);
// The dissertation's bracing procedure (§3.4): fit, remove the inliers, fit again, up to max_planes.
std::variant<std::vector<PlaneFit>, MapError> extract_planes(std::span<const Eigen::Vector3d> points,
                                                             const RansacParameters& p,
                                                             std::size_t max_planes);

struct BracingParameters {
  double patch_side_mm = 150.0;  // Abah 2022, §3.4
  // The map is sparse; a patch counts as continuous when every cell of this size under it holds a point.
  double cell_mm = 25.0;
  double max_residual_mm = 40.0;  // inliers only
  int orientations = 6;           // square orientations tried, over 90°
};
struct BracingResult {
  bool admissible = false;
  double largest_square_mm = 0.0;  // side of the largest fully occupied square found
  Eigen::Vector3d patch_centre = Eigen::Vector3d::Zero();
  std::string reason;  // for a person
};
// Whether the plane carries a continuous square patch of patch_side_mm (any orientation tried).
BracingResult check_bracing(std::span<const Eigen::Vector3d> points, const PlaneFit& fit,
                            const BracingParameters& p);
// The same from a map, with the defined answer for an empty one.
std::variant<BracingResult, MapError> check_bracing_in_map(const VoxelMap& map,
                                                           const RansacParameters& ransac,
                                                           const BracingParameters& bracing);

// RMS of each point's orthogonal distance to its nearest plane (the dissertation's mapping error, §3.5).
double rms_to_nearest_plane(std::span<const Eigen::Vector3d> points, std::span<const Plane> planes) noexcept;

// --- Hall: unbiasing, force, contact -------------------------------------------------------------------

struct HallBias {
  std::array<std::array<double, 3>, kHallPerSdu> b0_mT{};
  std::array<double, kHallPerSdu> sd_z_mT{};  // spread of z during unbiasing
};

// Averages samples at start-up (robot at rest, nothing touching). Allocation-free.
class HallUnbiaser {
 public:
  void reset() noexcept { *this = HallUnbiaser{}; }
  // Adds a sample; returns false (and ignores it) when any Hall reading is invalid or not finite.
  bool add(const SduSample& sample) noexcept;
  std::size_t count() const noexcept { return n_; }
  HallBias bias() const noexcept;

 private:
  std::array<std::array<double, 3>, kHallPerSdu> sum_{};
  std::array<double, kHallPerSdu> sum_sq_z_{};
  std::size_t n_ = 0;
};

inline constexpr double kHallSlopeMilliTeslaPerNewton = 0.26;  // ᾱ (Abah 2022, §3.3.1)

// F_j = (B_z,j − B0_z,j) / slope; NaN for an invalid or non-finite reading.
std::array<double, kHallPerSdu> hall_forces(const SduSample& sample, const HallBias& bias,
                                            double slope_mT_per_N = kHallSlopeMilliTeslaPerNewton) noexcept;

struct ContactLocation {
  bool contact = false;
  int disk = -1;
  int slot = -1;
  double force_n = 0.0;
  double slot_angle_rad = 0.0;                            // in the disk frame
  Eigen::Vector3d point = Eigen::Vector3d::Zero();        // on the sleeve, in {0}
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();       // outward at the contact, in {0}
  Eigen::Vector3d from_centre = Eigen::Vector3d::Zero();  // r_c: disk centre to contact, in {0}
};
// The strongest Hall force at or above the threshold over every disk, with its place.
ContactLocation locate_contact(const SduSegmentModel& model, std::span<const Eigen::Isometry3d> disk_poses,
                               std::span<const std::array<double, kHallPerSdu>> forces,
                               double threshold_n) noexcept;

// --- slope calibration (§3.3.1) -------------------------------------------------------------------------

struct HallCalibration {
  double slope_mT_per_N = 0.0;   // α of B* = α·F + B0
  double intercept_mT = 0.0;     // B0 of the fit
  double f_linearity_pct = 0.0;  // (3.2) max|F − F*| / ΔF × 100, F* = (B − B0)/α
  double b_linearity_pct = 0.0;  // (3.1) max|B − B*| / ΔB × 100
  std::size_t samples = 0;
};
// Least-squares line through (F, B_z) pairs. Throws std::invalid_argument for fewer than two pairs,
// spans of different lengths, non-finite values or no spread in F.
HallCalibration calibrate_hall_slope(std::span<const double> force_n, std::span<const double> field_mT);

}  // namespace tendril::continuum
