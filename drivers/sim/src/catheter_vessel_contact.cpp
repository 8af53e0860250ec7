#include "tendril/drivers/sim/catheter_vessel_contact.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace tendril::sim {

namespace {
constexpr std::size_t kSegmentsPerGroup = 8;
// Central-difference step of the bend actuations (mm): far below the contact's length scale.
constexpr double kBendStep = 1e-2;
}  // namespace

CatheterVesselContact::CatheterVesselContact(std::vector<Eigen::Vector3d> centerline,
                                             const teleop::ModalCatheterParameters& shape,
                                             CatheterVesselContactParameters parameters)
    : centerline_(std::move(centerline)), shape_(shape), parameters_(std::move(parameters)) {
  if (centerline_.size() < 2)
    throw std::invalid_argument("vessel contact: the centerline needs at least 2 points");
  for (const auto& p : centerline_)
    if (!p.allFinite()) throw std::invalid_argument("vessel contact: a centerline point is not finite");
  if (!(parameters_.catheter_radius > 0) || !(parameters_.lumen_radius > parameters_.catheter_radius))
    throw std::invalid_argument("vessel contact: the lumen must be wider than the catheter");
  if (!parameters_.lumen_radii.empty()) {
    if (parameters_.lumen_radii.size() != centerline_.size())
      throw std::invalid_argument("vessel contact: " + std::to_string(parameters_.lumen_radii.size()) +
                                  " lumen radii for " + std::to_string(centerline_.size()) +
                                  " centerline points");
    for (std::size_t i = 0; i < centerline_.size(); ++i) {
      if (!(parameters_.lumen_radii[i] > parameters_.catheter_radius))
        throw std::invalid_argument("vessel contact: the lumen radius at centerline point " +
                                    std::to_string(i) + " is not wider than the catheter");
    }
  }
  if (!(parameters_.wall_stiffness > 0))
    throw std::invalid_argument("vessel contact: wall_stiffness must be > 0");
  if (parameters_.points_per_segment < 2 || parameters_.points_per_segment > 64)
    throw std::invalid_argument("vessel contact: points_per_segment must be 2..64");
  const std::size_t segments = centerline_.size() - 1;
  for (std::size_t first = 0; first < segments; first += kSegmentsPerGroup) {
    SegmentGroup g;
    g.first = first;
    g.last = std::min(segments, first + kSegmentsPerGroup);
    Eigen::Vector3d lo = centerline_[first], hi = lo;
    for (std::size_t i = first; i <= g.last; ++i) {
      lo = lo.cwiseMin(centerline_[i]);
      hi = hi.cwiseMax(centerline_[i]);
    }
    g.centre = 0.5 * (lo + hi);
    for (std::size_t i = first; i <= g.last; ++i)
      g.radius = std::max(g.radius, (centerline_[i] - g.centre).norm());
    groups_.push_back(g);
  }
  const std::size_t n = shape_.backbone_point_count(parameters_.points_per_segment);
  backbone_.resize(n);
  for (auto& b : perturbed_) b.resize(n);
  nearest_.assign(n, 0);
}

Eigen::Vector3d CatheterVesselContact::point_on_segment(std::size_t i,
                                                        const Eigen::Vector3d& p) const noexcept {
  const Eigen::Vector3d& a = centerline_[i];
  const Eigen::Vector3d ab = centerline_[i + 1] - a;
  const double len2 = ab.squaredNorm();
  const double u = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return a + u * ab;
}

double CatheterVesselContact::free_at(std::size_t i, const Eigen::Vector3d& nearest) const noexcept {
  const auto& radii = parameters_.lumen_radii;
  if (radii.empty()) return parameters_.lumen_radius - parameters_.catheter_radius;
  const double length = (centerline_[i + 1] - centerline_[i]).norm();
  const double u = length > 0 ? std::clamp((nearest - centerline_[i]).norm() / length, 0.0, 1.0) : 0.0;
  return (1.0 - u) * radii[i] + u * radii[i + 1] - parameters_.catheter_radius;
}

Eigen::Vector3d CatheterVesselContact::nearest_point(const Eigen::Vector3d& p,
                                                     std::size_t& segment) const noexcept {
  const std::size_t segments = centerline_.size() - 1;
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d nearest = centerline_.front();
  const auto consider = [&](std::size_t i) {
    const Eigen::Vector3d c = point_on_segment(i, p);
    const double d2 = (c - p).squaredNorm();
    if (d2 < best) {
      best = d2;
      nearest = c;
      segment = i;
    }
  };
  // Warm start: last tick's nearest segment and its neighbours make `best` tight at once.
  const std::size_t hint = std::min(segment, segments - 1);
  for (std::size_t i = hint > 2 ? hint - 2 : 0; i < std::min(segments, hint + 3); ++i) consider(i);
  // Exact: every other segment lies in a group whose bounding sphere is no nearer than `best`.
  for (const auto& g : groups_) {
    const double lower = (p - g.centre).norm() - g.radius;
    if (lower > 0 && lower * lower >= best) continue;
    for (std::size_t i = g.first; i < g.last; ++i) consider(i);
  }
  return nearest;
}

double CatheterVesselContact::distance_to_centerline(const Eigen::Vector3d& p) const noexcept {
  std::size_t segment = 0;
  return (nearest_point(p, segment) - p).norm();
}

std::size_t CatheterVesselContact::backbone(const Eigen::Vector4d& q,
                                            std::span<Eigen::Vector3d> out) const noexcept {
  if (!shaft_) return shape_.backbone(q, parameters_.points_per_segment, out);
  // The steerable section drawn at the origin with its roll, then placed on the shaft's base.
  const std::size_t n =
      shape_.backbone(Eigen::Vector4d(0.0, q[1], q[2], q[3]), parameters_.points_per_segment, out);
  shaft_->place(q[0], out.first(n));
  return n;
}

double CatheterVesselContact::energy(const Eigen::Vector4d& q, ContactForces* stats) noexcept {
  const std::size_t n = backbone(q, backbone_);
  const double k = parameters_.wall_stiffness;
  double e = 0.0;
  for (std::size_t i = 1; i < n; ++i) {  // the base point sits on the insertion axis, outside the model
    const Eigen::Vector3d nearest = nearest_point(backbone_[i], nearest_[i]);
    const double d = (nearest - backbone_[i]).norm() - free_at(nearest_[i], nearest);
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
  const std::size_t n = backbone(q, backbone_);
  const double k = parameters_.wall_stiffness;
  bool have_bend_rates = false;
  // With a shaft: the base on the centerline and its tangent (the roll axis there).
  Eigen::Matrix3d base_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d base_position = Eigen::Vector3d::Zero();
  if (shaft_) shaft_->section_base(q[0], base_rotation, base_position);
  const Eigen::Vector3d roll_axis = base_rotation.col(2);
  for (std::size_t i = 1; i < n; ++i) {  // the base point sits on the insertion axis, outside the model
    const Eigen::Vector3d& p = backbone_[i];
    const Eigen::Vector3d nearest = nearest_point(p, nearest_[i]);
    const Eigen::Vector3d outward = p - nearest;
    const double distance = outward.norm();
    const double d = distance - free_at(nearest_[i], nearest);
    if (d <= 0) continue;    // distance > free > 0 from here on
    if (!have_bend_rates) {  // only in contact: four more backbones
      for (std::size_t j = 0; j < (shaft_ ? 6u : 4u); ++j) {
        Eigen::Vector4d qj = q;
        // j = 0..3: the bends; 4, 5: the insertion (only on a shaft, where it is not a translation).
        const auto axis = static_cast<Eigen::Index>(j < 4 ? 2 + j / 2 : 0);
        qj[axis] += j % 2 == 0 ? kBendStep : -kBendStep;
        (void)backbone(qj, perturbed_[j]);
      }
      have_bend_rates = true;
    }
    // E = Σ ½·k·d², ∂d/∂p = n: Q_j = −k·d·nᵀ·∂p/∂q_j.
    const Eigen::Vector3d push = -k * d / distance * outward;
    if (shaft_) {
      out.generalised[0] += push.dot(perturbed_[4][i] - perturbed_[5][i]) / (2.0 * kBendStep);
      out.generalised[1] += push.dot(roll_axis.cross(p - base_position));  // a turn about the base's tangent
    } else {
      out.generalised[0] += push.z();                                     // ∂p/∂q1 = ẑ
      out.generalised[1] += push.dot(Eigen::Vector3d::UnitZ().cross(p));  // ∂p/∂q2 = ẑ × p
    }
    out.generalised[2] += push.dot(perturbed_[0][i] - perturbed_[1][i]) / (2.0 * kBendStep);
    out.generalised[3] += push.dot(perturbed_[2][i] - perturbed_[3][i]) / (2.0 * kBendStep);
    out.total_force += k * d;
    out.max_force = std::max(out.max_force, k * d);
    ++out.points_in_contact;
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
