// Three-segment variable-diameter MBCR and its gradient-projection redundancy resolution (Abah 2022,
// §2.7); see the header for the conventions and the choices where the dissertation is silent.
#include "tendril/teleop/variable_diameter_robot.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

void require(bool ok, const std::string& name, double value, const char* expectation) {
  if (!ok) {
    std::ostringstream out;
    out << "variable-diameter robot: " << name << " must be " << expectation << ", got " << value;
    throw std::invalid_argument(out.str());
  }
}

void require_positive(const std::string& name, double value) {
  require(std::isfinite(value) && value > 0.0, name, value, "positive and finite");
}

void require_non_negative(const std::string& name, double value) {
  require(std::isfinite(value) && value >= 0.0, name, value, "non-negative and finite");
}

SegmentConfiguration segment(const StackConfiguration& psi, Eigen::Index k) noexcept {
  return psi.segment<2>(2 * k);
}

}  // namespace

VariableDiameterRobot::VariableDiameterRobot(const VariableDiameterRobotParameters& parameters)
    : parameters_(parameters), linkage_(parameters.linkage) {
  validate(parameters.disks);
  require_positive("backbone_diameter (mm)", parameters.backbone_diameter);
  require_positive("youngs_modulus (N/mm²)", parameters.youngs_modulus);
  require(std::isfinite(parameters.backbone_lower) && std::isfinite(parameters.backbone_upper) &&
              parameters.backbone_lower < 0.0 && parameters.backbone_upper > 0.0,
          "backbone limits [backbone_lower, backbone_upper] (mm)", parameters.backbone_lower,
          "finite with lower < 0 < upper (a straight robot must be inside); lower");
  const RedundancyParameters& red = parameters.redundancy;
  require_non_negative("redundancy.force_weight (w1)", red.force_weight);
  require_non_negative("redundancy.limit_weight (w2)", red.limit_weight);
  require_non_negative("redundancy.step_gain (lambda)", red.step_gain);
  require_positive("redundancy.force_difference_step (mm)", red.force_difference_step);
  require_positive("redundancy.limit_floor (mm)", red.limit_floor);
  require_positive("redundancy.objective_length_scale (model units per objective unit)",
                   red.objective_length_scale);
  require_positive("redundancy.max_diameter_rate (mm/s)", red.max_diameter_rate);
  const TaskInverseParameters& task = parameters.task;
  require_non_negative("task.pose_gain (1/s)", task.pose_gain);
  require_non_negative("task.max_damping", task.max_damping);
  require_positive("task.singular_threshold", task.singular_threshold);
  bending_stiffness_ = backbone_bending_stiffness(parameters.youngs_modulus, parameters.backbone_diameter);
}

VariableDiameterData VariableDiameterRobot::make_data() const {
  VariableDiameterData data;
  for (auto& frame : data.frames) frame.setIdentity();
  return data;
}

Eigen::Isometry3d VariableDiameterRobot::tip_pose(const StackConfiguration& psi,
                                                  VariableDiameterData& data) const noexcept {
  const double length = parameters_.disks.segment_length;
  data.frames[0].setIdentity();
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    data.frames[k + 1] = data.frames[k] * segment_end_pose(segment(psi, k), length);
  }
  const Eigen::Vector3d tip = data.frames[kVariableDiameterSegments].translation();
  // Twist transformation of each segment's J_xψ to the tip, in the base frame: rotate it from the
  // segment's base frame and carry the end-disk velocity to the tip along the rest of the robot.
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    const SegmentTwistJacobian local = segment_twist_jacobian(segment(psi, k), length);
    const Eigen::Matrix3d rotation = data.frames[k].linear();
    const Eigen::Vector3d lever = tip - data.frames[k + 1].translation();
    for (int c = 0; c < 2; ++c) {
      const Eigen::Vector3d omega = rotation * local.block<3, 1>(3, c);
      const Eigen::Vector3d v = rotation * local.block<3, 1>(0, c) + omega.cross(lever);
      data.task_jacobian.block<3, 1>(0, 2 * k + c) = v;
      data.task_jacobian.block<3, 1>(3, 2 * k + c) = omega;
    }
  }
  return data.frames[kVariableDiameterSegments];
}

StackJoints VariableDiameterRobot::joints(const StackConfiguration& psi, double a) const noexcept {
  const double r = linkage_.configuration_radius(a);
  StackJoints q;
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    q.segment<2>(2 * k) = backbone_displacements(segment(psi, k), r).head<2>();
  }
  q[6] = a;
  return q;
}

Eigen::Matrix<double, 6, 7> VariableDiameterRobot::augmentation_matrix(const StackConfiguration& psi,
                                                                       double a) const noexcept {
  const double dr_da = linkage_.configuration_radius_rate(a);
  Eigen::Matrix<double, 6, 7> m = Eigen::Matrix<double, 6, 7>::Zero();
  m.leftCols<6>().setIdentity();
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    m.block<2, 1>(2 * k, 6) = -diameter_column(segment(psi, k), dr_da).head<2>();  // A_k of (2.33)
  }
  return m;
}

Eigen::Matrix<double, 6, 6> VariableDiameterRobot::backbone_jacobian(const StackConfiguration& psi,
                                                                     double a) const noexcept {
  const double r = linkage_.configuration_radius(a);
  Eigen::Matrix<double, 6, 6> j = Eigen::Matrix<double, 6, 6>::Zero();
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    j.block<2, 2>(2 * k, 2 * k) = tendril::teleop::backbone_jacobian(segment(psi, k), r).topRows<2>();
  }
  return j;
}

StackJoints VariableDiameterRobot::null_space_direction(const StackConfiguration& psi,
                                                        double a) const noexcept {
  const double dr_da = linkage_.configuration_radius_rate(a);
  StackJoints n;
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    n.segment<2>(2 * k) = diameter_column(segment(psi, k), dr_da).head<2>();
  }
  n[6] = 1.0;
  return n.normalized();
}

DiameterLimits VariableDiameterRobot::diameter_limits(const StackConfiguration& psi) const noexcept {
  DiameterLimits limits;
  limits.lower = linkage_.inner_radius_min();
  double b_limit = kInfinity;
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    b_limit =
        std::min(b_limit, interference_outer_radius_limit(parameters_.disks, segment_bend(segment(psi, k))));
  }
  if (std::isnan(b_limit)) {
    limits.upper = limits.lower;
    limits.interference = limits.lower;
    limits.interference_unavoidable = true;
    return limits;
  }
  if (b_limit >= linkage_.outer_radius_max()) {
    limits.interference = kInfinity;
  } else {
    const double r = linkage_.configuration_radius_for_outer_limit(b_limit);
    if (std::isnan(r)) {
      limits.interference = limits.lower;
      limits.interference_unavoidable = true;
    } else {
      limits.interference = linkage_.inner_radius(r);
    }
  }
  limits.upper = std::max(limits.lower, std::min(linkage_.inner_radius_max(), limits.interference));
  return limits;
}

bool VariableDiameterRobot::actuation(const StackConfiguration& psi, double a, const Wrench& wrench,
                                      VariableDiameterData& data, StackActuation& out) const noexcept {
  out.setZero();
  const double tolerance = 1e-9;
  if (!psi.allFinite() || !wrench.allFinite() || !std::isfinite(a) ||
      a < linkage_.inner_radius_min() - tolerance || a > linkage_.inner_radius_max() + tolerance) {
    return false;
  }
  const double r = linkage_.configuration_radius(a);
  const double dr_da = linkage_.configuration_radius_rate(a);
  const double length = parameters_.disks.segment_length;
  tip_pose(psi, data);
  data.backbone_jacobian.setZero();
  data.generalized_load.setZero();
  double radius_gradient = 0.0;
  for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
    const SegmentConfiguration psi_k = segment(psi, k);
    data.backbone_jacobian.block<4, 2>(4 * k, 2 * k) = tendril::teleop::backbone_jacobian(psi_k, r);
    data.diameter_column.segment<4>(4 * k) = diameter_column(psi_k, dr_da);
    radius_gradient += elastic_energy_radius_gradient(psi_k, r, length, bending_stiffness_);
    data.generalized_load.segment<2>(2 * k) =
        elastic_energy_configuration_gradient(psi_k, r, length, bending_stiffness_);
  }
  // J_q̃ψ = A₁₂⁺·J_qψ with A₁₂ = [I | −c]: A⁺ = [I; −cᵀ]·(I − ccᵀ/(1 + cᵀc)).
  const auto& c = data.diameter_column;
  const Eigen::Matrix<double, 1, 6> ctj = c.transpose() * data.backbone_jacobian;
  data.augmented_jacobian.topRows<12>() = data.backbone_jacobian - c * ctj / (1.0 + c.squaredNorm());
  data.augmented_jacobian.row(12) = -c.transpose() * data.augmented_jacobian.topRows<12>();
  const Eigen::Matrix<double, 1, 6> radius_jacobian = dr_da * data.augmented_jacobian.row(12);
  // (2.29): J_q̃ψᵀτ̃ = J_rψᵀ∇U_r + ∇U_ψ − J_xψsᵀW_e.
  data.generalized_load +=
      radius_jacobian.transpose() * radius_gradient - data.task_jacobian.transpose() * wrench;
  // (2.30): τ̃ = (J_q̃ψᵀ)⁺·load = J_q̃ψ·(J_q̃ψᵀJ_q̃ψ)⁺·load, the Gram matrix inverted on its
  // non-negligible eigenvalues (a straight segment's δ does nothing and is dropped).
  data.gram.noalias() = data.augmented_jacobian.transpose() * data.augmented_jacobian;
  data.gram_solver.compute(data.gram);
  const auto& values = data.gram_solver.eigenvalues();
  const auto& vectors = data.gram_solver.eigenvectors();
  const double cutoff = 1e-12 * std::max(values.maxCoeff(), 1e-300);
  Eigen::Matrix<double, 6, 1> projected = vectors.transpose() * data.generalized_load;
  for (int i = 0; i < 6; ++i) projected[i] = values[i] > cutoff ? projected[i] / values[i] : 0.0;
  out.noalias() = data.augmented_jacobian * (vectors * projected);
  if (!out.allFinite()) {
    out.setZero();
    return false;
  }
  return true;
}

double VariableDiameterRobot::limit_cost(const StackJoints& q, const DiameterLimits& limits,
                                         StackJoints* gradient) const noexcept {
  const double floor = parameters_.redundancy.limit_floor;
  double h = 0.0;
  for (int i = 0; i < 7; ++i) {
    const double lower = i < 6 ? parameters_.backbone_lower : limits.lower;
    const double upper = i < 6 ? parameters_.backbone_upper : limits.upper;
    const double range = upper - lower;
    const double to_upper = std::max(upper - q[i], floor);
    const double to_lower = std::max(q[i] - lower, floor);
    h += range / (to_upper * to_lower);
    if (gradient != nullptr) {
      (*gradient)[i] = range * (to_lower - to_upper) / (to_upper * to_upper * to_lower * to_lower);
    }
  }
  return h;
}

bool VariableDiameterRobot::task_inverse(VariableDiameterData& data, const StackTwist& twist,
                                         StackConfiguration& rate) const noexcept {
  rate.setZero();
  if (!twist.allFinite() || !data.task_jacobian.allFinite()) return false;
  // Scale the linear rows by the segment length so that J is dimensionless and one damping fits both.
  const double scale = 1.0 / parameters_.disks.segment_length;
  StackTwistJacobian scaled = data.task_jacobian;
  scaled.topRows<3>() *= scale;
  StackTwist scaled_twist = twist;
  scaled_twist.head<3>() *= scale;
  data.task_svd.compute(scaled, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const auto& sigma = data.task_svd.singularValues();
  const TaskInverseParameters& task = parameters_.task;
  data.smallest_singular = sigma[5];
  const double ratio = sigma[5] / task.singular_threshold;
  const double rho2 = ratio < 1.0 ? task.max_damping * task.max_damping * (1.0 - ratio * ratio) : 0.0;
  data.damping = std::sqrt(rho2);
  const Eigen::Matrix<double, 6, 1> projected = data.task_svd.matrixU().transpose() * scaled_twist;
  Eigen::Matrix<double, 6, 1> weighted;
  for (int i = 0; i < 6; ++i) {
    const double denominator = sigma[i] * sigma[i] + rho2;
    weighted[i] = denominator > 0.0 ? sigma[i] / denominator * projected[i] : 0.0;
  }
  rate.noalias() = data.task_svd.matrixV() * weighted;
  if (!rate.allFinite()) {
    rate.setZero();
    return false;
  }
  return true;
}

VariableDiameterStepReport VariableDiameterRobot::step(VariableDiameterState& state,
                                                       const Eigen::Isometry3d& target,
                                                       const StackTwist& target_twist, const Wrench& wrench,
                                                       double dt, bool vary_diameter,
                                                       VariableDiameterData& data) const noexcept {
  VariableDiameterStepReport report;
  if (!state.configuration.allFinite() || !std::isfinite(state.diameter_joint) ||
      !target.matrix().allFinite() || !target_twist.allFinite() || !wrench.allFinite() ||
      !std::isfinite(dt) || dt <= 0.0) {
    report.status = VariableDiameterStatus::kNonFinite;
    return report;
  }
  const StackConfiguration& psi = state.configuration;
  const double a = state.diameter_joint;
  report.limits = diameter_limits(psi);

  // Task: ψ̇_s from the closed-loop resolved rates.
  const Eigen::Isometry3d pose = tip_pose(psi, data);
  const StackTwist error = pose_error(target, pose);
  report.tracking_error = error.head<3>().norm();
  StackConfiguration psi_rate;
  if (!task_inverse(data, target_twist + parameters_.task.pose_gain * error, psi_rate)) {
    report.status = VariableDiameterStatus::kNonFinite;
    return report;
  }

  StackActuation forces;
  if (!actuation(psi, a, wrench, data, forces)) {
    report.status = VariableDiameterStatus::kNonFinite;
    return report;
  }
  report.force_norm = forces.norm();

  const Eigen::Matrix<double, 6, 6> jq = backbone_jacobian(psi, a);
  StackJoints rate = StackJoints::Zero();
  if (!vary_diameter) {
    rate.head<6>() = jq * psi_rate;
  } else {
    // (2.34): q̃̇ = A_s⁺·J_qψs·ψ̇_s + (I − A_s⁺A_s)·λ∇g, with A_s = [I | −c] and I − A_s⁺A_s = nnᵀ.
    const double dr_da = linkage_.configuration_radius_rate(a);
    Eigen::Matrix<double, 6, 1> c;
    for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
      c.segment<2>(2 * k) = diameter_column(segment(psi, k), dr_da).head<2>();
    }
    const Eigen::Matrix<double, 6, 1> w = jq * psi_rate;
    const Eigen::Matrix<double, 6, 1> y = w - c * (c.dot(w) / (1.0 + c.squaredNorm()));
    rate.head<6>() = y;
    rate[6] = -c.dot(y);

    // ∂‖τ̃_s‖/∂a at fixed ψ_s by central differences (one-sided at the ends of the linkage's range).
    const RedundancyParameters& red = parameters_.redundancy;
    const double a_lo = std::max(a - red.force_difference_step, linkage_.inner_radius_min());
    const double a_hi = std::min(a + red.force_difference_step, linkage_.inner_radius_max());
    StackActuation low, high;
    if (a_hi > a_lo && actuation(psi, a_lo, wrench, data, low) && actuation(psi, a_hi, wrench, data, high)) {
      report.force_gradient = (high.norm() - low.norm()) / (a_hi - a_lo);
    }
    StackJoints limit_gradient;
    limit_cost(joints(psi, a), report.limits, &limit_gradient);
    StackJoints n;
    n.head<6>() = c;
    n[6] = 1.0;
    n.normalize();
    // ∂g/∂n for g = −w₁‖τ̃_s‖ − w₂H, in the objective's units (s model units per objective unit): the
    // force term moves along n only through a (n[6]); ‖τ̃‖' scales with s, H' (H is 1/length) with s².
    const double s = red.objective_length_scale;
    const double slope = -red.force_weight * report.force_gradient * s * n[6] -
                         red.limit_weight * limit_gradient.dot(n) * s * s;
    // η = λ∇g in objective units per second, back to model units; the motion of a along n is capped.
    double null_rate = s * red.step_gain * slope;
    const double a_rate = std::abs(null_rate * n[6]);
    if (a_rate > red.max_diameter_rate) null_rate *= red.max_diameter_rate / a_rate;
    rate += null_rate * n;
  }
  if (!rate.allFinite()) {
    report.status = VariableDiameterStatus::kNonFinite;
    return report;
  }

  StackConfiguration next_psi = psi + dt * psi_rate;
  double next_a = a + dt * rate[6];
  const DiameterLimits next_limits = diameter_limits(next_psi);
  if (next_limits.interference_unavoidable) {
    report.status = VariableDiameterStatus::kInterferenceUnavoidable;
    next_a = next_limits.lower;
  } else if (next_a > next_limits.upper || next_a < next_limits.lower) {
    report.status = VariableDiameterStatus::kDiameterClamped;
    next_a = std::clamp(next_a, next_limits.lower, next_limits.upper);
  }
  // The joint velocity that the clamped step really makes.
  rate = (joints(next_psi, next_a) - joints(psi, a)) / dt;
  report.joint_velocity = rate;
  state.configuration = next_psi;
  state.diameter_joint = next_a;
  return report;
}

StackTwist pose_error(const Eigen::Isometry3d& target, const Eigen::Isometry3d& actual) noexcept {
  StackTwist e;
  e.head<3>() = target.translation() - actual.translation();
  const Eigen::AngleAxisd rotation(target.linear() * actual.linear().transpose());
  e.tail<3>() = rotation.angle() * rotation.axis();
  return e;
}

}  // namespace tendril::teleop
