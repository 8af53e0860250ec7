// Pre-operative planning of the ultrasound (US) sweep (Heunis et al. 2021, §2.4): the CT → tissue-frame {P}
// registration on the calibration stick (ICP, Besl–McKay), Algorithm 1 (arterial centroids Ψ_CT from
// the CT vessel-wall cloud) and Algorithm 2 (probe via-point poses on the skin surface cloud), with the
// corrections applied to the article's Algorithms 1–2:
//   - points sorted by x as rows, and only those with x_start ≤ x ≤ p_d,x enter the fit (the paper
//       left ς = 0 past the endpoint yet fitted all m rows);
//   - the parameter is v = (x − x_min)/L ∈ [0, 1] (not raw x, whose 4th power is ~2.4e8 at 125 mm)
//       and the quartic is solved by QR; the centroids are evenly spaced in x, as the paper's;
//   - three rows per rotation block (k += 3) — here simply one rotation per via-point;
//   - the rotation holds the probe axes as columns, so pose() maps probe coordinates into {P};
//   - the last via-point reuses the previous sweep direction; the cross products absorb a surface
//       step that is not horizontal;
//   and our reading of Algorithm 2: only surface points above the centroid are candidates, and the surface
//   point is the mean of the k nearest to the vertical line (k = 1 is the paper's argmin).
// Units: millimetres. {P}: y is the tissue's "up" (Algorithm 2), the vessel runs roughly along x.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <stdexcept>
#include <vector>

namespace tendril::ultrasound {

// Thrown for planning input that cannot give a plan (too few points, non-finite values, bad counts).
class PlanningInputError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Least-squares rigid transform T (rotation by SVD, det +1: Kabsch) with T·source[i] ≈ target[i].
// Throws PlanningInputError for fewer than 3 pairs, a size mismatch or non-finite points.
Eigen::Isometry3d rigid_fit(const std::vector<Eigen::Vector3d>& source,
                            const std::vector<Eigen::Vector3d>& target);

struct IcpOptions {
  int max_iterations = 100;
  double tolerance = 1e-6;  // mm of RMS change that ends the iteration (our choice)
};

struct IcpResult {
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // T_t^s: data (CT) → model ({P})
  double rms = 0.0;                                             // mm, nearest-neighbour RMS at the end
  int iterations = 0;
  bool converged = false;  // the RMS change fell below the tolerance
};

// Point-to-point ICP (Besl & McKay): nearest model point for every data point (exhaustive search —
// the stick clouds are thousands of points, done once per plan), Kabsch fit, repeat. Starts from
// `initial` when given, else from the translation aligning the centroids. Throws PlanningInputError
// for fewer than 3 points in either cloud or non-finite points.
IcpResult icp(const std::vector<Eigen::Vector3d>& model, const std::vector<Eigen::Vector3d>& data,
              const Eigen::Isometry3d* initial = nullptr, const IcpOptions& options = {});

struct CentroidPlanOptions {
  int count = 16;           // n (Heunis et al. 2021, §4.1)
  double end_x = 0.0;       // p_d,x: the user's endpoint in {P}
  double start_x = -1e300;  // optional start; the default keeps every point up to the endpoint
};

// Algorithm 1: `wall_ct` (B, CT frame) mapped by `ct_to_tissue` (T_t^s) into {P}, sorted by x, kept
// within [start_x, end_x], a quartic fitted to each coordinate over v ∈ [0, 1], evaluated at n evenly
// spaced v. Throws PlanningInputError for n < 2, fewer than 5 points in range, an x-extent under
// 1 mm, or non-finite input.
std::vector<Eigen::Vector3d> arterial_centroids(const std::vector<Eigen::Vector3d>& wall_ct,
                                                const Eigen::Isometry3d& ct_to_tissue,
                                                const CentroidPlanOptions& options);

struct ProbeViaPoint {
  Eigen::Vector3d surface_point = Eigen::Vector3d::Zero();  // s_i in {P}
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();   // R_i^P: probe x, y, z axes as columns
  Eigen::Isometry3d pose() const;                           // H_i^P
};

struct ViaPointOptions {
  Eigen::Vector3d up = Eigen::Vector3d::UnitY();  // the tissue's vertical (ŷ of Algorithm 2)
  int nearest = 5;  // surface points averaged around the vertical line (1 = the paper's argmin)
};

// Algorithm 2: per centroid c_i, the surface point s_i nearest to the vertical line through c_i
// (among the points above c_i), z = (c_i − s_i)/‖·‖ (probe axis, skin → vessel), ŝ = direction to the
// next surface point, y = z × ŝ (the array axis: the image plane cuts the vessel across), x = y × z.
// Throws PlanningInputError for fewer than 2 centroids, an empty surface, no surface point above a
// centroid, non-finite input, or a sweep direction parallel to the probe axis at every via-point.
std::vector<ProbeViaPoint> probe_via_points(const std::vector<Eigen::Vector3d>& surface,
                                            const std::vector<Eigen::Vector3d>& centroids,
                                            const ViaPointOptions& options = {});

}  // namespace tendril::ultrasound
