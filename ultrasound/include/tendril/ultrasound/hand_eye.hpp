// Robot–world and hand–eye calibration at once (Heunis et al. 2021, §2.3): the arm holds a marker rigid
// body that the optical tracker sees; at K poses the tracker reports the marker in the global frame {G},
// A_k = H_M^G, and the arm's forward kinematics gives the probe in its base frame {B}, F_k = H_U^B. With
// the unknown marker→probe transform X = H_U^M and base→global Y = H_B^G the probe's pose in {G} is, both
// ways round,
//
//     A_k X = Y F_k        (the AX = YB problem).
//
// Solved in three steps:
//  1. rotation of X (Park & Martin 1994): every pair of poses (i, j) gives a relative motion
//     A_ij X = X F_ij with A_ij = A_j⁻¹ A_i, F_ij = F_j⁻¹ F_i; the log vectors α = log R_A, β = log R_F
//     satisfy α = R_X β. Park–Martin's R_X = (MᵀM)^{-1/2} Mᵀ (M = Σ β αᵀ) needs axes in all three
//     directions; we take the same least squares in its orthogonal-Procrustes form (R_X = U diag(1, 1,
//     det) Vᵀ from the SVD of Σ α βᵀ), equal to it then and still defined when the axes span a plane.
//     Then R_Y = the rotation nearest to Σ R_Ak R_X R_Fkᵀ;
//  2. translations by linear least squares: R_Ak t_X − t_Y = R_Y t_Fk − t_Ak (3K equations, 6 unknowns);
//  3. Gauss–Newton on all twelve parameters (X and Y each perturbed on the right by exp of a twist),
//     residual per pose = the probe's position in {G} both ways (mm) and the rotation between the two
//     (rad, weighted by `rotation_weight_mm_per_rad`).
//
// Refusals (ok = false, a sentence in `message`): fewer than `min_pairs` poses, a pose that is not finite
// or not rigid, or too little rotation spread — the relative rotations must turn about at least two
// well-separated axes, else R_X is not determined (measured as the second-largest eigenvalue of
// Σ β βᵀ / n, whose square root must reach `min_rotation_spread_rad`).
//
// Pure computation; allocates (not for the control thread). Units: mm, rad.
#pragma once

#include <span>
#include <string>

#include <Eigen/Geometry>

namespace tendril::ultrasound {

struct HandEyePair {
  Eigen::Isometry3d tracked;    // A_k = H_M^G, the marker in the global (tracker) frame
  Eigen::Isometry3d kinematic;  // F_k = H_U^B, the probe in the arm's base frame (forward kinematics)
};

struct HandEyeOptions {
  int min_pairs = 10;
  double min_rotation_spread_rad = 0.05;
  int gauss_newton_iterations = 5;
  // A rotation residual of 1 rad counts as this many mm: the ratio of the tracker's noise per axis in
  // position and in rotation (0.56 mm / √3 ≈ 0.32 mm against 0.02° ≈ 0.00035 rad gives ~900), so that each
  // part of a pose weighs by how well it is measured. With 100 mm/rad the position noise dragged H_B^G's
  // rotation by up to 0.6° (3.8 mm at the limb) in the tests.
  double rotation_weight_mm_per_rad = 1000.0;
};

struct HandEyeResult {
  bool ok = false;
  std::string message;                                               // why not, or a one-line summary
  Eigen::Isometry3d world_T_base = Eigen::Isometry3d::Identity();    // Y = H_B^G
  Eigen::Isometry3d marker_T_probe = Eigen::Isometry3d::Identity();  // X = H_U^M
  int pairs = 0;
  int iterations = 0;              // Gauss–Newton iterations run
  double rotation_spread_rad = 0;  // the spread measure above
  // Residuals over the poses, after the solve: |p(A_k X) − p(Y F_k)| and the angle between the two.
  double rms_position_mm = 0, max_position_mm = 0;
  double rms_rotation_rad = 0, max_rotation_rad = 0;
  double closed_form_rms_position_mm = 0;  // before Gauss–Newton
};

HandEyeResult solve_hand_eye(std::span<const HandEyePair> pairs, const HandEyeOptions& options = {});

}  // namespace tendril::ultrasound
