#include "tendril/drivers/sim/catheter_vessel_contact.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace tendril::sim {

CatheterVesselContact::CatheterVesselContact(std::vector<Eigen::Vector3d> centerline,
                                             const teleop::ModalCatheterParameters& shape,
                                             CatheterVesselContactParameters parameters)
    : centerline_(std::move(centerline)), shape_(shape), parameters_(parameters) {
  if (centerline_.size() < 2)
    throw std::invalid_argument("vessel contact: the centerline needs at least 2 points");
  for (const auto& p : centerline_)
    if (!p.allFinite()) throw std::invalid_argument("vessel contact: a centerline point is not finite");
  if (!(parameters_.catheter_radius > 0) || !(parameters_.lumen_radius > parameters_.catheter_radius))
    throw std::invalid_argument("vessel contact: the lumen must be wider than the catheter");
  if (!(parameters_.wall_stiffness > 0))
    throw std::invalid_argument("vessel contact: wall_stiffness must be > 0");
  if (parameters_.points_per_segment < 2 || parameters_.points_per_segment > 64)
    throw std::invalid_argument("vessel contact: points_per_segment must be 2..64");
  backbone_.resize(shape_.backbone_point_count(parameters_.points_per_segment));
}

double CatheterVesselContact::distance_to_centerline(const Eigen::Vector3d& p) const noexcept {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < centerline_.size(); ++i) {
    const Eigen::Vector3d a = centerline_[i], ab = centerline_[i + 1] - a;
    const double len2 = ab.squaredNorm();
    const double u = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
    best = std::min(best, (a + u * ab - p).squaredNorm());
  }
  return std::sqrt(best);
}

double CatheterVesselContact::energy(const Eigen::Vector4d& q, ContactForces* stats) noexcept {
  const std::size_t n = shape_.backbone(q, parameters_.points_per_segment, backbone_);
  const double free = parameters_.lumen_radius - parameters_.catheter_radius;
  const double k = parameters_.wall_stiffness;
  double e = 0.0;
  for (std::size_t i = 1; i < n; ++i) {  // the base point sits on the insertion axis, outside the model
    const double d = distance_to_centerline(backbone_[i]) - free;
    if (d <= 0) continue;
    e += 0.5 * k * d * d;
    if (stats) {
      stats->total_force += k * d;
      stats->max_force = std::max(stats->max_force, k * d);
      ++stats->points_in_contact;
    }
  }
  return e;
}

ContactForces CatheterVesselContact::evaluate(const Eigen::Vector4d& q) noexcept {
  ContactForces out;
  (void)energy(q, &out);
  if (out.points_in_contact == 0) return out;
  // Central differences: 0.01 mm (or rad) is far below the contact's length scale.
  constexpr double h = 1e-2;
  for (int j = 0; j < 4; ++j) {
    Eigen::Vector4d plus = q, minus = q;
    plus[j] += h;
    minus[j] -= h;
    out.generalised[static_cast<std::size_t>(j)] = -(energy(plus) - energy(minus)) / (2.0 * h);
  }
  return out;
}

double tip_bend(const teleop::ModalCatheterKinematics& shape, const Eigen::Vector4d& q) noexcept {
  const auto pose = shape.tip_pose(q);
  const double c = std::clamp(pose.rotation.col(2).dot(Eigen::Vector3d::UnitZ()), -1.0, 1.0);
  return std::acos(c);
}

std::vector<Eigen::Vector3d> arc_channel(double lead_in, double bend_radius, double turn_rad, double step) {
  if (!(lead_in >= 0) || !(bend_radius > 0) || !(turn_rad > 0) || !(step > 0))
    throw std::invalid_argument("arc channel: lead-in >= 0, radius, turn and step > 0");
  std::vector<Eigen::Vector3d> points;
  const int straight = static_cast<int>(std::ceil(lead_in / step));
  const int n = std::max(2, static_cast<int>(std::ceil(turn_rad * bend_radius / step)));
  points.reserve(static_cast<std::size_t>(straight) + static_cast<std::size_t>(n) + 1);
  for (int i = 0; i < straight; ++i) points.emplace_back(0.0, 0.0, lead_in * i / straight);
  for (int i = 0; i <= n; ++i) {
    const double a = turn_rad * i / n;
    points.emplace_back(bend_radius * (1.0 - std::cos(a)), 0.0, lead_in + bend_radius * std::sin(a));
  }
  return points;
}

}  // namespace tendril::sim
