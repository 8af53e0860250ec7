// Simulation of the dissertation's variable-diameter circle experiment (Abah 2022, §2.7.2); see the header.
#include "tendril/teleop/variable_diameter_simulation.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

namespace tendril::teleop {

Eigen::Isometry3d circle_pose(const CircleTrajectoryParameters& circle, double t) noexcept {
  const double angle = circle.start_angle + circle.direction * 2.0 * std::numbers::pi * t / circle.period;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = circle.orientation;
  pose.translation() = circle.centre + circle.radius * Eigen::Vector3d(std::cos(angle), 0.0, std::sin(angle));
  return pose;
}

StackTwist circle_twist(const CircleTrajectoryParameters& circle, double t) noexcept {
  const double rate = circle.direction * 2.0 * std::numbers::pi / circle.period;
  const double angle = circle.start_angle + rate * t;
  StackTwist twist = StackTwist::Zero();
  twist.head<3>() = circle.radius * rate * Eigen::Vector3d(-std::sin(angle), 0.0, std::cos(angle));
  return twist;  // the orientation is held, so ω = 0
}

double solve_tip_pose(const VariableDiameterRobot& robot, const Eigen::Isometry3d& target,
                      StackConfiguration& psi, int iterations) {
  VariableDiameterData data = robot.make_data();
  StackConfiguration step;
  for (int i = 0; i < iterations; ++i) {
    const StackTwist error = pose_error(target, robot.tip_pose(psi, data));
    if (error.head<3>().norm() < 1e-9 && error.tail<3>().norm() < 1e-12) break;
    if (!robot.task_inverse(data, error, step)) break;
    // Half Newton steps: the damped inverse alone can overshoot on a 600 mm lever.
    psi += 0.5 * step;
  }
  return pose_error(target, robot.tip_pose(psi, data)).head<3>().norm();
}

StackConfiguration circle_start_configuration(const VariableDiameterRobot& robot,
                                              const CircleTrajectoryParameters& circle, CircleBranch branch) {
  // Two planar (y-z plane) guesses, one per inverse-kinematics branch that reaches [0, 150, 505] mm with
  // the end disk facing +y (a search from random starts found no other): the S shape bends gently
  // one way and back; the hook bends the first segment towards −y and the two others towards +y so
  // far that the end disk comes back round to face +y.
  const double half_pi = 0.5 * std::numbers::pi;
  StackConfiguration psi;
  if (branch == CircleBranch::kHook) {
    psi << kStraightTangentAngle + 0.8, half_pi, kStraightTangentAngle - 1.5, half_pi,
        kStraightTangentAngle - 2.3, -half_pi;
  } else {
    psi << kStraightTangentAngle - 0.2, half_pi, kStraightTangentAngle - 0.5, -half_pi,
        kStraightTangentAngle - 1.2, -half_pi;
  }
  solve_tip_pose(robot, circle_pose(circle, 0.0), psi);
  return psi;
}

CircleRun simulate_circle(const VariableDiameterRobot& robot, const CircleTrajectoryParameters& circle,
                          const StackConfiguration& start, bool vary_diameter) {
  CircleRun run;
  VariableDiameterData data = robot.make_data();
  VariableDiameterState state;
  state.configuration = start;
  const double a_min = robot.linkage().inner_radius_min();
  state.diameter_joint = vary_diameter ? a_min + circle.start_offset : a_min;
  const auto steps = static_cast<std::size_t>(std::llround(circle.period / circle.dt));
  run.samples.reserve(steps + 1);
  for (std::size_t i = 0; i <= steps; ++i) {
    const double t = static_cast<double>(i) * circle.dt;
    const StackConfiguration psi = state.configuration;
    const double a = state.diameter_joint;
    const VariableDiameterStepReport report =
        robot.step(state, circle_pose(circle, t + circle.dt), circle_twist(circle, t + circle.dt),
                   circle.payload, circle.dt, vary_diameter, data);
    CircleSample sample;
    sample.time = t;
    sample.diameter_joint = a;
    sample.diameter_upper = report.limits.upper;
    sample.interference = report.limits.interference;
    sample.force_norm = report.force_norm;
    sample.tracking_error = report.tracking_error;
    for (Eigen::Index k = 0; k < kVariableDiameterSegments; ++k) {
      sample.largest_bend = std::max(sample.largest_bend, std::abs(psi[2 * k] - kStraightTangentAngle));
    }
    sample.joints = robot.joints(psi, a);
    sample.status = report.status;
    run.samples.push_back(sample);
    if (report.status == VariableDiameterStatus::kNonFinite) {
      ++run.failed_steps;
      break;
    }
    if (report.status != VariableDiameterStatus::kOk) ++run.clamped_steps;
  }
  return run;
}

ForceComparison compare_forces(const CircleRun& fixed, const CircleRun& variable) {
  ForceComparison out;
  const std::size_t n = std::min(fixed.samples.size(), variable.samples.size());
  if (n == 0) return out;
  double sum_f = 0.0, sum_v = 0.0, sum_d = 0.0, sum_d2 = 0.0;
  out.min_reduction = std::numeric_limits<double>::infinity();
  out.max_reduction = -std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < n; ++i) {
    const double f = fixed.samples[i].force_norm, v = variable.samples[i].force_norm, d = f - v;
    sum_f += f * f;
    sum_v += v * v;
    sum_d += d;
    sum_d2 += d * d;
    out.min_reduction = std::min(out.min_reduction, d);
    out.max_reduction = std::max(out.max_reduction, d);
  }
  const double count = static_cast<double>(n);
  out.rms_fixed = std::sqrt(sum_f / count);
  out.rms_variable = std::sqrt(sum_v / count);
  out.rms_reduction = std::sqrt(sum_d2 / count);
  out.mean_reduction = sum_d / count;
  out.std_reduction = std::sqrt(std::max(0.0, sum_d2 / count - out.mean_reduction * out.mean_reduction));
  return out;
}

bool write_circle_csv(const std::string& path, const CircleRun& fixed, const CircleRun& variable) {
  std::ofstream out(path);
  if (!out) return false;
  out << "time_s,diameter_joint_mm,diameter_upper_mm,force_norm_fixed_N,force_norm_variable_N,largest_bend_"
         "rad\n";
  const std::size_t n = std::min(fixed.samples.size(), variable.samples.size());
  for (std::size_t i = 0; i < n; ++i) {
    const CircleSample& v = variable.samples[i];
    out << v.time << ',' << v.diameter_joint << ',' << v.diameter_upper << ',' << fixed.samples[i].force_norm
        << ',' << v.force_norm << ',' << v.largest_bend << '\n';
  }
  return static_cast<bool>(out);
}

namespace {

// One polyline of (t, value) scaled into a panel.
std::string polyline(const std::vector<std::pair<double, double>>& points, double t_max, double y_min,
                     double y_max, double top, double height, const char* colour) {
  std::ostringstream out;
  out << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"1.5\" points=\"";
  for (const auto& [t, y] : points) {
    const double px = 60.0 + 700.0 * t / t_max;
    const double py = top + height * (1.0 - (std::clamp(y, y_min, y_max) - y_min) / (y_max - y_min));
    out << px << ',' << py << ' ';
  }
  out << "\"/>\n";
  return out.str();
}

}  // namespace

bool write_circle_svg(const std::string& path, const CircleRun& fixed, const CircleRun& variable) {
  const std::size_t n = std::min(fixed.samples.size(), variable.samples.size());
  if (n < 2) return false;
  // Thin to at most ~1000 points per curve; the plot is 700 px wide.
  const std::size_t stride = std::max<std::size_t>(1, n / 1000);
  std::vector<std::pair<double, double>> a, upper, ff, fv;
  double a_max = 0.0, f_max = 0.0;
  for (std::size_t i = 0; i < n; i += stride) {
    const CircleSample& v = variable.samples[i];
    a.emplace_back(v.time, v.diameter_joint);
    upper.emplace_back(v.time, v.diameter_upper);
    ff.emplace_back(v.time, fixed.samples[i].force_norm);
    fv.emplace_back(v.time, v.force_norm);
    a_max = std::max({a_max, v.diameter_joint, v.diameter_upper});
    f_max = std::max({f_max, fixed.samples[i].force_norm, v.force_norm});
  }
  const double t_max = variable.samples[n - 1].time;
  a_max = std::ceil(a_max / 5.0) * 5.0;
  f_max = std::ceil(f_max / 50.0) * 50.0;
  std::ofstream out(path);
  if (!out) return false;
  out << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"800\" height=\"520\" font-family=\"sans-serif\" "
         "font-size=\"12\">\n<rect width=\"800\" height=\"520\" fill=\"white\"/>\n";
  out << "<text x=\"60\" y=\"20\">diameter joint a (mm): varying (blue), upper limit (grey); 0 to " << a_max
      << "</text>\n";
  out << "<rect x=\"60\" y=\"30\" width=\"700\" height=\"200\" fill=\"none\" stroke=\"black\"/>\n";
  out << polyline(upper, t_max, 0.0, a_max, 30.0, 200.0, "#999999");
  out << polyline(a, t_max, 0.0, a_max, 30.0, 200.0, "#1f77b4");
  out << "<text x=\"60\" y=\"270\">actuation force norm (N): fixed a = a_min (red), varying (blue); 0 to "
      << f_max << "</text>\n";
  out << "<rect x=\"60\" y=\"280\" width=\"700\" height=\"200\" fill=\"none\" stroke=\"black\"/>\n";
  out << polyline(ff, t_max, 0.0, f_max, 280.0, 200.0, "#d62728");
  out << polyline(fv, t_max, 0.0, f_max, 280.0, 200.0, "#1f77b4");
  out << "<text x=\"60\" y=\"500\">time 0 to " << t_max
      << " s (circle of Abah 2022, §2.7.2)</text>\n</svg>\n";
  return static_cast<bool>(out);
}

}  // namespace tendril::teleop
