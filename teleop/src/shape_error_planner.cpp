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

// Derivatives of f(b) = (1 − cos b)/b and g(b) = sin b / b, with series near 0 where the closed forms
// cancel (the series error at |b| = 1e-2 is below 1e-16).
// f(b) = (1 − cos b)/b and g(b) = sin b / b with their derivatives from one sin/cos pair, with series
// near 0 where the closed forms cancel (series errors below 1e-16 at the switch points).
struct ArcFunctions {
  double f, g, df, dg;
};
ArcFunctions arc_functions(double b, double s, double c) noexcept {
  ArcFunctions a{};
  const double b2 = b * b;
  if (std::abs(b) < 1e-4) {
    a.f = b * (0.5 - b2 / 24.0);
    a.g = 1.0 - b2 / 6.0;
  } else {
    a.f = (1.0 - c) / b;
    a.g = s / b;
  }
  if (std::abs(b) < 1e-2) {
    a.df = 0.5 - b2 / 8.0 + b2 * b2 / 144.0 - b2 * b2 * b2 / 5760.0;
    a.dg = b * (-1.0 / 3.0 + b2 / 30.0 - b2 * b2 / 840.0);
  } else {
    a.df = (s - a.f) / b;  // (b·sin b − (1 − cos b))/b²
    a.dg = (c - a.g) / b;  // (b·cos b − sin b)/b²
  }
  return a;
}

// Shape of the two steerable segments for one (q2, q3, q4, γ), base at the origin with tangent +z.
struct SteerableShape {
  Eigen::Matrix3d R1, R2;
  Eigen::Vector3d p2;
  Eigen::Vector3d p2_rate;  // ∂p2/∂bend1
  double bend1, bend2, L1, L2, k1, k2;

  SteerableShape(const CatheterParameters& P, double roll, double q3, double q4, double flexure) noexcept
      : L1(P.proximal_length),
        L2(P.distal_length),
        k1(P.proximal_curvature_gain),
        k2(P.distal_curvature_gain) {
    bend1 = k1 * q3;
    bend2 = k2 * q4;
    R1 = rot(roll, Eigen::Vector3d::UnitZ());
    p2 = R1 * Eigen::Vector3d(L1 * one_minus_cos_over(bend1), 0.0, L1 * sin_over(bend1));
    const ArcFunctions a = arc_functions(bend1, std::sin(bend1), std::cos(bend1));
    p2_rate = R1 * Eigen::Vector3d(L1 * a.df, 0.0, L1 * a.dg);
    R2 = R1 * rot(bend1, Eigen::Vector3d::UnitY()) * rot(P.plane_offset, Eigen::Vector3d::UnitZ()) *
         rot(flexure, Eigen::Vector3d::UnitX());
  }

  Eigen::Vector3d point(double sigma, Eigen::Vector3d& tangent) const noexcept {
    const bool proximal = sigma <= L1;
    const double local = proximal ? sigma : sigma - L1;
    const double bend = proximal ? bend1 * sigma / L1 : bend2 * local / L2;
    const Eigen::Matrix3d& R = proximal ? R1 : R2;
    const double s = std::sin(bend), c = std::cos(bend);
    const ArcFunctions a = arc_functions(bend, s, c);
    tangent = R * Eigen::Vector3d(s, 0.0, c);
    const Eigen::Vector3d p = R * Eigen::Vector3d(local * a.f, 0.0, local * a.g);
    return proximal ? p : Eigen::Vector3d(p2 + p);
  }

  // Point, tangent and their derivatives with respect to x = [q2, q3, q4, γ] (columns):
  //   q2: R1 = e^{q2[ẑ×]} turns everything about ẑ, so ∂/∂q2 = ẑ × (·);
  //   q3: the proximal bend b = k1·q3·σ/L1 inside its arc; on the distal segment it moves p2 and
  //       turns R2 about R1·ŷ;
  //   q4: the distal bend b = k2·q4·(σ − L1)/L2 inside its arc;
  //   γ:  turns the distal segment about R2·x̂ (the flexure axis).
  void derivatives(double sigma, Eigen::Vector3d& p, Eigen::Vector3d& t, Eigen::Matrix<double, 3, 4>& dp,
                   Eigen::Matrix<double, 3, 4>& dt) const noexcept {
    const bool proximal = sigma <= L1;
    const double local = proximal ? sigma : sigma - L1;
    const double rate = proximal ? k1 * sigma / L1 : k2 * local / L2;  // ∂b/∂q3 or ∂b/∂q4
    const double bend = proximal ? bend1 * sigma / L1 : bend2 * local / L2;
    const double s = std::sin(bend), c = std::cos(bend);
    const Eigen::Matrix3d& R = proximal ? R1 : R2;
    const ArcFunctions a = arc_functions(bend, s, c);
    const Eigen::Vector3d arc = R * Eigen::Vector3d(local * a.f, 0.0, local * a.g);
    const Eigen::Vector3d arc_rate = rate * (R * Eigen::Vector3d(local * a.df, 0.0, local * a.dg));
    t = R * Eigen::Vector3d(s, 0.0, c);
    const Eigen::Vector3d t_rate = rate * (R * Eigen::Vector3d(c, 0.0, -s));
    p = proximal ? arc : Eigen::Vector3d(p2 + arc);
    const Eigen::Vector3d z = Eigen::Vector3d::UnitZ();
    dp.col(0) = z.cross(p);
    dt.col(0) = z.cross(t);
    if (proximal) {
      dp.col(1) = arc_rate;
      dt.col(1) = t_rate;
      dp.rightCols<2>().setZero();
      dt.rightCols<2>().setZero();
      return;
    }
    const Eigen::Vector3d y1 = R1.col(1);
    dp.col(1) = k1 * (p2_rate + y1.cross(arc));
    dt.col(1) = k1 * y1.cross(t);
    dp.col(2) = arc_rate;
    dt.col(2) = t_rate;
    const Eigen::Vector3d x2 = R2.col(0);
    dp.col(3) = x2.cross(arc);
    dt.col(3) = x2.cross(t);
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
  tangent_factor_sqrt_ = std::sqrt(o.tangent_to_position_ratio / o.tangent_error_range);
}

Eigen::Vector3d ShapeErrorPlanner::steerable_point(const JointVector& q, double sigma,
                                                   Eigen::Vector3d* tangent) const noexcept {
  const SteerableShape shape(model_.parameters(), q[1], q[2], q[3], model_.parameters().flexure);
  Eigen::Vector3d t;
  Eigen::Vector3d p = shape.point(sigma, t) + Eigen::Vector3d(0.0, 0.0, q[0]);
  if (tangent != nullptr) *tangent = t;
  return p;
}

void ShapeErrorPlanner::build_transport_frames() {
  const auto& t = aligned_->tangents();
  transport_.resize(t.size());
  transport_[0] = Eigen::Matrix3d::Identity();  // aligned: first tangent is +z
  for (std::size_t i = 1; i < t.size(); ++i) {
    transport_[i] = Eigen::Quaterniond::FromTwoVectors(t[i - 1], t[i]).toRotationMatrix() * transport_[i - 1];
  }
}

void ShapeErrorPlanner::prepare(const VesselCenterline& vessel) {
  // The transform of VesselCenterline::aligned_to_insertion(), kept to map results back.
  const Eigen::Isometry3d alignment = vessel.insertion_alignment();
  VesselCenterline aligned = vessel.transformed(alignment.linear(), alignment.translation());
  const double dq1 = options_.insertion_step;
  if (aligned.length() + 1e-9 < dq1) {
    throw VesselInputError("ShapeErrorPlanner: vessel length " + std::to_string(aligned.length()) +
                           " mm is shorter than one insertion step of " + std::to_string(dq1) + " mm");
  }
  from_aligned_ = alignment.linear();
  aligned_offset_ = alignment.translation();
  aligned_.emplace(std::move(aligned));
  build_transport_frames();
}

ShapeErrorPlanner::StepWorkspace ShapeErrorPlanner::make_workspace() const {
  const auto& P = model_.parameters();
  const double ds = aligned_ ? aligned_->spacing() : 0.5;
  const auto capacity = static_cast<std::size_t>((P.proximal_length + P.distal_length) / ds) + 3;
  StepWorkspace ws;
  ws.sigma.resize(capacity);
  ws.sqrt_weight.resize(capacity);
  ws.target.resize(capacity);
  ws.target_tangent.resize(capacity);
  return ws;
}

void ShapeErrorPlanner::section_base(double q1, Eigen::Matrix3d& rotation,
                                     Eigen::Vector3d& position) const noexcept {
  const auto& P = model_.parameters();
  const double arc_length = q1 - (P.proximal_length + P.distal_length);
  if (!prepared() || !(arc_length > 0.0)) {
    rotation.setIdentity();
    position = Eigen::Vector3d(0.0, 0.0, std::isfinite(arc_length) ? std::min(arc_length, 0.0) : 0.0);
    return;
  }
  const auto& aligned = *aligned_;
  const double ds = aligned.spacing();
  const std::size_t last = aligned.size() - 1;
  const auto i =
      std::min(static_cast<std::size_t>(std::min(arc_length / ds, static_cast<double>(last))), last);
  if (i == last) {
    rotation = transport_[last];
    position = aligned.points()[last];
    return;
  }
  const double u = arc_length / ds - static_cast<double>(i);
  const auto& Pt = aligned.points();
  const auto& T = aligned.tangents();
  const Eigen::Vector3d tangent = ((1.0 - u) * T[i] + u * T[i + 1]).normalized();
  rotation = Eigen::Quaterniond::FromTwoVectors(T[i], tangent).toRotationMatrix() * transport_[i];
  position = (1.0 - u) * Pt[i] + u * Pt[i + 1];
}

void ShapeErrorPlanner::load_step(double q1, const Eigen::Vector3d& shape_offset,
                                  StepWorkspace& ws) const noexcept {
  ws.count = 0;
  if (!prepared()) return;
  const auto& aligned = *aligned_;
  q1 = std::isfinite(q1) ? std::clamp(q1, 0.0, aligned.length()) : 0.0;
  const auto& P = model_.parameters();
  const double L1 = P.proximal_length, L2 = P.distal_length;
  const double ds = aligned.spacing();
  const double base_arc = q1 - (L1 + L2);
  section_base(q1, ws.base_rotation, ws.base_position);
  ws.insertion = q1;
  const Eigen::Matrix3d to_base = ws.base_rotation.transpose();

  // Inserted vessel samples on the steerable section: max(s_b, 0) ≤ s_i ≤ q1 (eq. 4.16).
  const double eps = 1e-9 * ds;
  const auto first = static_cast<std::size_t>(std::ceil(std::max(base_arc, 0.0) / ds - 1e-9));
  const auto last = std::min(static_cast<std::size_t>(std::floor(q1 / ds + 1e-9)), aligned.size() - 1);
  for (std::size_t i = first; i <= last && ws.count < ws.sigma.size(); ++i) {
    const double sigma = std::clamp(aligned.arc_length(i) - base_arc, 0.0, L1 + L2 + eps);
    const double weight =
        sigma <= L1 ? options_.proximal_to_distal_ratio * tip_ramp(sigma / L1) : tip_ramp((sigma - L1) / L2);
    const std::size_t k = ws.count++;
    ws.sigma[k] = sigma;
    ws.sqrt_weight[k] = std::sqrt(weight / options_.position_error_range);
    // Shape + (σ/L)·offset against c is shape against c − (σ/L)·offset.
    ws.target[k] = to_base * (aligned.points()[i] - ws.base_position) - (sigma / (L1 + L2)) * shape_offset;
    ws.target_tangent[k] = to_base * aligned.tangents()[i];
  }
}

double ShapeErrorPlanner::cost(const StepWorkspace& ws, const StepVector& x) const noexcept {
  const SteerableShape shape(model_.parameters(), x[0], x[1], x[2], x[3]);
  double sum = 0.0;
  Eigen::Vector3d t;
  for (std::size_t k = 0; k < ws.count; ++k) {
    const Eigen::Vector3d p = shape.point(ws.sigma[k], t);
    const double w = ws.sqrt_weight[k] * ws.sqrt_weight[k];
    sum += w * ((p - ws.target[k]).squaredNorm() +
                tangent_factor_sqrt_ * tangent_factor_sqrt_ * (t - ws.target_tangent[k]).squaredNorm());
  }
  return sum;
}

double ShapeErrorPlanner::normal_equations(const StepWorkspace& ws, const StepVector& x, Eigen::Matrix4d& jtj,
                                           Eigen::Vector4d& jtr) const noexcept {
  const SteerableShape shape(model_.parameters(), x[0], x[1], x[2], x[3]);
  const double tf2 = tangent_factor_sqrt_ * tangent_factor_sqrt_;
  jtj.setZero();
  jtr.setZero();
  double sum = 0.0;
  Eigen::Vector3d p, t;
  Eigen::Matrix<double, 3, 4> dp, dt;
  for (std::size_t k = 0; k < ws.count; ++k) {
    shape.derivatives(ws.sigma[k], p, t, dp, dt);
    const double w = ws.sqrt_weight[k] * ws.sqrt_weight[k];
    const Eigen::Vector3d ep = p - ws.target[k], et = t - ws.target_tangent[k];
    sum += w * (ep.squaredNorm() + tf2 * et.squaredNorm());
    jtj.noalias() += w * (dp.transpose() * dp + tf2 * (dt.transpose() * dt));
    jtr.noalias() += w * (dp.transpose() * ep + tf2 * (dt.transpose() * et));
  }
  if (!options_.free_flexure) {  // γ is not an unknown: its column does not exist
    jtj.row(3).setZero();
    jtj.col(3).setZero();
    jtr[3] = 0.0;
  }
  return sum;
}

bool ShapeErrorPlanner::residuals(
    const StepWorkspace& ws, const StepVector& x, Eigen::Ref<Eigen::VectorXd> r,
    Eigen::Ref<Eigen::Matrix<double, Eigen::Dynamic, 4>> jacobian) const noexcept {
  const auto rows = static_cast<Eigen::Index>(6 * ws.count);
  if (r.size() != rows || jacobian.rows() != rows) return false;
  const SteerableShape shape(model_.parameters(), x[0], x[1], x[2], x[3]);
  Eigen::Vector3d p, t;
  Eigen::Matrix<double, 3, 4> dp, dt;
  for (std::size_t k = 0; k < ws.count; ++k) {
    shape.derivatives(ws.sigma[k], p, t, dp, dt);
    const double w = ws.sqrt_weight[k], wt = tangent_factor_sqrt_ * ws.sqrt_weight[k];
    const auto row = static_cast<Eigen::Index>(6 * k);
    r.segment<3>(row) = w * (p - ws.target[k]);
    r.segment<3>(row + 3) = wt * (t - ws.target_tangent[k]);
    jacobian.block<3, 4>(row, 0) = w * dp;
    jacobian.block<3, 4>(row + 3, 0) = wt * dt;
  }
  return true;
}

void ShapeErrorPlanner::solve_loaded(const StepWorkspace& ws, const StepVector& start,
                                     PlanStep& step) const noexcept {
  const auto& P = model_.parameters();
  step.q = JointVector(ws.insertion, 0.0, 0.0, 0.0);
  step.position_error_mean = step.position_error_max = 0.0;
  step.tangent_error_mean = step.tangent_error_max = 0.0;
  step.points = ws.count;

  // Candidate starts: the warm start plus bent starts in four roll directions, because at q3 = q4 = 0
  // the roll has no effect (zero gradient) and a vessel bending out of the current plane is a saddle.
  std::array<Eigen::Vector4d, 5> candidates;
  std::size_t count = 0;
  if (options_.warm_start) candidates[count++] = start;
  const double bent = std::min(0.5, 0.5 * options_.proximal_drive_max);
  for (int r = 0; r < 4; ++r) candidates[count++] = Eigen::Vector4d(r * 0.5 * kPi, bent, 0.0, start[3]);
  Eigen::Vector4d x = candidates[0];
  double cost_x = cost(ws, x);
  for (std::size_t c = 1; c < count; ++c) {
    const double candidate_cost = cost(ws, candidates[c]);
    if (candidate_cost < cost_x) {
      cost_x = candidate_cost;
      x = candidates[c];
    }
  }

  // Levenberg–Marquardt with Marquardt scaling, the analytic Jacobian (normal equations accumulated
  // per point, so nothing of the residual's size is stored) and an active set for the drive limits (a
  // coordinate at a bound whose gradient pushes outwards is held fixed). Fixed-size 4×4 algebra only.
  double lambda = options_.initial_damping;
  double growth = 2.0;  // Nielsen's ν
  int iterations = 0;
  bool converged = cost_x <= 0.0;
  const int unknowns = options_.free_flexure ? 4 : 3;
  Eigen::Matrix4d A;
  Eigen::Vector4d g;
  while (!converged && iterations < options_.max_iterations) {
    normal_equations(ws, x, A, g);
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
      const double candidate_cost = cost(ws, candidate);
      if (candidate_cost < cost_x) {
        // Nielsen's damping update from the gain ratio ρ = actual / predicted decrease (F = Σr²,
        // predicted from F + 2gᵀδ + δᵀAδ): λ falls fast while the Gauss–Newton model is good, so
        // a run of rejections does not leave the iteration crawling with large damping.
        const Eigen::Vector4d taken = candidate - x;
        const double predicted = -(2.0 * g.dot(taken) + taken.dot(A * taken));
        const double rho = predicted > 0.0 ? (cost_x - candidate_cost) / predicted : 0.0;
        const double improvement = (cost_x - candidate_cost) / std::max(cost_x, 1e-300);
        const double step_size = (candidate - x).cwiseAbs().maxCoeff();
        x = candidate;
        cost_x = candidate_cost;
        const double cube = (2.0 * rho - 1.0) * (2.0 * rho - 1.0) * (2.0 * rho - 1.0);
        lambda = std::max(lambda * std::max(1.0 / 3.0, 1.0 - cube), 1e-15);
        growth = 2.0;
        converged = improvement < options_.relative_cost_tolerance || step_size < options_.step_tolerance;
        break;
      }
      lambda *= growth;
      growth *= 2.0;
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
  step.cost = cost_x;
  step.iterations = iterations;
  step.design = P;
  step.design.flexure = x[3];
  step.base_rotation = from_aligned_.transpose() * ws.base_rotation;
  step.base_position = from_aligned_.transpose() * (ws.base_position - aligned_offset_);
  // Errors in the section base frame (rotation-invariant), against the loaded (possibly offset) targets.
  const SteerableShape shape(P, x[0], x[1], x[2], x[3]);
  Eigen::Vector3d t;
  double position_sum = 0.0, tangent_sum = 0.0;
  for (std::size_t k = 0; k < ws.count; ++k) {
    const Eigen::Vector3d p = shape.point(ws.sigma[k], t);
    const double position_error = (p - ws.target[k]).norm();
    const Eigen::Vector3d& tc = ws.target_tangent[k];
    const double tangent_error = kRadToDeg * std::atan2(t.cross(tc).norm(), t.dot(tc));
    position_sum += position_error;
    tangent_sum += tangent_error;
    step.position_error_max = std::max(step.position_error_max, position_error);
    step.tangent_error_max = std::max(step.tangent_error_max, tangent_error);
  }
  if (ws.count > 0) {
    step.position_error_mean = position_sum / static_cast<double>(ws.count);
    step.tangent_error_mean = tangent_sum / static_cast<double>(ws.count);
  }
}

PathPlan ShapeErrorPlanner::plan(const VesselCenterline& vessel) { return plan(vessel, JobControl{}); }

PathPlan ShapeErrorPlanner::plan(const VesselCenterline& vessel, const JobControl& job) {
  prepare(vessel);
  StepWorkspace ws = make_workspace();
  const auto& P = model_.parameters();
  const double dq1 = options_.insertion_step;
  PathPlan plan;
  plan.design = P;
  plan.free_flexure = options_.free_flexure;
  const auto steps = static_cast<std::size_t>(std::floor(aligned_->length() / dq1 + 1e-9));
  plan.steps.reserve(steps);
  Eigen::Vector4d start(0.0, 0.0, 0.0, P.flexure);
  double position_sum = 0.0, tangent_sum = 0.0;
  std::size_t point_count = 0;
  PlanStep step;
  for (std::size_t k = 1; k <= steps; ++k) {
    job.check_cancelled();
    load_step(dq1 * static_cast<double>(k), Eigen::Vector3d::Zero(), ws);
    solve_loaded(ws, start, step);
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
