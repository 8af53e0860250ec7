#include "tendril/teleop/catheter_kinematics.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

// (1 − cos x)/x and sin x / x, with series near 0 so a straight segment needs no division by zero.
double one_minus_cos_over(double x) noexcept {
  if (std::abs(x) < 1e-4) return x * (0.5 - x * x / 24.0);
  return (1.0 - std::cos(x)) / x;
}
double sin_over(double x) noexcept {
  if (std::abs(x) < 1e-4) return 1.0 - x * x / 6.0;
  return std::sin(x) / x;
}

// Point at arc length s of a constant-curvature segment whose tangent turns by bend_at_s over [0, s]
// (eq. 4.6 in closed form: ∫ [cos θ, 0, sin θ] ds with θ = π/2 − bend·σ/s).
Eigen::Vector3d arc_point(double s, double bend_at_s) noexcept {
  return {s * one_minus_cos_over(bend_at_s), 0.0, s * sin_over(bend_at_s)};
}

Eigen::Matrix3d rot_x(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix();
}
Eigen::Matrix3d rot_y(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()).toRotationMatrix();
}
Eigen::Matrix3d rot_z(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

struct Frame {
  Eigen::Matrix3d R;
  Eigen::Vector3d p;
  Eigen::Vector3d apply(const Eigen::Vector3d& x) const noexcept { return R * x + p; }
};

}  // namespace

ConstantCurvatureCatheter::ConstantCurvatureCatheter(const CatheterParameters& parameters)
    : parameters_(parameters) {
  auto require = [](bool ok, const std::string& message) {
    if (!ok) throw std::invalid_argument("ConstantCurvatureCatheter: " + message);
  };
  const auto& p = parameters;
  require(std::isfinite(p.proximal_length) && p.proximal_length > 0.0,
          "proximal_length L1 must be > 0 mm, got " + std::to_string(p.proximal_length));
  require(std::isfinite(p.distal_length) && p.distal_length > 0.0,
          "distal_length L2 must be > 0 mm, got " + std::to_string(p.distal_length));
  require(std::isfinite(p.plane_offset) && std::isfinite(p.flexure),
          "plane_offset and flexure must be finite");
  require(std::isfinite(p.proximal_curvature_gain) && std::isfinite(p.distal_curvature_gain),
          "curvature gains must be finite");
  require(std::isfinite(p.shaft_length) && p.shaft_length >= 0.0,
          "shaft_length must be >= 0 mm, got " + std::to_string(p.shaft_length));
}

double ConstantCurvatureCatheter::proximal_bend(const JointVector& q) const noexcept {
  return parameters_.proximal_curvature_gain * q[2];
}
double ConstantCurvatureCatheter::distal_bend(const JointVector& q) const noexcept {
  return parameters_.distal_curvature_gain * q[3];
}

TipPose ConstantCurvatureCatheter::tip_pose(const JointVector& q) const noexcept {
  const auto& P = parameters_;
  const double bend1 = proximal_bend(q), bend2 = distal_bend(q);
  // ⁰H₁·¹H₂: insertion then roll (roll about the insertion axis).
  Frame f{rot_z(q[1]), Eigen::Vector3d(0.0, 0.0, q[0])};
  // ²H₃: proximal segment.
  f.p += f.R * arc_point(P.proximal_length, bend1);
  f.R = f.R * rot_y(bend1);
  // ³H₄·⁴H₅: plane offset and passive flexure.
  f.R = f.R * rot_z(P.plane_offset) * rot_x(P.flexure);
  // ⁵H₆: distal segment.
  f.p += f.R * arc_point(P.distal_length, bend2);
  f.R = f.R * rot_y(bend2);
  return {f.p, f.R};
}

ConstantCurvatureCatheter::PositionJacobian ConstantCurvatureCatheter::tip_position_jacobian(
    const JointVector& q) const noexcept {
  PositionJacobian J;
  for (int j = 0; j < 4; ++j) {
    const double h = 1e-6 * std::max(1.0, std::abs(q[j]));
    JointVector plus = q, minus = q;
    plus[j] += h;
    minus[j] -= h;
    J.col(j) = (tip_pose(plus).position - tip_pose(minus).position) / (2.0 * h);
  }
  return J;
}

std::size_t ConstantCurvatureCatheter::backbone_point_count(std::size_t points_per_segment) const noexcept {
  return (parameters_.shaft_length > 0.0 ? 1 : 0) + 1 + 2 * points_per_segment;
}

std::size_t ConstantCurvatureCatheter::backbone(const JointVector& q, std::size_t points_per_segment,
                                                std::span<Eigen::Vector3d> out) const noexcept {
  if (points_per_segment == 0 || out.size() < backbone_point_count(points_per_segment)) return 0;
  const auto& P = parameters_;
  const double bend1 = proximal_bend(q), bend2 = distal_bend(q);
  std::size_t n = 0;
  if (P.shaft_length > 0.0) out[n++] = Eigen::Vector3d(0.0, 0.0, q[0] - P.shaft_length);

  Frame base1{rot_z(q[1]), Eigen::Vector3d(0.0, 0.0, q[0])};
  out[n++] = base1.p;
  const double count = static_cast<double>(points_per_segment);
  for (std::size_t i = 1; i <= points_per_segment; ++i) {
    const double fraction = static_cast<double>(i) / count;
    out[n++] = base1.apply(arc_point(P.proximal_length * fraction, bend1 * fraction));
  }
  Frame base2{base1.R * rot_y(bend1) * rot_z(P.plane_offset) * rot_x(P.flexure),
              base1.apply(arc_point(P.proximal_length, bend1))};
  for (std::size_t i = 1; i <= points_per_segment; ++i) {
    const double fraction = static_cast<double>(i) / count;
    out[n++] = base2.apply(arc_point(P.distal_length * fraction, bend2 * fraction));
  }
  return n;
}

}  // namespace tendril::teleop
