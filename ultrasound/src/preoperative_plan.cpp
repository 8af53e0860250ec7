// Pre-operative planning: ICP, Algorithm 1, Algorithm 2 (Heunis et al. 2021, §2.4); see the header.
#include "tendril/ultrasound/preoperative_plan.hpp"

#include <Eigen/Dense>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

namespace tendril::ultrasound {
namespace {

void require_finite(const std::vector<Eigen::Vector3d>& points, const char* what) {
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!points[i].allFinite()) {
      throw PlanningInputError(std::string(what) + ": point " + std::to_string(i) + " is not finite");
    }
  }
}

}  // namespace

Eigen::Isometry3d rigid_fit(const std::vector<Eigen::Vector3d>& source,
                            const std::vector<Eigen::Vector3d>& target) {
  if (source.size() != target.size() || source.size() < 3) {
    throw PlanningInputError("rigid_fit: needs at least 3 point pairs, got " + std::to_string(source.size()) +
                             " and " + std::to_string(target.size()) + " points");
  }
  require_finite(source, "rigid_fit source");
  require_finite(target, "rigid_fit target");
  Eigen::Vector3d mean_s = Eigen::Vector3d::Zero(), mean_t = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < source.size(); ++i) {
    mean_s += source[i];
    mean_t += target[i];
  }
  mean_s /= static_cast<double>(source.size());
  mean_t /= static_cast<double>(source.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < source.size(); ++i)
    covariance += (source[i] - mean_s) * (target[i] - mean_t).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(covariance, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d correction = Eigen::Matrix3d::Identity();
  // A reflection is not a rigid motion: flip the weakest axis so that det R = +1.
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0.0) correction(2, 2) = -1.0;
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  transform.linear() = svd.matrixV() * correction * svd.matrixU().transpose();
  transform.translation() = mean_t - transform.linear() * mean_s;
  return transform;
}

IcpResult icp(const std::vector<Eigen::Vector3d>& model, const std::vector<Eigen::Vector3d>& data,
              const Eigen::Isometry3d* initial, const IcpOptions& options) {
  if (model.size() < 3 || data.size() < 3) {
    throw PlanningInputError("icp: both clouds need at least 3 points, got " + std::to_string(model.size()) +
                             " (model) and " + std::to_string(data.size()) + " (data)");
  }
  if (options.max_iterations < 1 || !(options.tolerance > 0.0)) {
    throw PlanningInputError("icp: max_iterations must be >= 1 and tolerance > 0");
  }
  require_finite(model, "icp model");
  require_finite(data, "icp data");
  IcpResult result;
  if (initial != nullptr) {
    result.transform = *initial;
  } else {
    Eigen::Vector3d mean_m = Eigen::Vector3d::Zero(), mean_d = Eigen::Vector3d::Zero();
    for (const auto& p : model) mean_m += p;
    for (const auto& p : data) mean_d += p;
    result.transform.translation() =
        mean_m / static_cast<double>(model.size()) - mean_d / static_cast<double>(data.size());
  }
  std::vector<Eigen::Vector3d> moved(data.size()), matched(data.size());
  double previous_rms = std::numeric_limits<double>::infinity();
  for (int iteration = 1; iteration <= options.max_iterations; ++iteration) {
    double sum = 0.0;
    for (std::size_t i = 0; i < data.size(); ++i) {
      moved[i] = result.transform * data[i];
      double best = std::numeric_limits<double>::infinity();
      for (const auto& m : model) {
        const double d = (m - moved[i]).squaredNorm();
        if (d < best) {
          best = d;
          matched[i] = m;
        }
      }
      sum += best;
    }
    result.rms = std::sqrt(sum / static_cast<double>(data.size()));
    result.iterations = iteration;
    if (std::abs(previous_rms - result.rms) < options.tolerance) {
      result.converged = true;
      break;
    }
    previous_rms = result.rms;
    result.transform = rigid_fit(moved, matched) * result.transform;
  }
  return result;
}

std::vector<Eigen::Vector3d> arterial_centroids(const std::vector<Eigen::Vector3d>& wall_ct,
                                                const Eigen::Isometry3d& ct_to_tissue,
                                                const CentroidPlanOptions& options) {
  if (options.count < 2 || options.count > 10'000) {
    throw PlanningInputError("Algorithm 1: the number of centroids n must lie in 2..10000, got " +
                             std::to_string(options.count));
  }
  if (!std::isfinite(options.end_x) || std::isnan(options.start_x)) {
    throw PlanningInputError("Algorithm 1: the endpoint p_d must be finite");
  }
  require_finite(wall_ct, "Algorithm 1 vessel cloud B");
  // Lines 3–4: into {P}, rows sorted by x, truncated to the span the user chose.
  std::vector<Eigen::Vector3d> kept;
  kept.reserve(wall_ct.size());
  for (const auto& b : wall_ct) {
    const Eigen::Vector3d p = ct_to_tissue * b;
    if (p.x() >= options.start_x && p.x() <= options.end_x) kept.push_back(p);
  }
  std::sort(kept.begin(), kept.end(), [](const auto& a, const auto& b) { return a.x() < b.x(); });
  if (kept.size() < 5) {
    throw PlanningInputError(
        "Algorithm 1: " + std::to_string(kept.size()) +
        " vessel points lie between the start and the endpoint; a quartic needs at least 5");
  }
  const double x0 = kept.front().x(), length = kept.back().x() - x0;
  if (!(length >= 1.0)) {
    throw PlanningInputError("Algorithm 1: the vessel points span " + std::to_string(length) +
                             " mm in x; at least 1 mm is needed (is the cloud in millimetres?)");
  }
  // Lines 5–8 : v = (x − x_min)/L, S_a = [1 v v² v³ v⁴].
  Eigen::MatrixXd sa(static_cast<Eigen::Index>(kept.size()), 5);
  Eigen::MatrixXd rhs(static_cast<Eigen::Index>(kept.size()), 3);
  for (std::size_t j = 0; j < kept.size(); ++j) {
    const double v = (kept[j].x() - x0) / length;
    double power = 1.0;
    for (int d = 0; d < 5; ++d, power *= v) sa(static_cast<Eigen::Index>(j), d) = power;
    rhs.row(static_cast<Eigen::Index>(j)) = kept[j].transpose();
  }
  // Lines 9–11: S_a \ B_P by QR, one solve for the three coordinates.
  const Eigen::MatrixXd coefficients = sa.colPivHouseholderQr().solve(rhs);
  std::vector<Eigen::Vector3d> centroids(static_cast<std::size_t>(options.count));
  for (int i = 0; i < options.count; ++i) {
    const double v = static_cast<double>(i) / (options.count - 1);
    Eigen::Matrix<double, 1, 5> sb;
    double power = 1.0;
    for (int d = 0; d < 5; ++d, power *= v) sb(d) = power;
    centroids[static_cast<std::size_t>(i)] = (sb * coefficients).transpose();
  }
  return centroids;
}

Eigen::Isometry3d ProbeViaPoint::pose() const {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = rotation;
  pose.translation() = surface_point;
  return pose;
}

std::vector<ProbeViaPoint> probe_via_points(const std::vector<Eigen::Vector3d>& surface,
                                            const std::vector<Eigen::Vector3d>& centroids,
                                            const ViaPointOptions& options) {
  if (centroids.size() < 2) {
    throw PlanningInputError("Algorithm 2: needs at least 2 centroids, got " +
                             std::to_string(centroids.size()));
  }
  if (surface.empty()) throw PlanningInputError("Algorithm 2: the surface cloud C is empty");
  if (!options.up.allFinite() || options.up.norm() < 1e-9 || options.nearest < 1) {
    throw PlanningInputError("Algorithm 2: `up` must be a finite non-zero vector and `nearest` >= 1");
  }
  require_finite(surface, "Algorithm 2 surface cloud C");
  require_finite(centroids, "Algorithm 2 centroids");
  const Eigen::Vector3d up = options.up.normalized();
  const std::size_t k = static_cast<std::size_t>(options.nearest);
  std::vector<ProbeViaPoint> plan(centroids.size());
  std::vector<std::pair<double, std::size_t>> candidates;
  // Line 2 (with our reading of it): ‖(C_j − c_i) × ŷ‖ is the distance to the vertical through c_i.
  for (std::size_t i = 0; i < centroids.size(); ++i) {
    candidates.clear();
    for (std::size_t j = 0; j < surface.size(); ++j) {
      const Eigen::Vector3d d = surface[j] - centroids[i];
      if (d.dot(up) <= 0.0) continue;
      candidates.emplace_back(d.cross(up).norm(), j);
    }
    if (candidates.empty()) {
      throw PlanningInputError("Algorithm 2: no surface point lies above centroid " + std::to_string(i));
    }
    const std::size_t take = std::min(k, candidates.size());
    std::partial_sort(candidates.begin(), candidates.begin() + static_cast<std::ptrdiff_t>(take),
                      candidates.end());
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (std::size_t t = 0; t < take; ++t) mean += surface[candidates[t].second];
    plan[i].surface_point = mean / static_cast<double>(take);
  }
  // Lines 3–7 (axes as columns; the last point reuses the previous direction).
  Eigen::Vector3d previous_y = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < centroids.size(); ++i) {
    const Eigen::Vector3d z = (centroids[i] - plan[i].surface_point).normalized();
    const std::size_t a = i + 1 < centroids.size() ? i : i - 1;
    const Eigen::Vector3d sweep = (plan[a + 1].surface_point - plan[a].surface_point).normalized();
    Eigen::Vector3d y = z.cross(sweep);
    if (y.norm() < 1e-6 || !y.allFinite()) {
      if (previous_y.isZero()) {
        throw PlanningInputError("Algorithm 2: the sweep direction at via-point " + std::to_string(i) +
                                 " is parallel to the probe axis (coincident surface points?)");
      }
      y = previous_y - previous_y.dot(z) * z;  // Reuse the previous y axis
    }
    y.normalize();
    const Eigen::Vector3d x = y.cross(z).normalized();
    plan[i].rotation.col(0) = x;
    plan[i].rotation.col(1) = y;
    plan[i].rotation.col(2) = z;
    previous_y = y;
  }
  return plan;
}

}  // namespace tendril::ultrasound
