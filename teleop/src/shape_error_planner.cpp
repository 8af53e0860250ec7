#include "tendril/teleop/shape_error_planner.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRadToDeg = 180.0 / kPi;

// Same closed forms as catheter_kinematics.cpp (eq. 4.6), kept local so points can be evaluated at
// arbitrary arc lengths; steerable_point() is tested against ConstantCurvatureCatheter::backbone.
double one_minus_cos_over(double x) noexcept {
  if (std::abs(x) < 1e-4) return x * (0.5 - x * x / 24.0);
  return (1.0 - std::cos(x)) / x;
}
double sin_over(double x) noexcept {
  if (std::abs(x) < 1e-4) return 1.0 - x * x / 6.0;
  return std::sin(x) / x;
}
Eigen::Matrix3d rot(double a, const Eigen::Vector3d& axis) noexcept {
  return Eigen::AngleAxisd(a, axis).toRotationMatrix();
}

// Shape of the two steerable segments for one (q2, q3, q4), base at the origin with tangent +z.
struct SteerableShape {
  Eigen::Matrix3d R1, R2;
  Eigen::Vector3d p2;
  double bend1, bend2, L1, L2;

  SteerableShape(const CatheterParameters& P, double roll, double q3, double q4, double flexure) noexcept
      : L1(P.proximal_length), L2(P.distal_length) {
    bend1 = P.proximal_curvature_gain * q3;
    bend2 = P.distal_curvature_gain * q4;
    R1 = rot(roll, Eigen::Vector3d::UnitZ());
    p2 = R1 * Eigen::Vector3d(L1 * one_minus_cos_over(bend1), 0.0, L1 * sin_over(bend1));
    R2 = R1 * rot(bend1, Eigen::Vector3d::UnitY()) * rot(P.plane_offset, Eigen::Vector3d::UnitZ()) *
         rot(flexure, Eigen::Vector3d::UnitX());
  }

  Eigen::Vector3d point(double sigma, Eigen::Vector3d& tangent) const noexcept {
    const bool proximal = sigma <= L1;
    const double local = proximal ? sigma : sigma - L1;
    const double bend = proximal ? bend1 * sigma / L1 : bend2 * local / L2;
    const Eigen::Matrix3d& R = proximal ? R1 : R2;
    tangent = R * Eigen::Vector3d(std::sin(bend), 0.0, std::cos(bend));
    const Eigen::Vector3d p =
        R * Eigen::Vector3d(local * one_minus_cos_over(bend), 0.0, local * sin_over(bend));
    return proximal ? p : Eigen::Vector3d(p2 + p);
  }
};

// Eq. 4.20 soft step over the position u = v_k/n_k ∈ (0, 1] along a segment.
double tip_ramp(double u) noexcept { return 0.5 * (1.0 + std::tanh(5.0 * (u - 0.5))); }

double wrap_angle(double a) noexcept { return std::remainder(a, 2.0 * kPi); }

}  // namespace

CatheterParameters nominal_planning_design() {
  CatheterParameters p;
  p.proximal_length = 22.0;
  p.distal_length = 18.8;
  p.plane_offset = -0.76;
  p.proximal_curvature_gain = 1.4;
  p.distal_curvature_gain = 1.4;
  return p;
}

ShapeErrorPlanner::ShapeErrorPlanner(const ConstantCurvatureCatheter& model,
                                     const ShapeErrorPlannerOptions& options)
    : model_(model), options_(options) {
  const auto& o = options;
  auto require = [](bool ok, const std::string& message) {
    if (!ok) throw PlannerOptionsError("ShapeErrorPlanner: " + message);
  };
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  auto non_negative = [](double v) { return std::isfinite(v) && v >= 0.0; };
  require(positive(o.insertion_step), "insertion_step dq1 must be > 0 mm");
  require(positive(o.position_error_range), "position_error_range must be > 0 mm");
  require(positive(o.tangent_error_range), "tangent_error_range must be > 0 rad");
  require(non_negative(o.tangent_to_position_ratio), "tangent_to_position_ratio r_tp must be >= 0");
  require(non_negative(o.proximal_to_distal_ratio), "proximal_to_distal_ratio r_seg must be >= 0");
  require(std::isfinite(o.proximal_drive_min) && std::isfinite(o.proximal_drive_max) &&
              o.proximal_drive_min <= 0.0 && o.proximal_drive_max >= 0.0 &&
              o.proximal_drive_min < o.proximal_drive_max,
          "q3 limits must be finite with min <= 0 <= max and min < max");
  require(std::isfinite(o.distal_drive_min) && std::isfinite(o.distal_drive_max) &&
              o.distal_drive_min <= 0.0 && o.distal_drive_max >= 0.0 &&
              o.distal_drive_min < o.distal_drive_max,
          "q4 limits must be finite with min <= 0 <= max and min < max");
  require(o.max_iterations > 0, "max_iterations must be > 0");
  require(positive(o.initial_damping), "initial_damping must be > 0");
  require(non_negative(o.relative_cost_tolerance) && non_negative(o.step_tolerance),
          "tolerances must be >= 0");
  require(!o.free_flexure || (std::isfinite(o.flexure_min) && std::isfinite(o.flexure_max) &&
                              o.flexure_min <= 0.0 && o.flexure_max >= 0.0 && o.flexure_min < o.flexure_max),
          "flexure limits must be finite with min <= 0 <= max and min < max");
  // Roll is periodic and wrapped to (−π, π], so it needs no bounds. Without a free flexure γ is held
  // at the design's value (its bounds collapse onto it).
  const double inf = std::numeric_limits<double>::infinity();
  const double gamma = model.parameters().flexure;
  lower_ = {-inf, o.proximal_drive_min, o.distal_drive_min, o.free_flexure ? o.flexure_min : gamma};
  upper_ = {inf, o.proximal_drive_max, o.distal_drive_max, o.free_flexure ? o.flexure_max : gamma};
}

Eigen::Vector3d ShapeErrorPlanner::steerable_point(const JointVector& q, double sigma,
                                                   Eigen::Vector3d* tangent) const noexcept {
  const SteerableShape shape(model_.parameters(), q[1], q[2], q[3], model_.parameters().flexure);
  Eigen::Vector3d t;
  Eigen::Vector3d p = shape.point(sigma, t) + Eigen::Vector3d(0.0, 0.0, q[0]);
  if (tangent != nullptr) *tangent = t;
  return p;
}

void ShapeErrorPlanner::build_transport_frames(const VesselCenterline& aligned) {
  const auto& t = aligned.tangents();
  transport_.resize(t.size());
  transport_[0] = Eigen::Matrix3d::Identity();  // aligned: first tangent is +z
  for (std::size_t i = 1; i < t.size(); ++i) {
    transport_[i] = Eigen::Quaterniond::FromTwoVectors(t[i - 1], t[i]).toRotationMatrix() * transport_[i - 1];
  }
}

ShapeErrorPlanner::Base ShapeErrorPlanner::base_frame(const VesselCenterline& aligned,
                                                      double arc_length) const noexcept {
  if (arc_length <= 0.0) return {Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, arc_length)};
  const double ds = aligned.spacing();
  const std::size_t last = aligned.size() - 1;
  const auto i = std::min(static_cast<std::size_t>(arc_length / ds), last);
  if (i == last) return {transport_[last], aligned.points()[last]};
  const double u = arc_length / ds - static_cast<double>(i);
  const auto& P = aligned.points();
  const auto& T = aligned.tangents();
  const Eigen::Vector3d tangent = ((1.0 - u) * T[i] + u * T[i + 1]).normalized();
  return {Eigen::Quaterniond::FromTwoVectors(T[i], tangent).toRotationMatrix() * transport_[i],
          (1.0 - u) * P[i] + u * P[i + 1]};
}

double ShapeErrorPlanner::evaluate(const Eigen::Vector4d& x, Eigen::VectorXd& residual) const noexcept {
  const SteerableShape shape(model_.parameters(), x[0], x[1], x[2], x[3]);
  const double tangent_factor = options_.tangent_to_position_ratio / options_.tangent_error_range;
  Eigen::Vector3d t;
  for (std::size_t k = 0; k < active_; ++k) {
    const Eigen::Vector3d p = base_.rotation * shape.point(sigmas_[k], t) + base_.position;
    const double w = std::sqrt(weights_[k]);
    residual.segment<3>(static_cast<Eigen::Index>(6 * k)) = w * (p - targets_[k]);
    residual.segment<3>(static_cast<Eigen::Index>(6 * k + 3)) =
        std::sqrt(tangent_factor) * w * (base_.rotation * t - target_tangents_[k]);
  }
  return residual.head(static_cast<Eigen::Index>(6 * active_)).squaredNorm();
}

PlanStep ShapeErrorPlanner::solve_step(const VesselCenterline& aligned, double q1,
                                       const Eigen::Vector4d& start) {
  const auto& P = model_.parameters();
  const double L1 = P.proximal_length, L2 = P.distal_length;
  const double ds = aligned.spacing();
  const double base_arc = q1 - (L1 + L2);
  base_ = base_frame(aligned, base_arc);

  // Inserted vessel samples on the steerable section: max(s_b, 0) ≤ s_i ≤ q1 (eq. 4.16).
  const double eps = 1e-9 * ds;
  const auto first = static_cast<std::size_t>(std::ceil(std::max(base_arc, 0.0) / ds - 1e-9));
  const auto last = std::min(static_cast<std::size_t>(std::floor(q1 / ds + 1e-9)), aligned.size() - 1);
  active_ = 0;
  for (std::size_t i = first; i <= last; ++i) {
    const double sigma = std::clamp(aligned.arc_length(i) - base_arc, 0.0, L1 + L2 + eps);
    const double weight =
        sigma <= L1 ? options_.proximal_to_distal_ratio * tip_ramp(sigma / L1) : tip_ramp((sigma - L1) / L2);
    sigmas_[active_] = sigma;
    weights_[active_] = weight / options_.position_error_range;
    targets_[active_] = aligned.points()[i];
    target_tangents_[active_] = aligned.tangents()[i];
    ++active_;
  }
  const auto rows = static_cast<Eigen::Index>(6 * active_);

  PlanStep step;
  step.q[0] = q1;
  step.points = active_;

  // Candidate starts: the warm start plus bent starts in four roll directions, because at q3 = q4 = 0
  // the roll has no effect (zero gradient) and a vessel bending out of the current plane is a saddle.
  std::array<Eigen::Vector4d, 5> candidates;
  std::size_t count = 0;
  if (options_.warm_start) candidates[count++] = start;
  const double bent = std::min(0.5, 0.5 * options_.proximal_drive_max);
  for (int r = 0; r < 4; ++r) candidates[count++] = Eigen::Vector4d(r * 0.5 * kPi, bent, 0.0, start[3]);
  Eigen::Vector4d x = candidates[0];
  double cost = evaluate(x, residual_);
  for (std::size_t c = 1; c < count; ++c) {
    const double candidate_cost = evaluate(candidates[c], trial_residual_);
    if (candidate_cost < cost) {
      cost = candidate_cost;
      x = candidates[c];
    }
  }
  cost = evaluate(x, residual_);

  // Levenberg–Marquardt with Marquardt scaling, central-difference Jacobian and an active set for the
  // drive limits (a coordinate at a bound whose gradient pushes outwards is held fixed).
  double lambda = options_.initial_damping;
  int iterations = 0;
  bool converged = cost <= 0.0;
  const int unknowns = options_.free_flexure ? 4 : 3;
  while (!converged && iterations < options_.max_iterations) {
    jacobian_.col(3).head(rows).setZero();
    for (int j = 0; j < unknowns; ++j) {
      const double h = 1e-6 * std::max(1.0, std::abs(x[j]));
      Eigen::Vector4d xp = x, xm = x;
      xp[j] += h;
      xm[j] -= h;
      evaluate(xp, plus_);
      evaluate(xm, minus_);
      jacobian_.col(j).head(rows) = (plus_.head(rows) - minus_.head(rows)) / (2.0 * h);
    }
    const auto J = jacobian_.topRows(rows);
    const Eigen::Matrix4d A = J.transpose() * J;
    const Eigen::Vector4d g = J.transpose() * residual_.head(rows);
    std::array<bool, 4> fixed{};
    for (int j = 0; j < 4; ++j)
      fixed[j] = j >= unknowns || (x[j] <= lower_[j] && g[j] > 0.0) || (x[j] >= upper_[j] && g[j] < 0.0);
    double g_free = 0.0;
    for (int j = 0; j < 4; ++j)
      if (!fixed[j]) g_free = std::max(g_free, std::abs(g[j]));
    if (g_free < 1e-15) break;
    const double diag_floor = 1e-9 * std::max(1.0, A.diagonal().maxCoeff());
    while (iterations < options_.max_iterations) {
      ++iterations;
      Eigen::Matrix4d M = A;
      Eigen::Vector4d rhs = -g;
      for (int j = 0; j < 4; ++j) {
        M(j, j) += lambda * std::max(A(j, j), diag_floor);
        if (fixed[j]) {
          M.row(j).setZero();
          M.col(j).setZero();
          M(j, j) = 1.0;
          rhs[j] = 0.0;
        }
      }
      const Eigen::Vector4d delta = M.ldlt().solve(rhs);
      Eigen::Vector4d candidate = (x + delta).cwiseMax(lower_).cwiseMin(upper_);
      candidate[0] = wrap_angle(candidate[0]);
      const double candidate_cost = evaluate(candidate, trial_residual_);
      if (candidate_cost < cost) {
        const double improvement = (cost - candidate_cost) / std::max(cost, 1e-300);
        const double step_size = (candidate - x).cwiseAbs().maxCoeff();
        x = candidate;
        cost = candidate_cost;
        residual_.head(rows) = trial_residual_.head(rows);
        lambda = std::max(lambda / 3.0, 1e-15);
        converged = improvement < options_.relative_cost_tolerance || step_size < options_.step_tolerance;
        break;
      }
      lambda *= 4.0;
      if (lambda > 1e15 || delta.cwiseAbs().maxCoeff() < options_.step_tolerance) {
        converged = true;  // no descent left at machine precision: a (constrained) minimum
        break;
      }
    }
  }

  step.q[1] = x[0];
  step.q[2] = x[1];
  step.q[3] = x[2];
  step.flexure = x[3];
  step.cost = cost;
  step.iterations = iterations;
  step.design = P;
  step.design.flexure = x[3];
  step.base_rotation = from_aligned_.transpose() * base_.rotation;
  step.base_position = from_aligned_.transpose() * (base_.position - aligned_offset_);
  const SteerableShape shape(P, x[0], x[1], x[2], x[3]);
  Eigen::Vector3d t;
  double position_sum = 0.0, tangent_sum = 0.0;
  for (std::size_t k = 0; k < active_; ++k) {
    const Eigen::Vector3d p = base_.rotation * shape.point(sigmas_[k], t) + base_.position;
    const Eigen::Vector3d tw = base_.rotation * t;
    const double position_error = (p - targets_[k]).norm();
    const double tangent_error =
        kRadToDeg * std::atan2(tw.cross(target_tangents_[k]).norm(), tw.dot(target_tangents_[k]));
    position_sum += position_error;
    tangent_sum += tangent_error;
    step.position_error_max = std::max(step.position_error_max, position_error);
    step.tangent_error_max = std::max(step.tangent_error_max, tangent_error);
  }
  if (active_ > 0) {
    step.position_error_mean = position_sum / static_cast<double>(active_);
    step.tangent_error_mean = tangent_sum / static_cast<double>(active_);
  }
  return step;
}

PathPlan ShapeErrorPlanner::plan(const VesselCenterline& vessel) { return plan(vessel, JobControl{}); }

PathPlan ShapeErrorPlanner::plan(const VesselCenterline& vessel, const JobControl& job) {
  // The transform of VesselCenterline::aligned_to_insertion(), kept to map results back.
  const Eigen::Isometry3d alignment = vessel.insertion_alignment();
  from_aligned_ = alignment.linear();
  aligned_offset_ = alignment.translation();
  const VesselCenterline aligned = vessel.transformed(from_aligned_, aligned_offset_);
  const double dq1 = options_.insertion_step;
  if (aligned.length() + 1e-9 < dq1) {
    throw VesselInputError("ShapeErrorPlanner: vessel length " + std::to_string(aligned.length()) +
                           " mm is shorter than one insertion step of " + std::to_string(dq1) + " mm");
  }
  build_transport_frames(aligned);
  const auto& P = model_.parameters();
  const auto capacity =
      static_cast<std::size_t>((P.proximal_length + P.distal_length) / aligned.spacing()) + 3;
  sigmas_.resize(capacity);
  weights_.resize(capacity);
  targets_.resize(capacity);
  target_tangents_.resize(capacity);
  for (auto* v : {&residual_, &trial_residual_, &plus_, &minus_})
    v->resize(static_cast<Eigen::Index>(6 * capacity));
  jacobian_.resize(static_cast<Eigen::Index>(6 * capacity), 4);

  PathPlan plan;
  plan.design = P;
  plan.free_flexure = options_.free_flexure;
  const auto steps = static_cast<std::size_t>(std::floor(aligned.length() / dq1 + 1e-9));
  plan.steps.reserve(steps);
  Eigen::Vector4d start(0.0, 0.0, 0.0, P.flexure);
  double position_sum = 0.0, tangent_sum = 0.0;
  std::size_t point_count = 0;
  for (std::size_t k = 1; k <= steps; ++k) {
    job.check_cancelled();
    const PlanStep step = solve_step(aligned, dq1 * static_cast<double>(k), start);
    start = Eigen::Vector4d(step.q[1], step.q[2], step.q[3], step.flexure);
    position_sum += step.position_error_mean * static_cast<double>(step.points);
    tangent_sum += step.tangent_error_mean * static_cast<double>(step.points);
    point_count += step.points;
    plan.position_error_max = std::max(plan.position_error_max, step.position_error_max);
    plan.tangent_error_max = std::max(plan.tangent_error_max, step.tangent_error_max);
    plan.total_iterations += step.iterations;
    plan.steps.push_back(step);
    job.report(static_cast<double>(k) / static_cast<double>(steps));
  }
  if (point_count > 0) {
    plan.position_error_mean = position_sum / static_cast<double>(point_count);
    plan.tangent_error_mean = tangent_sum / static_cast<double>(point_count);
  }
  return plan;
}

std::vector<Eigen::Vector3d> planned_backbone(const PlanStep& step, double spacing) {
  if (!(std::isfinite(spacing) && spacing >= 0.01)) {
    throw PlannerOptionsError("planned_backbone: spacing must be at least 0.01 mm, got " +
                              std::to_string(spacing));
  }
  const auto& P = step.design;
  const SteerableShape shape(P, step.q[1], step.q[2], step.q[3], step.flexure);
  const double length = P.proximal_length + P.distal_length;
  const auto intervals = static_cast<std::size_t>(std::ceil(length / spacing - 1e-9));
  std::vector<Eigen::Vector3d> points;
  points.reserve(intervals + 1);
  Eigen::Vector3d tangent;
  for (std::size_t i = 0; i <= intervals; ++i) {
    const double sigma = std::min(length, spacing * static_cast<double>(i));
    points.push_back(step.base_rotation * shape.point(sigma, tangent) + step.base_position);
  }
  return points;
}

}  // namespace tendril::teleop
