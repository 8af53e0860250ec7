#include "tendril/continuum/sdu_simulation.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace tendril::continuum {

namespace {

bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

void require(bool ok, const char* what) {
  if (!ok) throw std::invalid_argument(std::string("SIMULATED SDU: ") + what);
}

// Ray against an oriented box (slab method), entry distance only (the origin outside).
std::optional<double> ray_box(const SceneBox& box, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  const Eigen::Isometry3d inv = box.pose.inverse();
  const Eigen::Vector3d lo = inv * o;
  const Eigen::Vector3d ld = inv.linear() * d;
  double t0 = 0.0, t1 = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double e = box.half_extent_mm[a];
    if (std::abs(ld[a]) < 1e-12) {
      if (lo[a] < -e || lo[a] > e) return std::nullopt;
      continue;
    }
    double ta = (-e - lo[a]) / ld[a], tb = (e - lo[a]) / ld[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return std::nullopt;
  }
  if (t0 <= 0.0) return std::nullopt;  // inside the box: the sensor is blocked, not ranging
  return t0;
}

std::optional<double> ray_cylinder(const SceneCylinder& c, const Eigen::Vector3d& o,
                                   const Eigen::Vector3d& d) {
  const Eigen::Vector3d w = o - c.centre;
  const Eigen::Vector3d dp = d - d.dot(c.axis) * c.axis;
  const Eigen::Vector3d wp = w - w.dot(c.axis) * c.axis;
  const double a = dp.squaredNorm();
  if (a < 1e-12) return std::nullopt;
  const double b = 2.0 * dp.dot(wp);
  const double cc = wp.squaredNorm() - c.radius_mm * c.radius_mm;
  const double disc = b * b - 4.0 * a * cc;
  if (disc < 0.0) return std::nullopt;
  const double t = (-b - std::sqrt(disc)) / (2.0 * a);
  if (t <= 0.0) return std::nullopt;
  const double along = (w + t * d).dot(c.axis);
  if (std::abs(along) > c.half_length_mm) return std::nullopt;
  return t;
}

}  // namespace

std::size_t Scene::add(const ScenePlane& plane) {
  require(finite(plane.point) && finite(plane.normal) && plane.normal.norm() > 1e-9,
          "a plane needs a finite point and a non-zero normal");
  ScenePlane p = plane;
  p.normal.normalize();
  planes_.push_back(p);
  return planes_.size() - 1;
}

std::size_t Scene::add(const SceneBox& box) {
  require(
      box.pose.matrix().allFinite() && finite(box.half_extent_mm) && (box.half_extent_mm.array() > 0.0).all(),
      "a box needs a finite pose and positive half extents");
  boxes_.push_back(box);
  return boxes_.size() - 1;
}

std::size_t Scene::add(const SceneCylinder& cylinder) {
  require(finite(cylinder.centre) && finite(cylinder.axis) && cylinder.axis.norm() > 1e-9 &&
              std::isfinite(cylinder.radius_mm) && cylinder.radius_mm > 0.0 &&
              std::isfinite(cylinder.half_length_mm) && cylinder.half_length_mm > 0.0,
          "a cylinder needs a finite centre, a non-zero axis and a positive radius and length");
  SceneCylinder c = cylinder;
  c.axis.normalize();
  cylinders_.push_back(c);
  return cylinders_.size() - 1;
}

void Scene::move_cylinder(std::size_t index, const Eigen::Vector3d& centre) {
  if (index >= cylinders_.size())
    throw std::out_of_range("SIMULATED SDU scene: no cylinder " + std::to_string(index));
  require(finite(centre), "a cylinder's centre must be finite");
  cylinders_[index].centre = centre;
}

std::optional<RayHit> Scene::cast(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                                  double max_range) const noexcept {
  std::optional<RayHit> best;
  auto consider = [&](double t, SurfaceFinish finish) {
    if (t > 0.0 && t <= max_range && (!best || t < best->distance_mm)) best = RayHit{t, finish};
  };
  for (const auto& p : planes_) {
    const double denom = d.dot(p.normal);
    if (denom >= -1e-12) continue;  // parallel, or seen from behind
    consider((p.point - o).dot(p.normal) / denom, p.finish);
  }
  for (const auto& b : boxes_)
    if (const auto t = ray_box(b, o, d)) consider(*t, b.finish);
  for (const auto& c : cylinders_)
    if (const auto t = ray_cylinder(c, o, d)) consider(*t, c.finish);
  return best;
}

double Scene::penetration(const Eigen::Vector3d& x) const noexcept {
  double depth = 0.0;
  for (const auto& p : planes_) depth = std::max(depth, -(x - p.point).dot(p.normal));
  for (const auto& b : boxes_) {
    const Eigen::Vector3d l = b.pose.inverse() * x;
    const Eigen::Vector3d inside = b.half_extent_mm - l.cwiseAbs();
    if ((inside.array() > 0.0).all()) depth = std::max(depth, inside.minCoeff());
  }
  for (const auto& c : cylinders_) {
    const Eigen::Vector3d w = x - c.centre;
    const double along = w.dot(c.axis);
    if (std::abs(along) > c.half_length_mm) continue;
    const double radial = (w - along * c.axis).norm();
    depth = std::max(depth, std::min(c.radius_mm - radial, c.half_length_mm - std::abs(along)));
  }
  return depth;
}

double tof_error_mm(const TofModel& m, SurfaceFinish finish, double off_axis) noexcept {
  const bool glossy = finish == SurfaceFinish::kGlossy;
  const double edge = glossy ? m.glossy_half_angle_rad : m.matte_half_angle_rad;
  const double axis_error = glossy ? m.glossy_on_axis_error_mm : m.matte_on_axis_error_mm;
  const double edge_error = glossy ? m.glossy_edge_error_mm : m.matte_edge_error_mm;
  const double x = std::min(1.0, std::abs(off_axis) / edge);
  return axis_error + (edge_error - axis_error) * x * x;
}

double hall_field_change_mT(const HallModel& m, double force_n) noexcept {
  const double x = std::clamp(force_n / m.calibration_range_N, 0.0, 1.0);
  return m.slope_mT_per_N * (force_n + 6.0 * m.f_linearity * m.calibration_range_N * x * (1.0 - x));
}

SimulatedSduNode::SimulatedSduNode(const SduSegmentModel& segment, TofModel tof, HallModel hall,
                                   std::uint64_t seed)
    : segment_(segment), tof_(tof), hall_(hall), rng_(seed) {
  segment_.validate();
  require(tof_.max_range_mm > 0.0 && tof_.noise_sd_mm >= 0.0 && tof_.rings >= 0 && tof_.rays_per_ring > 0,
          "ToF model: range must be positive, noise non-negative");
  require(hall_.slope_mT_per_N > 0.0 && hall_.sleeve_stiffness_N_per_mm > 0.0 && hall_.noise_sd_mT >= 0.0 &&
              hall_.calibration_range_N > 0.0 && hall_.footprint_half_angle_rad > 0.0,
          "Hall model: slope, stiffness, range and footprint must be positive, noise non-negative");
  // Each magnet's rest field differs (position tolerance of the casting): a few mT on z, less across.
  std::uniform_real_distribution<double> across(-0.5, 0.5), along(6.0, 12.0);
  for (auto& b : rest_field_) b = {across(rng_), across(rng_), along(rng_)};
}

void SimulatedSduNode::fill_hall(SduSample& s, double t_s) {
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    const double dz = hall_field_change_mT(hall_, true_force_[j]) + hall_.drift_mT_per_s * t_s;
    for (int a = 0; a < 3; ++a)
      s.hall_mT[j][a] = rest_field_[j][a] + (a == 2 ? dz : 0.0) + hall_.noise_sd_mT * unit_(rng_);
    s.hall_ok[j] = true;
  }
}

SduSample SimulatedSduNode::sense(const Scene& scene, const Eigen::Isometry3d& disk_pose, double t_s) {
  SduSample s;
  s.received = true;
  const double cone = tof_.matte_half_angle_rad;
  for (std::size_t j = 0; j < kTofPerSdu; ++j) {
    const Eigen::Isometry3d sensor = disk_pose * tof_sensor_in_disk(segment_, j);
    const Eigen::Vector3d origin = sensor.translation();
    const Eigen::Vector3d axis = sensor.linear().col(2), u = sensor.linear().col(0),
                          v = sensor.linear().col(1);
    double best = std::numeric_limits<double>::infinity();
    // A window covered by an object (pressed into the sleeve) reads zero, as a covered VL6180X does; a
    // ray starting inside a solid would otherwise see nothing and call the way clear.
    if (scene.penetration(origin) > 0.0) best = 0.0;
    auto ray = [&](double off, double around) {
      const Eigen::Vector3d dir =
          (std::cos(off) * axis + std::sin(off) * (std::cos(around) * u + std::sin(around) * v)).normalized();
      const auto hit = scene.cast(origin, dir, tof_.max_range_mm + 20.0);
      if (!hit) return;
      const double half =
          hit->finish == SurfaceFinish::kGlossy ? tof_.glossy_half_angle_rad : tof_.matte_half_angle_rad;
      if (off > half + 1e-9) return;  // outside this finish's cone: no return
      best = std::min(best, hit->distance_mm + tof_error_mm(tof_, hit->finish, off));
    };
    ray(0.0, 0.0);
    for (int r = 1; r <= tof_.rings; ++r)
      for (int k = 0; k < tof_.rays_per_ring; ++k)
        ray(cone * r / tof_.rings, 2.0 * M_PI * k / tof_.rays_per_ring);
    if (std::isfinite(best)) best += tof_.noise_sd_mm * unit_(rng_);
    if (std::isfinite(best) && best <= tof_.max_range_mm) {
      s.tof_status[j] = TofStatus::kValid;
      s.tof_mm[j] = std::max(0.0, best);
    } else {
      s.tof_status[j] = TofStatus::kNoTarget;
      s.tof_mm[j] = 0.0;
    }
  }
  // Hall: the deepest intrusion of the scene into the sleeve over each window's sector, weighted by
  // how near the window's centre it is, makes the normal force on that window.
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    double depth = 0.0;
    constexpr int kSamples = 9;
    for (int k = 0; k < kSamples; ++k) {
      const double frac = -1.0 + 2.0 * k / (kSamples - 1);
      const double a = hall_slot_angle(segment_, j) + frac * hall_.footprint_half_angle_rad;
      const Eigen::Vector3d local(segment_.disk_radius_mm * std::cos(a),
                                  segment_.disk_radius_mm * std::sin(a), 0.0);
      depth = std::max(depth, scene.penetration(disk_pose * local) * (1.0 - 0.5 * std::abs(frac)));
    }
    true_force_[j] = hall_.sleeve_stiffness_N_per_mm * depth;
  }
  fill_hall(s, t_s);
  return s;
}

SduSample SimulatedSduNode::sense_forces(const std::array<double, kHallPerSdu>& force_n, double t_s) {
  SduSample s;
  s.received = true;
  s.tof_status.fill(TofStatus::kNoTarget);
  for (std::size_t j = 0; j < kHallPerSdu; ++j) true_force_[j] = std::max(0.0, force_n[j]);
  fill_hall(s, t_s);
  return s;
}

}  // namespace tendril::continuum
