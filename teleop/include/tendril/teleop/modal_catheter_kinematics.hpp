// ModalCatheterKinematics: forward kinematics of the two-segment SRMC (Abah 2022, §4.5.1, eqs. 4.4–4.6)
// with the calibrated modal shape model of §4.5.2 (eq. 4.9):
//   θ_i(s, q) = Ψ(s)ᵀ·A_i·η(q),  Ψ(s) = [1, s, …, s^{n−1}]ᵀ,  η(q) = [1, q, …, q^{m−1}]ᵀ,
// where θ is the tangent angle from x̂ in the bending (x–z) plane, s ∈ [0, L_i] in mm and q the
// segment's push-pull actuation in mm. CatheterSegment displacement d_i = ∫₀^{L_i} [cos θ, 0, sin θ]ᵀ ds
// (composite Simpson) and tip rotation e^{θ̃_L[ŷ×]} with θ̃_L = π/2 − θ_L.
//
// Frame convention: identical to ConstantCurvatureCatheter (catheter_kinematics.hpp). The proximal
// segment base is at (0, 0, q1); a straight catheter points along +z; a bend with θ_L < π/2 turns
// the tip toward +x. Chain: insertion · roll e^{q2[ẑ×]} · proximal CS · e^{δ2[ẑ×]} · e^{γ[x̂×]} ·
// distal CS. With A = [[π/2, 0], [0, −k/L], [0, 0], [0, 0]] the model equals the constant-curvature
// placeholder θ = π/2 − k·q·s/L.
//
// Model/data split: the object is immutable after construction; every evaluation is const,
// noexcept and allocation-free (shape matrices live in fixed-capacity Eigen storage).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <span>

#include "tendril/teleop/catheter_kinematics.hpp"  // TipPose

namespace tendril::teleop {

// Largest supported modal order n (s-basis) and actuation order m (q-basis).
inline constexpr int kMaxModalOrder = 6;

// A_i with at most kMaxModalOrder rows and columns; fixed capacity, so copying never allocates.
using ShapeMatrix =
    Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::ColMajor, kMaxModalOrder, kMaxModalOrder>;

struct ModalSegmentShape {
  Eigen::MatrixXd shape_matrix;  // A_i, n×m (rows: powers of s, columns: powers of q)
  double length = 0.0;           // L_i (mm)
};

struct ModalCatheterParameters {
  ModalSegmentShape proximal;   // θ_1(s, q3)
  ModalSegmentShape distal;     // θ_2(s, q4)
  double plane_offset = -0.44;  // δ2 (rad)
  double flexure = 0.0;         // γ (rad)
  int simpson_intervals = 32;   // composite Simpson intervals over a full segment (even, ≥ 2)
};

// The constant-curvature placeholder of §4.5.2 as shape matrices (n = 4, m = 2): the same model as
// ConstantCurvatureCatheter with gains k1, k2 (rad/mm).
ModalCatheterParameters constant_curvature_modal_parameters(const CatheterParameters& parameters);

enum class CatheterSegment { kProximal = 0, kDistal = 1 };

class ModalCatheterKinematics {
 public:
  using JointVector = Eigen::Matrix<double, 4, 1>;
  using PositionJacobian = Eigen::Matrix<double, 3, 4>;

  // Throws std::invalid_argument when a shape matrix is empty or larger than 6×6, an entry is not
  // finite, a length is not > 0, or simpson_intervals is odd or < 2.
  explicit ModalCatheterKinematics(const ModalCatheterParameters& parameters);

  double length(CatheterSegment segment) const noexcept;
  double plane_offset() const noexcept { return plane_offset_; }
  double flexure() const noexcept { return flexure_; }
  const ShapeMatrix& shape_matrix(CatheterSegment segment) const noexcept;

  // θ_i(s, q) (rad); q is q3 for the proximal and q4 for the distal segment.
  double tangent_angle(CatheterSegment segment, double arc_length, double actuation) const noexcept;
  // ∂θ_i(s, q)/∂q (rad/mm).
  double tangent_angle_rate(CatheterSegment segment, double arc_length, double actuation) const noexcept;
  // θ_Li(q) = θ_i(L_i, q) and ∂θ_Li/∂q (constant when m = 2): the diagonal entries of J_ψq (4.23).
  double tip_angle(CatheterSegment segment, double actuation) const noexcept;
  double tip_angle_rate(CatheterSegment segment, double actuation) const noexcept;

  // d_i(s) = ∫₀^s [cos θ, 0, sin θ]ᵀ dσ in the segment base frame (s clamped to [0, L_i]); Simpson
  // with intervals scaled to the fraction of the segment (at least 2).
  Eigen::Vector3d segment_displacement(CatheterSegment segment, double arc_length,
                                       double actuation) const noexcept;

  // Pose of the distal tip (frame {6}) in frame {0}.
  TipPose tip_pose(const JointVector& q) const noexcept;

  // ∂(tip position)/∂q (3×4) in frame {0}: analytic (insertion, roll and the bend columns through
  // ∂d/∂q = ∫ [−sin θ, 0, cos θ]ᵀ ∂θ/∂q ds and the derivative of e^{θ̃[ŷ×]}).
  PositionJacobian tip_position_jacobian(const JointVector& q) const noexcept;

  // Points backbone() writes: the proximal base then points_per_segment per segment.
  std::size_t backbone_point_count(std::size_t points_per_segment) const noexcept {
    return 1 + 2 * points_per_segment;
  }
  // Backbone polyline in frame {0}, ending at the tip. Returns the number of points written, or 0
  // when out is too small or points_per_segment is 0.
  std::size_t backbone(const JointVector& q, std::size_t points_per_segment,
                       std::span<Eigen::Vector3d> out) const noexcept;

 private:
  struct SegmentModel {
    ShapeMatrix A;
    double length;
  };
  const SegmentModel& model(CatheterSegment segment) const noexcept {
    return segment == CatheterSegment::kProximal ? proximal_ : distal_;
  }
  // Ψ(s)ᵀ·A (1×m) evaluated at s, then dotted with η(q) or η'(q).
  double evaluate(const SegmentModel& m, double s, double q, bool derivative_in_q) const noexcept;
  // ∫₀^s of [cos θ, 0, sin θ] (or, with derivative, [−sin θ, 0, cos θ]·∂θ/∂q).
  Eigen::Vector3d integrate(const SegmentModel& m, double s, double q, bool derivative_in_q) const noexcept;
  // The same over [from, to] with `intervals` Simpson intervals (rounded up to even, at least 2).
  Eigen::Vector3d integrate_between(const SegmentModel& m, double from, double to, double q, int intervals,
                                    bool derivative_in_q) const noexcept;

  SegmentModel proximal_;
  SegmentModel distal_;
  double plane_offset_;
  double flexure_;
  int simpson_intervals_;
};

}  // namespace tendril::teleop
