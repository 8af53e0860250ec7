#include "tendril/drivers/sim/contact_surface.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "tendril/drivers/sim/simulated_drive.hpp"  // SimulationSetupError

namespace tendril::sim {

namespace {

constexpr double kNormalStep = 0.5;  // mm, central differences of the height map

bool is_rigid(const Eigen::Isometry3d& pose) noexcept {
  const Eigen::Matrix3d r = pose.linear();
  return pose.matrix().allFinite() && (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-9 &&
         r.determinant() > 0.0;
}

void require(bool ok, const std::string& what) {
  if (!ok) throw SimulationSetupError("contact surface: " + what);
}

}  // namespace

ContactSurface::ContactSurface(const ContactSurfaceParameters& parameters) : parameters_(parameters) {
  const auto& p = parameters;
  require(is_rigid(p.pose), "pose must be a finite rigid transform");
  require(std::isfinite(p.stiffness) && p.stiffness > 0.0,
          "stiffness must be positive (got " + std::to_string(p.stiffness) + " N/mm)");
  require(std::isfinite(p.damping) && p.damping >= 0.0,
          "damping must be >= 0 (got " + std::to_string(p.damping) + " N·s/mm)");
  if (p.shape == ContactShape::box) {
    require(std::isfinite(p.half_length) && p.half_length > 0.0 && std::isfinite(p.half_width) &&
                p.half_width > 0.0 && std::isfinite(p.depth) && p.depth > 0.0,
            "a box needs positive half_length, half_width and depth");
  }
  move_to(p.pose);
}

void ContactSurface::move_to(const Eigen::Isometry3d& pose, const Eigen::Vector3d& velocity) noexcept {
  if (!is_rigid(pose) || !velocity.allFinite()) return;
  Motion m;
  Eigen::Map<Eigen::Matrix4d>(m.pose.data()) = pose.matrix();
  Eigen::Map<Eigen::Vector3d>(m.velocity.data()) = velocity;
  motion_.store(m);
}

Eigen::Isometry3d ContactSurface::pose() const noexcept {
  const Motion m = motion_.load();
  Eigen::Isometry3d pose;
  pose.matrix() = Eigen::Map<const Eigen::Matrix4d>(m.pose.data());
  return pose;
}

double ContactSurface::surface_height(double x, double y) const noexcept {
  if (parameters_.height_map == nullptr) return 0.0;
  const double h = parameters_.height_map->height(x, y);
  return std::isfinite(h) ? h : 0.0;
}

ContactSample ContactSurface::contact(const Eigen::Vector3d& point,
                                      const Eigen::Vector3d& velocity) const noexcept {
  ContactSample out;
  if (!point.allFinite() || !velocity.allFinite()) return out;
  const Motion m = motion_.load();
  Eigen::Isometry3d pose;
  pose.matrix() = Eigen::Map<const Eigen::Matrix4d>(m.pose.data());
  const Eigen::Matrix3d r = pose.linear();
  // The tool point and its velocity relative to the surface, in the surface frame.
  const Eigen::Vector3d x = r.transpose() * (point - pose.translation());
  const Eigen::Vector3d u = r.transpose() * (velocity - Eigen::Map<const Eigen::Vector3d>(m.velocity.data()));

  const double h = surface_height(x.x(), x.y());
  if (!(x.z() < h)) return out;  // above the surface (or a NaN height map)
  Eigen::Vector3d n(0.0, 0.0, 1.0);
  if (parameters_.height_map != nullptr) {
    const double dhdx =
        (surface_height(x.x() + kNormalStep, x.y()) - surface_height(x.x() - kNormalStep, x.y())) /
        (2.0 * kNormalStep);
    const double dhdy =
        (surface_height(x.x(), x.y() + kNormalStep) - surface_height(x.x(), x.y() - kNormalStep)) /
        (2.0 * kNormalStep);
    n = Eigen::Vector3d(-dhdx, -dhdy, 1.0).normalized();
  }
  double depth = (h - x.z()) * n.z();
  if (parameters_.shape == ContactShape::box) {
    const double to_x = parameters_.half_length - std::abs(x.x());
    const double to_y = parameters_.half_width - std::abs(x.y());
    const double to_bottom = x.z() + parameters_.depth;
    if (to_x < 0.0 || to_y < 0.0 || to_bottom < 0.0) return out;  // outside the box
    // The nearest face pushes the point out.
    if (to_x < depth) {
      depth = to_x;
      n = Eigen::Vector3d(std::copysign(1.0, x.x()), 0.0, 0.0);
    }
    if (to_y < depth) {
      depth = to_y;
      n = Eigen::Vector3d(0.0, std::copysign(1.0, x.y()), 0.0);
    }
    if (to_bottom < depth) {
      depth = to_bottom;
      n = Eigen::Vector3d(0.0, 0.0, -1.0);
    }
  }
  const double rate = -u.dot(n);  // penetration speed
  const double magnitude = std::max(0.0, parameters_.stiffness * depth + parameters_.damping * rate);
  out.in_contact = true;
  out.penetration = depth;
  out.normal = r * n;
  out.force = magnitude * out.normal;
  return out;
}

}  // namespace tendril::sim
