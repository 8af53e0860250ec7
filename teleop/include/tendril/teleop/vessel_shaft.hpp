// VesselShaft: the catheter's passive shaft lying along a vessel (issue 31). The part of the catheter
// proximal to the steerable segments is elastic and, pushed into a vessel, lies along the vessel's
// centerline — the placement the path planner assumes (shape_error_planner.hpp): the steerable
// section's base sits on the centerline at arc length s_b = q1 − (L1 + L2) from the vessel's start
// (the entry point, where the tip is at zero insertion), oriented by a rotation-minimising
// (parallel-transport) frame started at the entry's frame; the roll q2 turns the steerable section
// about that frame's z axis (the shaft carries the roll from the drive, torsionally stiff). Before the
// entry (s_b ≤ 0) the base runs straight along the entry's axis (an introducer); past the vessel's end
// it goes straight on along the last tangent.
//
// Assumptions (Abah 2022 is silent, chosen here): the shaft follows the centerline exactly (no slack,
// no buckling, no lateral offset inside the lumen, no friction), so it feels no wall force and the wall
// acts on the steerable segments only; the whole insertion advances the base along the vessel.
//
// Immutable after construction; every query is const, noexcept and allocation-free.
#pragma once

#include <Eigen/Core>
#include <span>
#include <vector>

#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop {

class VesselShaft {
 public:
  // `vessel`: the centerline in the catheter's frame {0}, starting at the entry point (where the tip is
  // at zero insertion); `steerable_length` = L1 + L2 (mm); ds: resampling step. Throws VesselInputError
  // for an unusable polyline and std::invalid_argument for a non-positive length.
  VesselShaft(const CenterlinePolyline& vessel, double steerable_length, double ds = 0.5);

  double steerable_length() const noexcept { return steerable_length_; }
  double vessel_length() const noexcept { return vessel_.length(); }
  const VesselCenterline& vessel() const noexcept { return vessel_; }

  // Pose of the steerable section's base (rotation columns x, y, z = tangent; before the roll) in
  // frame {0} at insertion q1.
  void section_base(double q1, Eigen::Matrix3d& rotation, Eigen::Vector3d& position) const noexcept;
  // The shaft's point `back` mm proximal of the steerable base at insertion q1 (for drawing).
  Eigen::Vector3d shaft_point(double q1, double back) const noexcept;
  // Moves points given with the steerable base at the origin (insertion 0, frame {0}'s axes) onto the
  // shaft's base at insertion q1: p ↦ position + rotation·p.
  void place(double q1, std::span<Eigen::Vector3d> points) const noexcept;

 private:
  // Base pose at arc length s from the entry (any real s).
  void pose_at(double s, Eigen::Matrix3d& rotation, Eigen::Vector3d& position) const noexcept;

  VesselCenterline vessel_;
  double steerable_length_;
  std::vector<Eigen::Matrix3d> transport_;
};

}  // namespace tendril::teleop
