// SIMULATED contact of the steerable catheter with a vessel wall: the vessel is a tube (centerline
// polyline in the catheter's frame {0}, mm, and a lumen radius, constant or per point); the catheter's
// backbone comes from its assembled shape model at the actuation that reaches the tubes (insertion, roll,
// proximal carriage, effective distal actuation). A backbone point whose distance from the centerline plus
// the catheter radius exceeds the lumen penetrates the wall by d and stores ½·k_wall·d² of elastic
// energy. The generalised wall forces are Q = −∂E/∂q = −Σ k·d_i·n_iᵀ·∂p_i/∂q (n_i the outward unit
// normal from the nearest centerline point), i.e. what a compliant wall pushes back with through the
// catheter's kinematics: ∂p/∂q is exact for insertion (a translation along z) and roll (a rotation
// about the insertion axis) and a central difference of the backbone for the two bend actuations.
// Distances come from a pruned search: the previous tick's nearest segment bounds the answer, and
// groups of consecutive segments whose bounding sphere lies farther away are skipped, so a point
// costs a few segment projections instead of the whole centerline (it runs 1000 times a second).
// Allocation-free after construction; one instance per plant (it keeps scratch buffers).
// With a shaft (set_shaft, issue 31) the steerable section starts where the passive shaft lying along
// the vessel puts it (teleop::VesselShaft: on the centerline at q1 − (L1 + L2), the vessel's local
// tangent) instead of at (0, 0, q1) on a straight axis; ∂p/∂q1 is then a central difference too and
// ∂p/∂q2 a rotation about the base's tangent. The shaft itself lies on the centerline: no wall force.
#pragma once

#include <array>
#include <cstddef>
#include <span>
#include <vector>

#include <Eigen/Core>

#include <optional>
#include "tendril/teleop/modal_catheter_kinematics.hpp"
#include "tendril/teleop/vessel_shaft.hpp"

namespace tendril::sim {

struct CatheterVesselContactParameters {
  double lumen_radius = 1.5875;  // mm: the dissertation's phantom tubing, ID 3.175 mm
  // Lumen radius at each centerline point (mm), e.g. a vessel file's r column; empty = lumen_radius
  // everywhere. Between points it is interpolated along the nearest segment. The wall force keeps the
  // direction of the normal: the slope of the radius along the vessel is neglected in ∂d/∂p.
  std::vector<double> lumen_radii;
  double catheter_radius = 0.6;  // mm: 1.2 mm outer tube
  double wall_stiffness = 1.0;   // N/mm per backbone point in contact
  std::size_t points_per_segment = 8;
};

struct ContactForces {
  // Generalised forces on [insertion (N), roll (N·mm), proximal carriage (N), distal actuation (N)].
  std::array<double, 4> generalised{};
  double total_force = 0.0;  // Σ k·d over the points in contact (N)
  double max_force = 0.0;    // largest single point force (N)
  int points_in_contact = 0;
};

class CatheterVesselContact {
 public:
  // Throws std::invalid_argument (via SimulationSetupError's base) for fewer than 2 centerline points,
  // non-finite values, a lumen not wider than the catheter, or a non-positive stiffness.
  CatheterVesselContact(std::vector<Eigen::Vector3d> centerline, const teleop::ModalCatheterParameters& shape,
                        CatheterVesselContactParameters parameters);

  // q = [insertion mm, roll rad, proximal carriage mm, effective distal actuation mm].
  ContactForces evaluate(const Eigen::Vector4d& q) noexcept;
  // Wall energy at q (N·mm); also used by evaluate() for the differences.
  double energy(const Eigen::Vector4d& q, ContactForces* stats = nullptr) noexcept;

  // Set-up, before evaluating: the passive shaft follows this vessel (see above).
  void set_shaft(teleop::VesselShaft shaft) { shaft_.emplace(std::move(shaft)); }
  const std::optional<teleop::VesselShaft>& shaft() const noexcept { return shaft_; }
  // The backbone the contact uses at q (straight axis or on the shaft); returns the points written.
  std::size_t backbone(const Eigen::Vector4d& q, std::span<Eigen::Vector3d> out) const noexcept;

  const teleop::ModalCatheterKinematics& shape() const noexcept { return shape_; }
  const std::vector<Eigen::Vector3d>& centerline() const noexcept { return centerline_; }
  const CatheterVesselContactParameters& parameters() const noexcept { return parameters_; }
  // Distance (mm) from p to the centerline polyline (exact; the pruned search).
  double distance_to_centerline(const Eigen::Vector3d& p) const noexcept;

 private:
  // Consecutive centerline segments [first, last) inside a sphere: a lower bound on their distance.
  struct SegmentGroup {
    Eigen::Vector3d centre;
    double radius = 0.0;
    std::size_t first = 0, last = 0;
  };
  // Nearest point on the polyline to p; `segment` is a hint (any valid index) and returns the
  // nearest segment.
  Eigen::Vector3d nearest_point(const Eigen::Vector3d& p, std::size_t& segment) const noexcept;
  Eigen::Vector3d point_on_segment(std::size_t i, const Eigen::Vector3d& p) const noexcept;
  // Room between the catheter and the wall at `nearest` on segment i: lumen radius − catheter radius.
  double free_at(std::size_t i, const Eigen::Vector3d& nearest) const noexcept;

  std::vector<Eigen::Vector3d> centerline_;
  std::vector<SegmentGroup> groups_;
  teleop::ModalCatheterKinematics shape_;
  CatheterVesselContactParameters parameters_;
  std::vector<Eigen::Vector3d> backbone_;  // scratch, sized at construction
  // Backbones at q3 + h, q3 − h, q4 + h, q4 − h: ∂p/∂q of the bends by central differences.
  // With a shaft also at q1 + h, q1 − h.
  std::array<std::vector<Eigen::Vector3d>, 6> perturbed_;
  std::optional<teleop::VesselShaft> shaft_;
  std::vector<std::size_t> nearest_;  // per backbone point: last nearest segment (warm start)
};

// Bend of the catheter tip relative to its base axis (rad), from the assembled shape at q.
double tip_bend(const teleop::ModalCatheterKinematics& shape, const Eigen::Vector4d& q) noexcept;

// A channel for experiments: straight along +z from the origin for lead_in mm, then a circular arc
// of bend_radius turning by turn_rad toward +x, sampled about every step mm.
std::vector<Eigen::Vector3d> arc_channel(double lead_in, double bend_radius, double turn_rad,
                                         double step = 0.5);

}  // namespace tendril::sim
