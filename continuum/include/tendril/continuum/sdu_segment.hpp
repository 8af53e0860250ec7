// The SDU continuum segment (Abah 2022, §3.5): one constant-curvature continuum segment (CS) on a
// rotary stage coaxial with its backbone, carrying sensing disk units (SDU) — each a spacer disk with 8
// time-of-flight (ToF) range sensors and 8 three-axis Hall sensors under a silicone sleeve.
//
// Frames (all poses are Eigen::Isometry3d, millimetres):
//   {0}  base: origin on the backbone where the segment leaves the rotary stage, z along the straight
//        backbone. The stage rolls the whole segment about z.
//   {d_i} disk i: origin on the backbone at arc length s_i, z along the backbone tangent, x towards
//        angular slot 0°. Constant curvature without torsion (Webster & Jones): ⁰R_d = Rz(roll)·Rz(δ)·
//        Ry(θ·s/L)·Rz(−δ), so a straight segment's disks all share {0}'s orientation (after the roll).
//   {s}  a ToF sensor's top surface: origin on the disk rim at its slot angle, z its line of sight
//        (radially outward), x along the disk's z. A range d is the point ⁰H_s·[0, 0, d, 1]ᵀ — the
//        the dissertation's chain (3.7) with the axis it leaves unstated.
// Angles: θ bending angle (0 = straight; the tip tangent turns by θ), δ bending-plane angle about z
// from x of the rolled base, roll the stage angle. Slots: ToF j at tof_slot0 + j·45°, Hall j at
// hall_slot0 + j·45° (interleaved; a half-disk carries 4 of each as in the dissertation).
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cstddef>
#include <cstdint>

namespace tendril::continuum {

inline constexpr std::size_t kSdusPerSegment = 5;
inline constexpr std::size_t kTofPerSdu = 8;
inline constexpr std::size_t kHallPerSdu = 8;

struct SduSegmentModel {
  double length_mm = 370.0;      // Abah 2022, §3.5
  double disk_radius_mm = 79.0;  // OD 158 mm, the sleeve's outer surface
  // Arc length of each disk along the backbone. The dissertation gives only 5 SDUs on a 370 mm segment
  // "separated by metallic bellows"; tendril spaces them evenly with the last one at the tip.
  std::array<double, kSdusPerSegment> disk_arc_mm{74.0, 148.0, 222.0, 296.0, 370.0};
  double tof_slot0_rad = 0.0;
  double hall_slot0_rad = 0.39269908169872414;  // 22.5°: between two ToF windows
  double slot_pitch_rad = 0.78539816339744831;  // 45°
  double max_bending_rad = 1.5707963267948966;  // 90°, a safe bound for a 370 mm wire-driven segment

  // Throws std::invalid_argument naming the field when a length is not positive and finite, the disks
  // are not strictly increasing within (0, length], or the bending bound is not in (0, π].
  void validate() const;
};

struct SegmentConfiguration {
  double stage_roll_rad = 0.0;
  double bending_rad = 0.0;        // θ ≥ 0
  double bending_plane_rad = 0.0;  // δ
};

// Pose of the backbone frame at arc length s (0 ≤ s ≤ L) in {0}.
Eigen::Isometry3d backbone_pose(const SduSegmentModel& model, const SegmentConfiguration& q,
                                double s_mm) noexcept;
// ⁰H_d of disk i (i < kSdusPerSegment).
Eigen::Isometry3d disk_pose(const SduSegmentModel& model, const SegmentConfiguration& q,
                            std::size_t disk) noexcept;
// All disk poses at once.
std::array<Eigen::Isometry3d, kSdusPerSegment> disk_poses(const SduSegmentModel& model,
                                                          const SegmentConfiguration& q) noexcept;

double tof_slot_angle(const SduSegmentModel& model, std::size_t slot) noexcept;
double hall_slot_angle(const SduSegmentModel& model, std::size_t slot) noexcept;
// ᵈH_s of ToF slot j (constant, the CAD transform of the dissertation's chain).
Eigen::Isometry3d tof_sensor_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept;
// Outward unit normal of Hall slot j and its point on the sleeve's surface, in the disk frame.
Eigen::Vector3d hall_normal_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept;
Eigen::Vector3d hall_point_in_disk(const SduSegmentModel& model, std::size_t slot) noexcept;

// The dissertation's optical-tracker chain (3.7) up to the disk: ⁰H_d = (ᶜH₀)⁻¹·ᶜH_m·ᵐH_d, with ᶜH₀ the base
// marker and ᶜH_m the disk's marker as the tracker sees them, ᵐH_d from CAD. Use it in place of the
// kinematic disk pose when a tracker is fitted.
Eigen::Isometry3d disk_pose_from_tracker(const Eigen::Isometry3d& camera_T_base,
                                         const Eigen::Isometry3d& camera_T_marker,
                                         const Eigen::Isometry3d& marker_T_disk) noexcept;

// The tip position's derivative with respect to θ (mm/rad), for turning a tip speed into a bending rate.
Eigen::Vector3d tip_position_per_bending(const SduSegmentModel& model,
                                         const SegmentConfiguration& q) noexcept;

}  // namespace tendril::continuum
