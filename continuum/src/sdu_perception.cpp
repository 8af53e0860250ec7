#include "tendril/continuum/sdu_perception.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

namespace tendril::continuum {

Eigen::Vector3d tof_point(const SduSegmentModel& model, const Eigen::Isometry3d& disk_pose, std::size_t slot,
                          double range_mm) noexcept {
  return disk_pose * (tof_sensor_in_disk(model, slot) * Eigen::Vector3d(0.0, 0.0, range_mm));
}

std::size_t sample_points(const SduSegmentModel& model, const Eigen::Isometry3d& disk_pose,
                          const SduSample& sample, double max_range_mm,
                          std::span<Eigen::Vector3d> out) noexcept {
  std::size_t n = 0;
  if (!sample.received) return 0;
  for (std::size_t j = 0; j < kTofPerSdu && n < out.size(); ++j) {
    const double d = sample.tof_mm[j];
    if (sample.tof_status[j] != TofStatus::kValid || !std::isfinite(d) || d < 0.0 || d > max_range_mm)
      continue;
    out[n++] = tof_point(model, disk_pose, j, d);
  }
  return n;
}

// --- VoxelMap ---------------------------------------------------------------------------------------

VoxelMap::VoxelMap(double voxel_mm, std::size_t capacity) : voxel_mm_(voxel_mm), capacity_(capacity) {
  if (!std::isfinite(voxel_mm) || voxel_mm <= 0.0)
    throw std::invalid_argument("voxel map: voxel size must be a positive length in mm");
  if (capacity == 0) throw std::invalid_argument("voxel map: capacity must be at least one voxel");
  std::size_t slots = 16;
  while (slots < 2 * capacity) slots *= 2;  // load ≤ 50 %: short probes
  table_.assign(slots, 0);
  cells_.resize(capacity);
}

MapInsert VoxelMap::insert(const Eigen::Vector3d& x) noexcept {
  if (!x.allFinite() || x.cwiseAbs().maxCoeff() > 1e9) {
    ++refused_invalid_;
    return MapInsert::kRejected;
  }
  // 21 bits per axis (±1,048,576 voxels) packed into one key.
  std::int64_t key = 0;
  for (int a = 0; a < 3; ++a) {
    const auto i = static_cast<std::int64_t>(std::floor(x[a] / voxel_mm_));
    key = (key << 21) | ((i + (1 << 20)) & ((1 << 21) - 1));
  }
  const std::size_t mask = table_.size() - 1;
  std::size_t h =
      static_cast<std::size_t>(static_cast<std::uint64_t>(key) * 0x9E3779B97F4A7C15ULL >> 20) & mask;
  for (;; h = (h + 1) & mask) {
    const std::int64_t slot = table_[h];
    if (slot == 0) break;
    Cell& c = cells_[static_cast<std::size_t>(slot - 1)];
    if (c.key == key) {
      c.sum += x;
      ++c.count;
      ++points_in_;
      return MapInsert::kMerged;
    }
  }
  if (used_ >= capacity_) {
    ++refused_full_;
    return MapInsert::kFull;
  }
  cells_[used_] = Cell{key, x, 1};
  table_[h] = static_cast<std::int64_t>(++used_);
  ++points_in_;
  return MapInsert::kNewVoxel;
}

std::vector<Eigen::Vector3d> VoxelMap::points() const {
  std::vector<Eigen::Vector3d> out;
  out.reserve(used_);
  for (std::size_t i = 0; i < used_; ++i) out.push_back(cells_[i].sum / cells_[i].count);
  return out;
}

// --- planes -------------------------------------------------------------------------------------------

const char* to_string(MapError error) noexcept {
  switch (error) {
    case MapError::kNoPoints:
      return "the map holds no points yet";
    case MapError::kTooFewPoints:
      return "too few points for a plane";
    case MapError::kNoPlaneFound:
      return "no plane with enough inliers";
    case MapError::kInvalidInput:
      return "invalid parameters";
  }
  return "unknown";
}

namespace {

bool normal_admissible(const Eigen::Vector3d& n, const RansacParameters& p) {
  if (!p.reference_normal) return true;
  return std::abs(n.dot(*p.reference_normal)) >= std::cos(p.max_angle_rad);
}

// Least-squares plane through the points selected: the covariance's smallest eigenvector.
Plane refit(std::span<const Eigen::Vector3d> points, const std::vector<std::size_t>& idx) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (auto i : idx) mean += points[i];
  mean /= static_cast<double>(idx.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (auto i : idx) {
    const Eigen::Vector3d d = points[i] - mean;
    cov += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
  Plane pl;
  pl.normal = es.eigenvectors().col(0).normalized();
  pl.offset_mm = pl.normal.dot(mean);
  return pl;
}

}  // namespace

std::variant<PlaneFit, MapError> fit_plane_ransac(std::span<const Eigen::Vector3d> points,
                                                  const RansacParameters& p) {
  if (!std::isfinite(p.inlier_distance_mm) || p.inlier_distance_mm <= 0.0 || p.iterations == 0 ||
      (p.reference_normal && (!p.reference_normal->allFinite() || p.reference_normal->norm() < 1e-9)))
    return MapError::kInvalidInput;
  if (points.empty()) return MapError::kNoPoints;
  if (points.size() < 3 || points.size() < p.min_inliers) return MapError::kTooFewPoints;
  RansacParameters params = p;
  if (params.reference_normal) params.reference_normal->normalize();

  std::mt19937_64 rng(p.seed);
  std::uniform_int_distribution<std::size_t> pick(0, points.size() - 1);
  std::size_t best_count = 0;
  Plane best;
  for (std::size_t it = 0; it < p.iterations; ++it) {
    const auto& a = points[pick(rng)];
    const auto& b = points[pick(rng)];
    const auto& c = points[pick(rng)];
    Eigen::Vector3d n = (b - a).cross(c - a);
    if (n.norm() < 1e-6) continue;
    n.normalize();
    if (!normal_admissible(n, params)) continue;
    const Plane cand{n, n.dot(a)};
    std::size_t count = 0;
    for (const auto& x : points) count += std::abs(cand.distance(x)) <= p.inlier_distance_mm ? 1 : 0;
    if (count > best_count) {
      best_count = count;
      best = cand;
    }
  }
  if (best_count < std::max<std::size_t>(3, p.min_inliers)) return MapError::kNoPlaneFound;

  PlaneFit fit;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (std::abs(best.distance(points[i])) <= p.inlier_distance_mm) fit.inliers.push_back(i);
  fit.plane = refit(points, fit.inliers);
  if (!normal_admissible(fit.plane.normal, params)) fit.plane = best;  // keep the admissible sample plane
  // Re-select with the refined plane, so the inliers are those of the plane reported.
  fit.inliers.clear();
  for (std::size_t i = 0; i < points.size(); ++i)
    if (std::abs(fit.plane.distance(points[i])) <= p.inlier_distance_mm) fit.inliers.push_back(i);
  if (fit.inliers.size() < std::max<std::size_t>(3, p.min_inliers)) return MapError::kNoPlaneFound;
  const Eigen::Vector3d want = params.reference_normal.value_or(Eigen::Vector3d::Zero());
  if (params.reference_normal && fit.plane.normal.dot(want) < 0.0) {
    fit.plane.normal = -fit.plane.normal;
    fit.plane.offset_mm = -fit.plane.offset_mm;
  }
  double sq = 0.0;
  for (auto i : fit.inliers) sq += fit.plane.distance(points[i]) * fit.plane.distance(points[i]);
  fit.rms_mm = std::sqrt(sq / static_cast<double>(fit.inliers.size()));
  return fit;
}

std::variant<std::vector<PlaneFit>, MapError> extract_planes(std::span<const Eigen::Vector3d> points,
                                                             const RansacParameters& p,
                                                             std::size_t max_planes) {
  if (points.empty()) return MapError::kNoPoints;
  std::vector<Eigen::Vector3d> rest(points.begin(), points.end());
  std::vector<std::size_t> original(points.size());
  for (std::size_t i = 0; i < original.size(); ++i) original[i] = i;
  std::vector<PlaneFit> planes;
  for (std::size_t k = 0; k < max_planes; ++k) {
    RansacParameters pk = p;
    pk.seed = p.seed + k;
    auto r = fit_plane_ransac(rest, pk);
    if (std::holds_alternative<MapError>(r)) {
      if (planes.empty()) return std::get<MapError>(r);
      break;
    }
    PlaneFit fit = std::get<PlaneFit>(std::move(r));
    std::vector<bool> taken(rest.size(), false);
    for (auto i : fit.inliers) taken[i] = true;
    std::vector<Eigen::Vector3d> next;
    std::vector<std::size_t> next_original;
    for (std::size_t i = 0; i < rest.size(); ++i) {
      if (!taken[i]) {
        next.push_back(rest[i]);
        next_original.push_back(original[i]);
      }
    }
    for (auto& i : fit.inliers) i = original[i];  // report indices into the caller's points
    planes.push_back(std::move(fit));
    rest.swap(next);
    original.swap(next_original);
    if (rest.empty()) break;
  }
  return planes;
}

BracingResult check_bracing(std::span<const Eigen::Vector3d> points, const PlaneFit& fit,
                            const BracingParameters& p) {
  BracingResult out;
  if (!(p.cell_mm > 0.0) || !(p.patch_side_mm > 0.0) || p.orientations < 1) {
    out.reason = "invalid bracing parameters";
    return out;
  }
  const Eigen::Vector3d n = fit.plane.normal;
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  std::vector<Eigen::Vector2d> uv;
  for (auto i : fit.inliers) {
    if (i >= points.size()) continue;
    if (std::abs(fit.plane.distance(points[i])) > p.max_residual_mm) continue;
    uv.emplace_back(points[i].dot(e1), points[i].dot(e2));
  }
  if (uv.size() < 3) {
    out.reason = "fewer than three points on the plane";
    return out;
  }
  const double origin_offset = fit.plane.offset_mm;
  int best_k = 0;
  Eigen::Vector2d best_centre = Eigen::Vector2d::Zero();
  for (int o = 0; o < p.orientations; ++o) {
    const double a = (M_PI / 2.0) * o / p.orientations;
    const Eigen::Rotation2Dd rot(a);
    Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector2d hi = -lo;
    std::vector<Eigen::Vector2d> r(uv.size());
    for (std::size_t i = 0; i < uv.size(); ++i) {
      r[i] = rot * uv[i];
      lo = lo.cwiseMin(r[i]);
      hi = hi.cwiseMax(r[i]);
    }
    const int nx = static_cast<int>(std::floor((hi.x() - lo.x()) / p.cell_mm)) + 1;
    const int ny = static_cast<int>(std::floor((hi.y() - lo.y()) / p.cell_mm)) + 1;
    if (static_cast<long>(nx) * ny > 4'000'000) continue;  // a plane kilometres wide: not a map of this robot
    std::vector<int> dp(static_cast<std::size_t>(nx) * ny, 0);
    std::vector<char> occ(dp.size(), 0);
    for (const auto& q : r) {
      const int ix = std::min(nx - 1, static_cast<int>((q.x() - lo.x()) / p.cell_mm));
      const int iy = std::min(ny - 1, static_cast<int>((q.y() - lo.y()) / p.cell_mm));
      occ[static_cast<std::size_t>(iy) * nx + ix] = 1;
    }
    // Largest all-occupied square (classic dynamic programme).
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * nx + x;
        if (!occ[i]) continue;
        int v = 1;
        if (x > 0 && y > 0) v = 1 + std::min({dp[i - 1], dp[i - nx], dp[i - nx - 1]});
        dp[i] = v;
        if (v > best_k) {
          best_k = v;
          const Eigen::Vector2d centre_rot(lo.x() + (x + 1 - v / 2.0) * p.cell_mm,
                                           lo.y() + (y + 1 - v / 2.0) * p.cell_mm);
          best_centre = rot.inverse() * centre_rot;
        }
      }
    }
  }
  // Points in the first and last cells of a k-cell run span between (k − 2) and k cells: (k − 1)·cell.
  out.largest_square_mm = best_k > 0 ? (best_k - 1) * p.cell_mm : 0.0;
  out.patch_centre = best_centre.x() * e1 + best_centre.y() * e2 + origin_offset * n;
  out.admissible = out.largest_square_mm >= p.patch_side_mm;
  char buf[160];
  std::snprintf(buf, sizeof buf, "largest continuous square patch %.0f mm %s the %.0f mm required",
                out.largest_square_mm, out.admissible ? "meets" : "is smaller than", p.patch_side_mm);
  out.reason = buf;
  return out;
}

std::variant<BracingResult, MapError> check_bracing_in_map(const VoxelMap& map,
                                                           const RansacParameters& ransac,
                                                           const BracingParameters& bracing) {
  if (map.size() == 0) return MapError::kNoPoints;
  const auto points = map.points();
  auto fit = fit_plane_ransac(points, ransac);
  if (std::holds_alternative<MapError>(fit)) return std::get<MapError>(fit);
  return check_bracing(points, std::get<PlaneFit>(fit), bracing);
}

double rms_to_nearest_plane(std::span<const Eigen::Vector3d> points, std::span<const Plane> planes) noexcept {
  if (points.empty() || planes.empty()) return std::numeric_limits<double>::quiet_NaN();
  double sq = 0.0;
  for (const auto& x : points) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& pl : planes) best = std::min(best, std::abs(pl.distance(x)));
    sq += best * best;
  }
  return std::sqrt(sq / static_cast<double>(points.size()));
}

// --- Hall ---------------------------------------------------------------------------------------------

bool HallUnbiaser::add(const SduSample& s) noexcept {
  if (!s.received) return false;
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    if (!s.hall_ok[j]) return false;
    for (double v : s.hall_mT[j])
      if (!std::isfinite(v)) return false;
  }
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    for (int a = 0; a < 3; ++a) sum_[j][a] += s.hall_mT[j][a];
    sum_sq_z_[j] += s.hall_mT[j][2] * s.hall_mT[j][2];
  }
  ++n_;
  return true;
}

HallBias HallUnbiaser::bias() const noexcept {
  HallBias b;
  if (n_ == 0) return b;
  const double n = static_cast<double>(n_);
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    for (int a = 0; a < 3; ++a) b.b0_mT[j][a] = sum_[j][a] / n;
    b.sd_z_mT[j] = std::sqrt(std::max(0.0, sum_sq_z_[j] / n - b.b0_mT[j][2] * b.b0_mT[j][2]));
  }
  return b;
}

std::array<double, kHallPerSdu> hall_forces(const SduSample& s, const HallBias& bias, double slope) noexcept {
  std::array<double, kHallPerSdu> f;
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    const double bz = s.hall_mT[j][2];
    f[j] = (s.received && s.hall_ok[j] && std::isfinite(bz) && slope > 0.0)
               ? (bz - bias.b0_mT[j][2]) / slope
               : std::numeric_limits<double>::quiet_NaN();
  }
  return f;
}

ContactLocation locate_contact(const SduSegmentModel& model, std::span<const Eigen::Isometry3d> poses,
                               std::span<const std::array<double, kHallPerSdu>> forces,
                               double threshold) noexcept {
  ContactLocation c;
  const std::size_t disks = std::min(poses.size(), forces.size());
  for (std::size_t i = 0; i < disks; ++i) {
    for (std::size_t j = 0; j < kHallPerSdu; ++j) {
      const double f = forces[i][j];
      if (!std::isfinite(f) || f < threshold || (c.contact && f <= c.force_n)) continue;
      c.contact = true;
      c.disk = static_cast<int>(i);
      c.slot = static_cast<int>(j);
      c.force_n = f;
    }
  }
  if (c.contact) {
    const auto& pose = poses[static_cast<std::size_t>(c.disk)];
    const auto slot = static_cast<std::size_t>(c.slot);
    c.slot_angle_rad = hall_slot_angle(model, slot);
    c.point = pose * hall_point_in_disk(model, slot);
    c.normal = pose.linear() * hall_normal_in_disk(model, slot);
    c.from_centre = c.point - pose.translation();
  }
  return c;
}

HallCalibration calibrate_hall_slope(std::span<const double> f, std::span<const double> b) {
  if (f.size() != b.size())
    throw std::invalid_argument("Hall calibration: as many field readings as forces are needed");
  if (f.size() < 2)
    throw std::invalid_argument("Hall calibration: at least two (force, field) pairs are needed");
  double mf = 0.0, mb = 0.0;
  for (std::size_t i = 0; i < f.size(); ++i) {
    if (!std::isfinite(f[i]) || !std::isfinite(b[i]))
      throw std::invalid_argument("Hall calibration: pair " + std::to_string(i) + " is not finite");
    mf += f[i];
    mb += b[i];
  }
  const double n = static_cast<double>(f.size());
  mf /= n;
  mb /= n;
  double sff = 0.0, sfb = 0.0;
  for (std::size_t i = 0; i < f.size(); ++i) {
    sff += (f[i] - mf) * (f[i] - mf);
    sfb += (f[i] - mf) * (b[i] - mb);
  }
  if (sff <= 0.0) throw std::invalid_argument("Hall calibration: the forces do not vary");
  HallCalibration c;
  c.samples = f.size();
  c.slope_mT_per_N = sfb / sff;
  c.intercept_mT = mb - c.slope_mT_per_N * mf;
  const auto [fmin, fmax] = std::minmax_element(f.begin(), f.end());
  const auto [bmin, bmax] = std::minmax_element(b.begin(), b.end());
  double worst_f = 0.0, worst_b = 0.0;
  for (std::size_t i = 0; i < f.size(); ++i) {
    worst_b = std::max(worst_b, std::abs(b[i] - (c.slope_mT_per_N * f[i] + c.intercept_mT)));
    if (c.slope_mT_per_N != 0.0)
      worst_f = std::max(worst_f, std::abs(f[i] - (b[i] - c.intercept_mT) / c.slope_mT_per_N));
  }
  c.f_linearity_pct = 100.0 * worst_f / (*fmax - *fmin);
  c.b_linearity_pct = *bmax > *bmin ? 100.0 * worst_b / (*bmax - *bmin) : 0.0;
  return c;
}

}  // namespace tendril::continuum
