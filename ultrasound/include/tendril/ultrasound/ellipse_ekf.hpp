// Artery boundary per ultrasound (US) slice: the ellipse extended Kalman filter (EKF) of Heunis et al. 2021
// Appendix B with probabilistic edge weighting, iterated by the star algorithm (
// ellipse EKF), with the exponent of A21 squared and N rays of M candidates each, as the equations need.
//
// Per slice, from a seed centre c:
//   1. the image is blurred (Gaussian, σ in pixels) once — speckle would otherwise make every
//      candidate an edge;
//   2. around the contour, ray q = 0..N−1 at θ_q = 2πq/N (12° for N = 30) in the (y, z) plane: random
//      walk prediction P += Q; predicted radius D (A15) and its Jacobian; S = J P Jᵀ + R; M candidates
//      r_j = j·r_max/M; edge magnitude F_e (below); likelihood p_j = F_e² · exp(−(r_j − D)²/(2S)) (A21;
//      the 1/√(2πS) factor cancels in A20); weighted radius r_q = Σ β_j r_j (A19–A20); update A16–A18;
//   3. star algorithm: the new centre is the mean of the N contour points; repeat from 2 until the
//      centre moves less than the tolerance or the iteration cap is reached.
// Choices where the article is silent (ours):
//   * F_e is the radial intensity rise I(r + δ) − I(r − δ) of the blurred image, clipped at an upper
//     threshold and scaled to [0, 1] ("an intensity constrained by an upper threshold"; the paper's
//     plain intensity would make all the bright tissue beyond the wall an edge, and the dark-lumen →
//     bright-wall rise is what marks the boundary).
//   * The ellipse state carries over between star iterations (the covariance restarts at P₀), so
//     later iterations refine rather than relearn the shape.
//   * A ray with no edge anywhere (Σ p = 0) skips its update and keeps the prediction.
//   * Contour points are the posterior radius D(x̂_q|q) along each ray (a smoother contour than the raw
//     weighted radius r_q, which the result also keeps).
// segment() allocates nothing: every buffer is sized by the constructor for one image geometry.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "tendril/ultrasound/bmode_image.hpp"

namespace tendril::ultrasound {

struct EllipseEkfParameters {
  int rays = 30;        // N, boundary detection indices (Heunis et al. 2021, §4.1: 30 for the 10 mm tube)
  int candidates = 40;  // M edge candidates per ray (our choice)
  double max_radius = 10.0;                          // r_max (mm) (our choice): 2× the nominal radius
  double nominal_radius = 5.0;                       // R₀ (mm): x̂₀ = [R₀, R₀, 0]
  Eigen::Vector3d initial_variance{1.0, 1.0, 0.5};   // P₀ diagonal (mm², mm², rad²)
  Eigen::Vector3d process_noise{0.01, 0.01, 0.001};  // Q diagonal per ray
  double measurement_noise = 0.25;                   // R (mm²)
  double blur_sigma = 2.0;                           // Gaussian pre-filter (pixels)
  double edge_step = 0.5;        // δ (mm): half the baseline of the radial intensity rise
  double edge_threshold = 0.15;  // rise (of the [0, 1] intensity scale) at which F_e saturates
  int max_iterations = 20;       // star iterations
  double tolerance = 0.01;       // mm of centre motion that counts as converged
};

struct SliceSegmentation {
  bool valid = false;                                 // a contour was found (false: seed outside the image)
  bool converged = false;                             // the centre moved less than the tolerance
  int iterations = 0;                                 // star iterations run
  double final_shift = 0.0;                           // mm the centre moved in the last iteration
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();   // (y, z) mm in {I}: the slice centroid ψ_US
  Eigen::Vector3d ellipse = Eigen::Vector3d::Zero();  // (f, h, φ): semi-axes (mm) and tilt (rad)
  std::vector<Eigen::Vector2d> contour;               // N points (y, z) mm in {I}: Λ_US
  std::vector<double> measured_radius;                // r_q of A19 per ray (mm; the prediction where no edge)
};

class EllipseSliceSegmenter {
 public:
  // Throws UltrasoundSetupError for an invalid geometry or parameters outside their sense (rays < 3,
  // candidates < 2, radii, variances, noise, blur or tolerance not positive and finite).
  EllipseSliceSegmenter(const BModeGeometry& geometry, const EllipseEkfParameters& parameters = {});

  const EllipseEkfParameters& parameters() const noexcept { return parameters_; }
  const BModeGeometry& geometry() const noexcept { return geometry_; }

  // Segments one frame from a seed centre (y, z) mm in {I}. The result lives until the next call.
  // An image of another geometry, or a seed that is not finite or outside the image, gives a result
  // with valid = false. Allocation-free.
  const SliceSegmentation& segment(const BModeImage& image, const Eigen::Vector2d& seed) noexcept;

  // Fills `mask` (resized to the geometry's pixel count) with the polygon of the contour, the lumen
  // mask a slice result carries; all zero for an invalid result.
  void lumen_mask(const SliceSegmentation& result, LumenMask& mask) const;

 private:
  void blur(const BModeImage& image) noexcept;
  double sample(double y, double z) const noexcept;
  void run_contour(const Eigen::Vector2d& centre, Eigen::Vector3d& state) noexcept;

  BModeGeometry geometry_;
  EllipseEkfParameters parameters_;
  std::vector<float> kernel_;
  std::vector<float> scratch_;
  std::vector<float> blurred_;
  SliceSegmentation result_;
};

// The ellipse radius D(x) of A15 at angle θ and its Jacobian ∂D/∂(f, h, φ) (derived from A15).
double ellipse_radius(const Eigen::Vector3d& state, double theta) noexcept;
Eigen::Vector3d ellipse_radius_jacobian(const Eigen::Vector3d& state, double theta) noexcept;

}  // namespace tendril::ultrasound
