// The artery model built from ultrasound (US) slices and the catheter–wall contacts (Heunis et al. 2021,
// §3.3):
//   * Eq. 5 (read as a point set, with the probe's forward kinematics at the acquisition time):
//     Λ_G = H_B^G · H_U^B(t_acq) · H_I^U · Λ_US; the caller composes the chain into one image pose and
//     may append (H_P^G(t_acq))⁻¹ for the motion-stabilised tissue frame {P};
//   * consecutive contours lofted into a triangle mesh (teleop::TriangleMesh, the vessel mesh type the
//     planner already reads): 2N triangles per pair of slices, contour point q joined to point q of the
//     next slice (the rays start at the same angle in every image, so the contours do not twist);
//   * contacts: the distance of each FBG sensor to the mesh (exact point-to-triangle), flagged under
//     r_catheter + margin = 1.25 mm (Fig. 7d).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

#include "tendril/teleop/vessel_mesh.hpp"
#include "tendril/ultrasound/ellipse_ekf.hpp"

namespace tendril::ultrasound {

struct ReconstructedSlice {
  std::vector<Eigen::Vector3d> contour;                // Λ in the target frame
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();  // ψ in the target frame
};

// Eq. 5 for one segmented slice: [0, y, z] of each contour point and of the centre through `image_pose`
// (the image frame {I} in the target frame). Throws std::invalid_argument for an invalid segmentation.
ReconstructedSlice map_slice(const SliceSegmentation& segmentation, const Eigen::Isometry3d& image_pose);

// Lofts the slices in acquisition order. Throws std::invalid_argument for fewer than 2 slices or
// contours of different or fewer than 3 points.
teleop::TriangleMesh loft_artery_mesh(const std::vector<ReconstructedSlice>& slices);

// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5).
Eigen::Vector3d closest_point_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                          const Eigen::Vector3d& b, const Eigen::Vector3d& c) noexcept;
// Unsigned distance from p to the nearest triangle; +∞ for a mesh without triangles.
double distance_to_mesh(const teleop::TriangleMesh& mesh, const Eigen::Vector3d& p) noexcept;

struct CatheterContactParameters {
  double catheter_radius = 1.0;  // mm (D_c = 2 mm, Heunis et al. 2021, §2.2)
  double margin = 0.25;          // mm: 1 + 0.25 = the paper's 1.25 mm threshold (§4.2)
  double threshold() const noexcept { return catheter_radius + margin; }
};

struct CatheterContact {
  int sensor = 0;                                      // grating index
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // in the mesh's frame
  double distance = 0.0;                               // to the wall (mm)
};

// The sensors closer to the wall than the threshold, in sensor order, into `contacts` (cleared first).
// `distances` (resized to sensors.size()) receives every sensor's distance.
void find_contacts(const teleop::TriangleMesh& wall, const std::vector<Eigen::Vector3d>& sensors,
                   const CatheterContactParameters& parameters, std::vector<CatheterContact>& contacts,
                   std::vector<double>& distances);

}  // namespace tendril::ultrasound
