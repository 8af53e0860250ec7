#include "tendril/teleop/modal_catheter_kinematics.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

Eigen::Matrix3d rot_x(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix();
}
Eigen::Matrix3d rot_y(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()).toRotationMatrix();
}
Eigen::Matrix3d rot_z(double a) noexcept {
  return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

void validate_segment(const ModalSegmentShape& shape, const char* name) {
  const std::string prefix = std::string("ModalCatheterKinematics: ") + name + " segment ";
  const auto rows = shape.shape_matrix.rows(), cols = shape.shape_matrix.cols();
  if (rows < 1 || cols < 1 || rows > kMaxModalOrder || cols > kMaxModalOrder) {
    throw std::invalid_argument(prefix + "shape matrix must be n×m with 1 ≤ n, m ≤ " +
                                std::to_string(kMaxModalOrder) + ", got " + std::to_string(rows) + "×" +
                                std::to_string(cols));
  }
  if (!shape.shape_matrix.allFinite())
    throw std::invalid_argument(prefix + "shape matrix has a NaN or infinite entry");
  if (!std::isfinite(shape.length) || shape.length <= 0.0) {
    throw std::invalid_argument(prefix + "length must be > 0 mm, got " + std::to_string(shape.length));
  }
}

}  // namespace

ModalCatheterParameters constant_curvature_modal_parameters(const CatheterParameters& parameters) {
  auto shape = [](double gain, double length) {
    ModalSegmentShape s;
    s.length = length;
    s.shape_matrix = Eigen::MatrixXd::Zero(4, 2);
    s.shape_matrix(0, 0) = std::numbers::pi / 2.0;
    s.shape_matrix(1, 1) = -gain / length;
    return s;
  };
  ModalCatheterParameters out;
  out.proximal = shape(parameters.proximal_curvature_gain, parameters.proximal_length);
  out.distal = shape(parameters.distal_curvature_gain, parameters.distal_length);
  out.plane_offset = parameters.plane_offset;
  out.flexure = parameters.flexure;
  return out;
}

ModalCatheterKinematics::ModalCatheterKinematics(const ModalCatheterParameters& parameters)
    : plane_offset_(parameters.plane_offset),
      flexure_(parameters.flexure),
      simpson_intervals_(parameters.simpson_intervals) {
  validate_segment(parameters.proximal, "proximal");
  validate_segment(parameters.distal, "distal");
  if (!std::isfinite(plane_offset_) || !std::isfinite(flexure_)) {
    throw std::invalid_argument("ModalCatheterKinematics: plane_offset and flexure must be finite");
  }
  if (simpson_intervals_ < 2 || simpson_intervals_ % 2 != 0) {
    throw std::invalid_argument("ModalCatheterKinematics: simpson_intervals must be even and ≥ 2, got " +
                                std::to_string(simpson_intervals_));
  }
  proximal_ = {parameters.proximal.shape_matrix, parameters.proximal.length};
  distal_ = {parameters.distal.shape_matrix, parameters.distal.length};
}

double ModalCatheterKinematics::length(CatheterSegment segment) const noexcept {
  return model(segment).length;
}

const ShapeMatrix& ModalCatheterKinematics::shape_matrix(CatheterSegment segment) const noexcept {
  return model(segment).A;
}

double ModalCatheterKinematics::evaluate(const SegmentModel& m, double s, double q,
                                         bool derivative_in_q) const noexcept {
  // Horner in s for each column of A, then the polynomial in q (or its derivative).
  double result = 0.0;
  double q_power = 1.0;  // q^(j) for θ, or j·q^(j−1) built below for ∂θ/∂q
  for (int j = 0; j < m.A.cols(); ++j) {
    double column = 0.0;
    for (int i = static_cast<int>(m.A.rows()) - 1; i >= 0; --i) column = column * s + m.A(i, j);
    if (derivative_in_q) {
      const double weight = j == 0 ? 0.0 : j * std::pow(q, j - 1);
      result += column * weight;
    } else {
      result += column * q_power;
      q_power *= q;
    }
  }
  return result;
}

Eigen::Vector3d ModalCatheterKinematics::integrate(const SegmentModel& m, double s, double q,
                                                   bool derivative_in_q) const noexcept {
  s = std::clamp(s, 0.0, m.length);
  if (s == 0.0) return Eigen::Vector3d::Zero();
  // Keep the step roughly that of a full segment: intervals ∝ s/L, rounded up to even, at least 2.
  const int intervals = static_cast<int>(std::ceil(simpson_intervals_ * s / m.length));
  return integrate_between(m, 0.0, s, q, intervals, derivative_in_q);
}

Eigen::Vector3d ModalCatheterKinematics::integrate_between(const SegmentModel& m, double from, double to,
                                                           double q, int intervals,
                                                           bool derivative_in_q) const noexcept {
  intervals = std::max(2, intervals + (intervals % 2));
  const double h = (to - from) / intervals;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (int k = 0; k <= intervals; ++k) {
    const double sk = from + k * h;
    const double theta = evaluate(m, sk, q, false);
    Eigen::Vector3d f;
    if (derivative_in_q) {
      const double rate = evaluate(m, sk, q, true);
      f = Eigen::Vector3d(-std::sin(theta) * rate, 0.0, std::cos(theta) * rate);
    } else {
      f = Eigen::Vector3d(std::cos(theta), 0.0, std::sin(theta));
    }
    const double weight = (k == 0 || k == intervals) ? 1.0 : (k % 2 == 1 ? 4.0 : 2.0);
    sum += weight * f;
  }
  return sum * (h / 3.0);
}

double ModalCatheterKinematics::tangent_angle(CatheterSegment segment, double arc_length,
                                              double actuation) const noexcept {
  return evaluate(model(segment), arc_length, actuation, false);
}
double ModalCatheterKinematics::tangent_angle_rate(CatheterSegment segment, double arc_length,
                                                   double actuation) const noexcept {
  return evaluate(model(segment), arc_length, actuation, true);
}
double ModalCatheterKinematics::tip_angle(CatheterSegment segment, double actuation) const noexcept {
  return evaluate(model(segment), model(segment).length, actuation, false);
}
double ModalCatheterKinematics::tip_angle_rate(CatheterSegment segment, double actuation) const noexcept {
  return evaluate(model(segment), model(segment).length, actuation, true);
}

Eigen::Vector3d ModalCatheterKinematics::segment_displacement(CatheterSegment segment, double arc_length,
                                                              double actuation) const noexcept {
  return integrate(model(segment), arc_length, actuation, false);
}

TipPose ModalCatheterKinematics::tip_pose(const JointVector& q) const noexcept {
  const double half_pi = std::numbers::pi / 2.0;
  Eigen::Matrix3d R = rot_z(q[1]);
  Eigen::Vector3d p(0.0, 0.0, q[0]);
  p += R * integrate(proximal_, proximal_.length, q[2], false);
  R = R * rot_y(half_pi - tip_angle(CatheterSegment::kProximal, q[2])) * rot_z(plane_offset_) *
      rot_x(flexure_);
  p += R * integrate(distal_, distal_.length, q[3], false);
  R = R * rot_y(half_pi - tip_angle(CatheterSegment::kDistal, q[3]));
  return {p, R};
}

ModalCatheterKinematics::PositionJacobian ModalCatheterKinematics::tip_position_jacobian(
    const JointVector& q) const noexcept {
  const double half_pi = std::numbers::pi / 2.0;
  const Eigen::Matrix3d R0 = rot_z(q[1]);
  const Eigen::Matrix3d R1 = rot_y(half_pi - tip_angle(CatheterSegment::kProximal, q[2]));
  const Eigen::Matrix3d offset = rot_z(plane_offset_) * rot_x(flexure_);
  const Eigen::Vector3d d1 = integrate(proximal_, proximal_.length, q[2], false);
  const Eigen::Vector3d d2 = integrate(distal_, distal_.length, q[3], false);
  const Eigen::Vector3d local_tip = d1 + R1 * offset * d2;  // tip relative to the proximal base, before roll

  PositionJacobian J;
  J.col(0) = Eigen::Vector3d::UnitZ();
  J.col(1) = Eigen::Vector3d::UnitZ().cross(R0 * local_tip);  // d/dq2 e^{q2[ẑ×]} = [ẑ×]·e^{q2[ẑ×]}
  // θ̃1 = π/2 − θ_L1, so ∂θ̃1/∂q3 = −∂θ_L1/∂q3 and ∂R1/∂θ̃1 = [ŷ×]·R1.
  const double bend1_rate = -tip_angle_rate(CatheterSegment::kProximal, q[2]);
  J.col(2) = R0 * (integrate(proximal_, proximal_.length, q[2], true) +
                   bend1_rate * Eigen::Vector3d::UnitY().cross(R1 * offset * d2));
  J.col(3) = R0 * R1 * offset * integrate(distal_, distal_.length, q[3], true);
  return J;
}

std::size_t ModalCatheterKinematics::backbone(const JointVector& q, std::size_t points_per_segment,
                                              std::span<Eigen::Vector3d> out) const noexcept {
  if (points_per_segment == 0 || out.size() < backbone_point_count(points_per_segment)) return 0;
  const double half_pi = std::numbers::pi / 2.0;
  const double count = static_cast<double>(points_per_segment);
  std::size_t n = 0;
  Eigen::Matrix3d R = rot_z(q[1]);
  Eigen::Vector3d base(0.0, 0.0, q[0]);
  out[n++] = base;
  // Piece by piece from the last point (not from the base each time): the same Simpson step as a
  // whole segment, at a fraction of the cost — the simulated vessel contact calls this 5000 times a
  // second.
  const int piece_intervals = static_cast<int>(std::ceil(static_cast<double>(simpson_intervals_) / count));
  Eigen::Vector3d d = Eigen::Vector3d::Zero();
  for (std::size_t i = 1; i <= points_per_segment; ++i) {
    const double from = proximal_.length * (static_cast<double>(i - 1) / count);
    const double to = proximal_.length * (static_cast<double>(i) / count);
    d += integrate_between(proximal_, from, to, q[2], piece_intervals, false);
    out[n++] = base + R * d;
  }
  base = out[n - 1];
  R = R * rot_y(half_pi - tip_angle(CatheterSegment::kProximal, q[2])) * rot_z(plane_offset_) *
      rot_x(flexure_);
  d.setZero();
  for (std::size_t i = 1; i <= points_per_segment; ++i) {
    const double from = distal_.length * (static_cast<double>(i - 1) / count);
    const double to = distal_.length * (static_cast<double>(i) / count);
    d += integrate_between(distal_, from, to, q[3], piece_intervals, false);
    out[n++] = base + R * d;
  }
  return n;
}

}  // namespace tendril::teleop
