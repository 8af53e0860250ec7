// One variable-diameter MBCR segment: kinematics (Abah 2022, §2.5) and statics (§2.6.1); see the header.
#include "tendril/teleop/variable_diameter_segment.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace tendril::teleop {
namespace {

// Below this |Θ| the closed forms (cos Θ − 1)/Θ etc. lose digits; their Taylor series are used instead.
constexpr double kTaylorBend = 1e-4;

double backbone_angle(const SegmentConfiguration& psi, int i) noexcept {
  return psi[1] + i * 0.5 * std::numbers::pi;
}

// (cos Θ − 1)/Θ, (sin Θ)/Θ and their derivatives, which the pose and its Jacobian are built from.
struct BendFactors {
  double c2;  // (cos Θ − 1)/Θ
  double s1;  // sin Θ/Θ
  double c1;  // d/dΘ of c2 = (−Θ sin Θ − cos Θ + 1)/Θ²
  double c3;  // d/dΘ of s1 = (Θ cos Θ − sin Θ)/Θ²
};

BendFactors bend_factors(double t) noexcept {
  if (std::abs(t) < kTaylorBend) {
    const double t2 = t * t;
    return {-t / 2.0 + t * t2 / 24.0, 1.0 - t2 / 6.0, -0.5 + t2 / 8.0, -t / 3.0 + t * t2 / 30.0};
  }
  const double s = std::sin(t), c = std::cos(t);
  return {(c - 1.0) / t, s / t, (-t * s - c + 1.0) / (t * t), (t * c - s) / (t * t)};
}

}  // namespace

Eigen::Vector4d backbone_displacements(const SegmentConfiguration& psi, double r) noexcept {
  const double bend = segment_bend(psi);
  Eigen::Vector4d q;
  for (int i = 0; i < 4; ++i) q[i] = r * bend * std::cos(backbone_angle(psi, i));
  return q;
}

SegmentJointJacobian backbone_jacobian(const SegmentConfiguration& psi, double r) noexcept {
  const double bend = segment_bend(psi);
  SegmentJointJacobian j;
  for (int i = 0; i < 4; ++i) {
    const double angle = backbone_angle(psi, i);
    j(i, 0) = r * std::cos(angle);
    j(i, 1) = -r * bend * std::sin(angle);
  }
  return j;
}

Eigen::Vector4d diameter_column(const SegmentConfiguration& psi, double dr_da) noexcept {
  const double bend = segment_bend(psi);
  Eigen::Vector4d c;
  for (int i = 0; i < 4; ++i) c[i] = bend * std::cos(backbone_angle(psi, i)) * dr_da;
  return c;
}

SegmentAugmentation augmentation_matrix(const SegmentConfiguration& psi, double dr_da) noexcept {
  SegmentAugmentation a;
  a.leftCols<4>().setIdentity();
  a.col(4) = -diameter_column(psi, dr_da);
  return a;
}

SegmentAugmentedJacobian augmented_jacobian(const SegmentConfiguration& psi, double r,
                                            double dr_da) noexcept {
  // A = [I | −c] ⇒ AAᵀ = I + ccᵀ and A⁺ = [I; −cᵀ]·(I − ccᵀ/(1 + cᵀc)).
  const Eigen::Vector4d c = diameter_column(psi, dr_da);
  const SegmentJointJacobian w = backbone_jacobian(psi, r);
  const Eigen::Matrix<double, 4, 2> y = w - c * (c.transpose() * w) / (1.0 + c.squaredNorm());
  SegmentAugmentedJacobian j;
  j.topRows<4>() = y;
  j.row(4) = -c.transpose() * y;
  return j;
}

Eigen::Isometry3d segment_end_pose(const SegmentConfiguration& psi, double length) noexcept {
  const double bend = segment_bend(psi);
  const double delta = psi[1];
  const BendFactors f = bend_factors(bend);
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translation() = length * Eigen::Vector3d(std::cos(delta) * f.c2, -std::sin(delta) * f.c2, f.s1);
  pose.linear() = (Eigen::AngleAxisd(-delta, Eigen::Vector3d::UnitZ()) *
                   Eigen::AngleAxisd(-bend, Eigen::Vector3d::UnitY()) *
                   Eigen::AngleAxisd(delta, Eigen::Vector3d::UnitZ()))
                      .toRotationMatrix();
  return pose;
}

SegmentTwistJacobian segment_twist_jacobian(const SegmentConfiguration& psi, double length) noexcept {
  const double bend = segment_bend(psi);
  const double sd = std::sin(psi[1]), cd = std::cos(psi[1]);
  const BendFactors f = bend_factors(bend);
  const double sb = std::sin(bend), cb = std::cos(bend);
  SegmentTwistJacobian j;
  // Linear part: ∂p/∂θ_L and ∂p/∂δ of the end-disk position.
  j(0, 0) = length * cd * f.c1;
  j(1, 0) = -length * sd * f.c1;
  j(2, 0) = length * f.c3;
  j(0, 1) = -length * sd * f.c2;
  j(1, 1) = -length * cd * f.c2;
  j(2, 1) = 0.0;
  // Angular part (Abah 2022, §2.5, extended, with cos θ_L = −sin Θ and sin θ_L = cos Θ).
  j(3, 0) = -sd;
  j(4, 0) = -cd;
  j(5, 0) = 0.0;
  j(3, 1) = -cd * sb;
  j(4, 1) = sd * sb;
  j(5, 1) = cb - 1.0;
  return j;
}

double backbone_bending_stiffness(double youngs_modulus, double diameter) noexcept {
  return youngs_modulus * std::numbers::pi * std::pow(diameter, 4) / 64.0;
}

double elastic_energy(const SegmentConfiguration& psi, double r, double length,
                      double bending_stiffness) noexcept {
  const double bend = segment_bend(psi);
  double u = 0.0;
  for (int i = 0; i < 4; ++i) {
    const double li = length + r * bend * std::cos(backbone_angle(psi, i));
    u += bending_stiffness * bend * bend / (2.0 * li);
  }
  return u;
}

double elastic_energy_radius_gradient(const SegmentConfiguration& psi, double r, double length,
                                      double bending_stiffness) noexcept {
  const double bend = segment_bend(psi);
  double sum = 0.0;
  for (int i = 0; i < 4; ++i) {
    const double ci = std::cos(backbone_angle(psi, i));
    const double li = length + r * bend * ci;
    sum += ci / (li * li);
  }
  return -bending_stiffness * bend * bend * bend / 2.0 * sum;
}

Eigen::Vector2d elastic_energy_configuration_gradient(const SegmentConfiguration& psi, double r,
                                                      double length, double bending_stiffness) noexcept {
  const double bend = segment_bend(psi);
  double inv = 0.0, cos_sum = 0.0, sin_sum = 0.0;
  for (int i = 0; i < 4; ++i) {
    const double angle = backbone_angle(psi, i);
    const double li = length + r * bend * std::cos(angle);
    inv += 1.0 / li;
    cos_sum += std::cos(angle) / (li * li);
    sin_sum += std::sin(angle) / (li * li);
  }
  return bending_stiffness * Eigen::Vector2d(bend * inv - r * bend * bend / 2.0 * cos_sum,
                                             r * bend * bend * bend / 2.0 * sin_sum);
}

bool segment_statics(const SegmentConfiguration& psi, double r, double dr_da, double length,
                     double bending_stiffness, const Wrench& wrench, SegmentStatics& out) noexcept {
  out = SegmentStatics{};
  if (!psi.allFinite() || !std::isfinite(r) || !std::isfinite(dr_da) || !std::isfinite(length) ||
      !std::isfinite(bending_stiffness) || !wrench.allFinite()) {
    return false;
  }
  out.augmented_jacobian = augmented_jacobian(psi, r, dr_da);
  out.radius_jacobian = dr_da * out.augmented_jacobian.row(4);
  const double grad_r = elastic_energy_radius_gradient(psi, r, length, bending_stiffness);
  const Eigen::Vector2d grad_psi = elastic_energy_configuration_gradient(psi, r, length, bending_stiffness);
  const SegmentTwistJacobian jx = segment_twist_jacobian(psi, length);
  out.generalized_load = out.radius_jacobian.transpose() * grad_r + grad_psi - jx.transpose() * wrench;
  // (J_q̃ψᵀ)⁺ = J_q̃ψ·(J_q̃ψᵀJ_q̃ψ)⁺; the 2×2 Gram matrix is inverted on its non-negligible eigenvalues.
  const Eigen::Matrix2d gram = out.augmented_jacobian.transpose() * out.augmented_jacobian;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(gram);
  const Eigen::Vector2d& values = eig.eigenvalues();
  const double cutoff = 1e-12 * std::max(values.maxCoeff(), 1e-300);
  Eigen::Vector2d inverse_values;
  for (int i = 0; i < 2; ++i) inverse_values[i] = values[i] > cutoff ? 1.0 / values[i] : 0.0;
  const Eigen::Matrix2d gram_pinv =
      eig.eigenvectors() * inverse_values.asDiagonal() * eig.eigenvectors().transpose();
  out.actuation = out.augmented_jacobian * (gram_pinv * out.generalized_load);
  return out.actuation.allFinite();
}

}  // namespace tendril::teleop
