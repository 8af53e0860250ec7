#include "tendril/ultrasound/hand_eye.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>
#include <Eigen/SVD>

namespace tendril::ultrasound {

namespace {

using Eigen::Isometry3d;
using Eigen::Matrix3d;
using Eigen::Vector3d;

Vector3d log_rotation(const Matrix3d& r) {
  const Eigen::AngleAxisd aa(r);
  return aa.angle() * aa.axis();
}

Matrix3d exp_rotation(const Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-15) return Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// The rotation nearest (Frobenius) to m: U diag(1, 1, det(UVᵀ)) Vᵀ.
Matrix3d nearest_rotation(const Matrix3d& m) {
  const Eigen::JacobiSVD<Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Matrix3d d = Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

bool rigid(const Isometry3d& t) {
  if (!t.matrix().allFinite()) return false;
  const Matrix3d r = t.linear();
  return (r.transpose() * r - Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-6 && r.determinant() > 0;
}

// X·exp(δ): the right perturbation by a twist δ = (ω, v) (v in the frame of X).
Isometry3d perturb(const Isometry3d& x, const Eigen::Matrix<double, 6, 1>& d) {
  Isometry3d e = Isometry3d::Identity();
  e.linear() = exp_rotation(d.head<3>());
  e.translation() = d.tail<3>();
  return x * e;
}

void residual(const HandEyePair& p, const Isometry3d& x, const Isometry3d& y, double weight,
              Eigen::Ref<Eigen::Matrix<double, 6, 1>> r) {
  const Isometry3d left = p.tracked * x;
  const Isometry3d right = y * p.kinematic;
  r.head<3>() = left.translation() - right.translation();
  r.tail<3>() = weight * log_rotation(right.linear().transpose() * left.linear());
}

void statistics(std::span<const HandEyePair> pairs, const Isometry3d& x, const Isometry3d& y,
                HandEyeResult& out) {
  double sp = 0, sr = 0;
  out.max_position_mm = out.max_rotation_rad = 0;
  for (const auto& p : pairs) {
    Eigen::Matrix<double, 6, 1> r;
    residual(p, x, y, 1.0, r);
    const double dp = r.head<3>().norm(), dr = r.tail<3>().norm();
    sp += dp * dp;
    sr += dr * dr;
    out.max_position_mm = std::max(out.max_position_mm, dp);
    out.max_rotation_rad = std::max(out.max_rotation_rad, dr);
  }
  out.rms_position_mm = std::sqrt(sp / static_cast<double>(pairs.size()));
  out.rms_rotation_rad = std::sqrt(sr / static_cast<double>(pairs.size()));
}

HandEyeResult refuse(HandEyeResult out, const char* format, double a = 0, double b = 0) {
  char text[320];
  std::snprintf(text, sizeof text, format, a, b);
  out.ok = false;
  out.message = text;
  return out;
}

}  // namespace

HandEyeResult solve_hand_eye(std::span<const HandEyePair> pairs, const HandEyeOptions& options) {
  HandEyeResult out;
  out.pairs = static_cast<int>(pairs.size());
  if (out.pairs < options.min_pairs)
    return refuse(out, "robot–world calibration needs at least %.0f poses; it has %.0f",
                  static_cast<double>(options.min_pairs), static_cast<double>(out.pairs));
  for (std::size_t k = 0; k < pairs.size(); ++k)
    if (!rigid(pairs[k].tracked) || !rigid(pairs[k].kinematic))
      return refuse(out, "robot–world calibration: pose %.0f is not a finite rigid transform",
                    static_cast<double>(k));

  // 1. Rotations from every pair of poses.
  Matrix3d spread = Matrix3d::Zero();
  Matrix3d correlation = Matrix3d::Zero();
  int motions = 0;
  for (std::size_t i = 0; i < pairs.size(); ++i)
    for (std::size_t j = i + 1; j < pairs.size(); ++j) {
      const Vector3d alpha = log_rotation(pairs[j].tracked.linear().transpose() * pairs[i].tracked.linear());
      const Vector3d beta =
          log_rotation(pairs[j].kinematic.linear().transpose() * pairs[i].kinematic.linear());
      spread += beta * beta.transpose();
      correlation += alpha * beta.transpose();
      ++motions;
    }
  spread /= static_cast<double>(motions);
  const Eigen::SelfAdjointEigenSolver<Matrix3d> eigen(spread);
  out.rotation_spread_rad = std::sqrt(std::max(0.0, eigen.eigenvalues()(1)));
  if (out.rotation_spread_rad < options.min_rotation_spread_rad)
    return refuse(
        out,
        "robot–world calibration: the poses turn too little, or about one axis only (rotation spread "
        "%.4f rad, at least %.4f needed); choose poses that tilt the probe about two different axes",
        out.rotation_spread_rad, options.min_rotation_spread_rad);
  const Matrix3d rx = nearest_rotation(correlation);
  Matrix3d sum = Matrix3d::Zero();
  for (const auto& p : pairs) sum += p.tracked.linear() * rx * p.kinematic.linear().transpose();
  const Matrix3d ry = nearest_rotation(sum);

  // 2. Translations: R_Ak t_X − t_Y = R_Y t_Fk − t_Ak.
  const auto rows = static_cast<Eigen::Index>(3 * pairs.size());
  Eigen::MatrixXd a(rows, 6);
  Eigen::VectorXd b(rows);
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const auto r = static_cast<Eigen::Index>(3 * k);
    a.block<3, 3>(r, 0) = pairs[k].tracked.linear();
    a.block<3, 3>(r, 3) = -Matrix3d::Identity();
    b.segment<3>(r) = ry * pairs[k].kinematic.translation() - pairs[k].tracked.translation();
  }
  const Eigen::VectorXd t = a.colPivHouseholderQr().solve(b);
  Isometry3d x = Isometry3d::Identity(), y = Isometry3d::Identity();
  x.linear() = rx;
  x.translation() = t.head<3>();
  y.linear() = ry;
  y.translation() = t.tail<3>();
  statistics(pairs, x, y, out);
  out.closed_form_rms_position_mm = out.rms_position_mm;

  // 3. Gauss–Newton on (X, Y), numerical Jacobian (central differences).
  const double w = options.rotation_weight_mm_per_rad;
  Eigen::VectorXd r(6 * pairs.size()), r_plus(6 * pairs.size()), r_minus(6 * pairs.size());
  Eigen::MatrixXd jac(6 * pairs.size(), 12);
  auto evaluate = [&](const Isometry3d& xx, const Isometry3d& yy, Eigen::VectorXd& into) {
    for (std::size_t k = 0; k < pairs.size(); ++k)
      residual(pairs[k], xx, yy, w, into.segment<6>(static_cast<Eigen::Index>(6 * k)));
  };
  for (int iteration = 0; iteration < options.gauss_newton_iterations; ++iteration) {
    evaluate(x, y, r);
    for (int c = 0; c < 12; ++c) {
      Eigen::Matrix<double, 6, 1> d = Eigen::Matrix<double, 6, 1>::Zero();
      const double h = (c % 6) < 3 ? 1e-6 : 1e-4;  // rad, mm
      d(c % 6) = h;
      if (c < 6) {
        evaluate(perturb(x, d), y, r_plus);
        evaluate(perturb(x, -d), y, r_minus);
      } else {
        evaluate(x, perturb(y, d), r_plus);
        evaluate(x, perturb(y, -d), r_minus);
      }
      jac.col(c) = (r_plus - r_minus) / (2 * h);
    }
    const Eigen::Matrix<double, 12, 1> step = (jac.transpose() * jac).ldlt().solve(-jac.transpose() * r);
    if (!step.allFinite()) break;
    x = perturb(x, step.head<6>());
    y = perturb(y, step.tail<6>());
    out.iterations = iteration + 1;
    if (step.cwiseAbs().maxCoeff() < 1e-9) break;
  }
  // Re-orthonormalise against drift of the repeated products.
  x.linear() = nearest_rotation(x.linear());
  y.linear() = nearest_rotation(y.linear());
  out.marker_T_probe = x;
  out.world_T_base = y;
  statistics(pairs, x, y, out);
  out.ok = true;
  char text[256];
  std::snprintf(text, sizeof text,
                "robot–world calibration from %d poses: residual %.2f mm rms (max %.2f), %.3f° rms; rotation "
                "spread %.3f rad",
                out.pairs, out.rms_position_mm, out.max_position_mm, out.rms_rotation_rad * 180.0 / M_PI,
                out.rotation_spread_rad);
  out.message = text;
  return out;
}

}  // namespace tendril::ultrasound
