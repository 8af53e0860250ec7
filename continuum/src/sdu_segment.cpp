#include "tendril/continuum/sdu_segment.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::continuum {

namespace {
void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("SDU segment model: " + what);
}
}  // namespace

void SduSegmentModel::validate() const {
  require(std::isfinite(length_mm) && length_mm > 0.0, "length_mm must be a positive finite length");
  require(std::isfinite(disk_radius_mm) && disk_radius_mm > 0.0,
          "disk_radius_mm must be positive and finite");
  double previous = 0.0;
  for (std::size_t i = 0; i < kSdusPerSegment; ++i) {
    const double s = disk_arc_mm[i];
    require(std::isfinite(s) && s > previous && s <= length_mm,
            "disk_arc_mm[" + std::to_string(i) + "] = " + std::to_string(s) +
                " must increase strictly within (0, length_mm]");
    previous = s;
  }
  require(std::isfinite(slot_pitch_rad) && slot_pitch_rad > 0.0, "slot_pitch_rad must be positive");
  require(std::isfinite(max_bending_rad) && max_bending_rad > 0.0 && max_bending_rad <= M_PI,
          "max_bending_rad must lie in (0, pi]");
}

Eigen::Isometry3d backbone_pose(const SduSegmentModel& model, const SegmentConfiguration& q,
                                double s) noexcept {
  const double kappa = q.bending_rad / model.length_mm;
  const double angle = kappa * s;
  // In the bending plane (x'z): the arc from the origin, tangent z at s = 0.
  Eigen::Vector3d p_plane;
  if (std::abs(kappa) < 1e-12) {
    p_plane = {0.0, 0.0, s};
  } else {
    // 1 − cos a = 2 sin²(a/2): no cancellation for the nearly straight segment.
    const double half = std::sin(0.5 * angle);
    p_plane = {2.0 * half * half / kappa, 0.0, std::sin(angle) / kappa};
  }
  const Eigen::AngleAxisd roll(q.stage_roll_rad, Eigen::Vector3d::UnitZ());
  const Eigen::AngleAxisd plane(q.bending_plane_rad, Eigen::Vector3d::UnitZ());
  const Eigen::AngleAxisd bend(angle, Eigen::Vector3d::UnitY());
  const Eigen::AngleAxisd unplane(-q.bending_plane_rad, Eigen::Vector3d::UnitZ());
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = (roll * plane * bend * unplane).toRotationMatrix();
  pose.translation() = roll * (plane * p_plane);
  return pose;
}

Eigen::Isometry3d disk_pose(const SduSegmentModel& model, const SegmentConfiguration& q,
                            std::size_t disk) noexcept {
  return backbone_pose(model, q, model.disk_arc_mm[disk < kSdusPerSegment ? disk : kSdusPerSegment - 1]);
}

std::array<Eigen::Isometry3d, kSdusPerSegment> disk_poses(const SduSegmentModel& model,
                                                          const SegmentConfiguration& q) noexcept {
  std::array<Eigen::Isometry3d, kSdusPerSegment> out;
  for (std::size_t i = 0; i < kSdusPerSegment; ++i) out[i] = disk_pose(model, q, i);
  return out;
}

double tof_slot_angle(const SduSegmentModel& model, std::size_t slot) noexcept {
  return model.tof_slot0_rad + static_cast<double>(slot) * model.slot_pitch_rad;
}

double hall_slot_angle(const SduSegmentModel& model, std::size_t slot) noexcept {
  return model.hall_slot0_rad + static_cast<double>(slot) * model.slot_pitch_rad;
}

Eigen::Isometry3d tof_sensor_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept {
  const double a = tof_slot_angle(model, slot);
  const Eigen::Vector3d radial(std::cos(a), std::sin(a), 0.0);
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d::UnitZ();  // x along the backbone
  r.col(2) = radial;                    // z the line of sight
  r.col(1) = r.col(2).cross(r.col(0));  // right-handed
  Eigen::Isometry3d h = Eigen::Isometry3d::Identity();
  h.linear() = r;
  h.translation() = model.disk_radius_mm * radial;
  return h;
}

Eigen::Vector3d hall_normal_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept {
  const double a = hall_slot_angle(model, slot);
  return {std::cos(a), std::sin(a), 0.0};
}

Eigen::Vector3d hall_point_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept {
  return model.disk_radius_mm * hall_normal_in_disk(model, slot);
}

Eigen::Isometry3d disk_pose_from_tracker(const Eigen::Isometry3d& camera_T_base,
                                         const Eigen::Isometry3d& camera_T_marker,
                                         const Eigen::Isometry3d& marker_T_disk) noexcept {
  return camera_T_base.inverse() * camera_T_marker * marker_T_disk;
}

Eigen::Vector3d tip_position_per_bending(const SduSegmentModel& model,
                                         const SegmentConfiguration& q) noexcept {
  // Central difference: the closed form has a removable singularity at θ = 0.
  constexpr double h = 1e-6;
  SegmentConfiguration a = q, b = q;
  a.bending_rad -= h;
  b.bending_rad += h;
  return (backbone_pose(model, b, model.length_mm).translation() -
          backbone_pose(model, a, model.length_mm).translation()) /
         (2.0 * h);
}

}  // namespace tendril::continuum
