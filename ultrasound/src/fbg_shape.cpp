// FBG catheter shape: frame codec, reconstruction, Eq. 2 and the SIMULATED interrogator (Heunis et al. 2021,
// §2.2 and §3.3).
#include "tendril/ultrasound/fbg_shape.hpp"

#include "tendril/ultrasound/preoperative_plan.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <limits>

namespace tendril::ultrasound {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kThermoOptic = 6.7e-6;  // 1/K: (α_Λ + α_n) of silica (simulator only)

double reference_wavelength(int grating) { return 1510.0 + 1.25 * grating; }

// exp([w]×) by Rodrigues.
Eigen::Matrix3d exp_so3(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

std::string_view next_field(std::string_view& rest) {
  const std::size_t end = rest.find_first_of(" \t");
  const std::string_view field = rest.substr(0, end);
  rest = end == std::string_view::npos ? std::string_view{} : rest.substr(end + 1);
  return field;
}

template <typename T>
T parse_number(std::string_view field, const char* name) {
  T value{};
  const auto [end, error] = std::from_chars(field.data(), field.data() + field.size(), value);
  if (field.empty() || error != std::errc{} || end != field.data() + field.size()) {
    throw FbgFrameError(std::string("FBG frame: ") + name + " '" + std::string(field.substr(0, 32)) +
                        "' is not a number");
  }
  return value;
}

}  // namespace

void MulticoreFiber::validate() const {
  if (gratings < 2 || gratings > kMaxFbgGratings) {
    throw std::invalid_argument("multicore fibre: gratings must lie in 2..1024, got " +
                                std::to_string(gratings));
  }
  for (const double v : {grating_spacing, core_radius, max_curvature}) {
    if (!std::isfinite(v) || v <= 0.0) {
      throw std::invalid_argument(
          "multicore fibre: grating_spacing, core_radius and max_curvature must be positive");
    }
  }
  if (!std::isfinite(photoelastic) || photoelastic < 0.0 || photoelastic >= 1.0) {
    throw std::invalid_argument("multicore fibre: photoelastic must lie in [0, 1)");
  }
}

FbgFrame parse_fbg_frame(std::string_view text) {
  if (text.size() > 1'000'000) throw FbgFrameError("FBG frame: longer than 1 MB");
  if (text.ends_with("\r\n")) {
    text.remove_suffix(2);
  } else if (text.ends_with('\n')) {
    text.remove_suffix(1);
  }
  std::string_view rest = text;
  if (next_field(rest) != "FBG") throw FbgFrameError("FBG frame: does not start with the tag 'FBG'");
  FbgFrame frame;
  frame.sequence = parse_number<std::uint64_t>(next_field(rest), "sequence");
  frame.gratings = parse_number<int>(next_field(rest), "gratings");
  frame.cores = parse_number<int>(next_field(rest), "cores");
  if (frame.gratings < 1 || frame.gratings > kMaxFbgGratings || frame.cores < 1 ||
      frame.cores > kMaxFbgCores) {
    throw FbgFrameError("FBG frame: " + std::to_string(frame.gratings) + " gratings x " +
                        std::to_string(frame.cores) + " cores; expected 1..1024 gratings and 1..16 cores");
  }
  const std::size_t expected =
      static_cast<std::size_t>(frame.gratings) * static_cast<std::size_t>(frame.cores);
  frame.wavelengths.reserve(expected);
  while (!rest.empty()) {
    if (frame.wavelengths.size() == expected) {
      throw FbgFrameError("FBG frame: more than the " + std::to_string(expected) + " wavelengths announced");
    }
    const double value = parse_number<double>(next_field(rest), "wavelength");
    if (!std::isfinite(value) || value <= 0.0 || value >= 10'000.0) {
      throw FbgFrameError("FBG frame: wavelength " + std::to_string(frame.wavelengths.size()) +
                          " is outside (0, 10000) nm");
    }
    frame.wavelengths.push_back(value);
  }
  if (frame.wavelengths.size() != expected) {
    throw FbgFrameError("FBG frame: " + std::to_string(frame.wavelengths.size()) + " wavelengths, expected " +
                        std::to_string(expected) + " (gratings x cores)");
  }
  return frame;
}

std::string format_fbg_frame(const FbgFrame& frame) {
  std::string out = "FBG " + std::to_string(frame.sequence) + " " + std::to_string(frame.gratings) + " " +
                    std::to_string(frame.cores);
  char buffer[64];
  for (const double w : frame.wavelengths) {
    // 17 significant digits: the text round-trips to the same double.
    std::snprintf(buffer, sizeof buffer, " %.17g", w);
    out += buffer;
  }
  out += '\n';
  return out;
}

const char* to_string(FbgShapeStatus status) noexcept {
  switch (status) {
    case FbgShapeStatus::ok:
      return "ok";
    case FbgShapeStatus::wrong_dimensions:
      return "wrong_dimensions";
    case FbgShapeStatus::not_finite:
      return "not_finite";
  }
  return "unknown";
}

FbgShapeReconstructor::FbgShapeReconstructor(const MulticoreFiber& fiber, const FbgFrame& reference,
                                             double step)
    : fiber_(fiber) {
  fiber_.validate();
  if (reference.gratings != fiber_.gratings || reference.cores != MulticoreFiber::cores ||
      reference.wavelengths.size() != static_cast<std::size_t>(fiber_.gratings) * MulticoreFiber::cores) {
    throw std::invalid_argument("FBG reconstruction: the reference frame has " +
                                std::to_string(reference.gratings) + " x " + std::to_string(reference.cores) +
                                " wavelengths; the fibre needs " + std::to_string(fiber_.gratings) + " x 4");
  }
  for (const double w : reference.wavelengths) {
    if (!std::isfinite(w) || w <= 0.0)
      throw std::invalid_argument("FBG reconstruction: a reference wavelength is not positive");
  }
  if (!std::isfinite(step) || step <= 0.0 || step > fiber_.grating_spacing) {
    throw std::invalid_argument("FBG reconstruction: the integration step must lie in (0, grating_spacing]");
  }
  reference_ = reference.wavelengths;
  Eigen::Matrix<double, 4, 3> geometry;
  geometry.row(0) << 0.0, 0.0, 1.0;
  for (int k = 0; k < 3; ++k) {
    const double psi = fiber_.outer_core_angles[static_cast<std::size_t>(k)];
    geometry.row(k + 1) << fiber_.core_radius * std::sin(psi), -fiber_.core_radius * std::cos(psi), 1.0;
  }
  solver_ = (geometry.transpose() * geometry).inverse() * geometry.transpose();
  if (!solver_.allFinite())
    throw std::invalid_argument("FBG reconstruction: the outer cores do not span the cross-section");
  substeps_ = static_cast<int>(std::ceil(fiber_.grating_spacing / step - 1e-9));
  const auto n = static_cast<std::size_t>(fiber_.gratings);
  shape_.points.assign(n, Eigen::Vector3d::Zero());
  shape_.curvature.assign(n, Eigen::Vector2d::Zero());
  shape_.over_limit.assign(n, 0);
  // Thomas factors of the spline's tridiagonal system (1, 4, 1) over the interior gratings 1..n−2:
  // pivot_[i] = 1/(4 − upper_[i−1]), upper_[i] = pivot_[i] (the super-diagonal 1 scaled).
  second_.assign(n, Eigen::Vector2d::Zero());
  forward_.assign(n, Eigen::Vector2d::Zero());
  pivot_.assign(n, 0.0);
  upper_.assign(n, 0.0);
  for (std::size_t i = 1; i + 1 < n; ++i) {
    pivot_[i] = 1.0 / (4.0 - (i > 1 ? upper_[i - 1] : 0.0));
    upper_[i] = pivot_[i];
  }
}

const FbgShape& FbgShapeReconstructor::reconstruct(const FbgFrame& frame) noexcept {
  const int g_count = fiber_.gratings;
  shape_.sequence = frame.sequence;
  if (frame.gratings != g_count || frame.cores != MulticoreFiber::cores ||
      frame.wavelengths.size() != reference_.size()) {
    shape_.status = FbgShapeStatus::wrong_dimensions;
    return shape_;
  }
  for (const double w : frame.wavelengths) {
    if (!std::isfinite(w) || w <= 0.0) {
      shape_.status = FbgShapeStatus::not_finite;
      return shape_;
    }
  }
  // Steps 1–2 and 5: curvature per grating.
  shape_.curvature_warning = false;
  shape_.max_curvature = 0.0;
  for (int g = 0; g < g_count; ++g) {
    Eigen::Vector4d strain;
    for (int k = 0; k < MulticoreFiber::cores; ++k) {
      const std::size_t i = static_cast<std::size_t>(g) * MulticoreFiber::cores + static_cast<std::size_t>(k);
      strain[k] = (frame.wavelengths[i] - reference_[i]) / reference_[i] / (1.0 - fiber_.photoelastic);
    }
    const Eigen::Vector3d solution = solver_ * strain;
    const auto gi = static_cast<std::size_t>(g);
    shape_.curvature[gi] = solution.head<2>();
    const double magnitude = shape_.curvature[gi].norm();
    shape_.over_limit[gi] = magnitude > fiber_.max_curvature ? 1 : 0;
    shape_.curvature_warning = shape_.curvature_warning || shape_.over_limit[gi] != 0;
    shape_.max_curvature = std::max(shape_.max_curvature, magnitude);
  }
  // Step 3: natural cubic spline through the gratings' curvatures (uniform spacing h):
  // M_{i−1} + 4M_i + M_{i+1} = 6/h²·(κ_{i+1} − 2κ_i + κ_{i−1}), M = κ'' and M₀ = M_{n−1} = 0, solved by
  // the Thomas algorithm with the factors from the constructor. Linear interpolation would bias a
  // curve whose curvature turns (0.44 mm at the tip of the S-curve test against 0.01 mm with the spline).
  const double h = fiber_.grating_spacing;
  const auto n = static_cast<std::size_t>(g_count);
  second_[0].setZero();
  second_[n - 1].setZero();
  if (n > 2) {
    for (std::size_t i = 1; i + 1 < n; ++i) {
      const Eigen::Vector2d rhs =
          6.0 / (h * h) * (shape_.curvature[i + 1] - 2.0 * shape_.curvature[i] + shape_.curvature[i - 1]);
      forward_[i] = rhs * pivot_[i];
      if (i > 1) forward_[i] -= forward_[i - 1] * pivot_[i];
    }
    for (std::size_t i = n - 2; i >= 1; --i) {
      second_[i] = forward_[i];
      if (i + 2 < n) second_[i] -= upper_[i] * second_[i + 1];
    }
  }
  // Step 4: midpoint integration.
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  shape_.points[0] = p;
  const double ds = h / substeps_;
  for (std::size_t g = 0; g + 1 < n; ++g) {
    const Eigen::Vector2d& k0 = shape_.curvature[g];
    const Eigen::Vector2d& k1 = shape_.curvature[g + 1];
    for (int step = 0; step < substeps_; ++step) {
      const double t = (step + 0.5) / substeps_, u = 1.0 - t;
      const Eigen::Vector2d k =
          u * k0 + t * k1 + h * h / 6.0 * ((u * u * u - u) * second_[g] + (t * t * t - t) * second_[g + 1]);
      const Eigen::Vector3d w(k.x() * ds, k.y() * ds, 0.0);
      const Eigen::Matrix3d half = R * exp_so3(0.5 * w);
      p += half.col(2) * ds;
      R = R * exp_so3(w);
    }
    shape_.points[g + 1] = p;
  }
  shape_.status = FbgShapeStatus::ok;
  return shape_;
}

void fbg_to_global(const Eigen::Isometry3d& catheter_base_in_global, const Eigen::Isometry3d& fiber_in_base,
                   const std::vector<Eigen::Vector3d>& in, std::vector<Eigen::Vector3d>& out) {
  const Eigen::Isometry3d fiber_in_global = catheter_base_in_global * fiber_in_base;
  out.resize(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) out[i] = fiber_in_global * in[i];
}

std::vector<Eigen::Vector3d> sample_at_arc_lengths(const std::vector<Eigen::Vector3d>& polyline,
                                                   double spacing, int count) {
  if (polyline.size() < 2 || count < 1 || !std::isfinite(spacing) || spacing <= 0.0) {
    throw std::invalid_argument(
        "arc-length sampling: needs a polyline of 2 points or more, count >= 1, spacing > 0");
  }
  std::vector<Eigen::Vector3d> samples;
  samples.reserve(static_cast<std::size_t>(count));
  double arc = 0.0;
  std::size_t i = 0;
  for (int g = 0; g < count; ++g) {
    const double s = g * spacing;
    for (;;) {
      if (i + 1 >= polyline.size()) {
        throw std::invalid_argument("arc-length sampling: the polyline (" + std::to_string(arc) +
                                    " mm) is shorter than " + std::to_string(s) + " mm");
      }
      const double length = (polyline[i + 1] - polyline[i]).norm();
      if (!std::isfinite(length)) throw std::invalid_argument("arc-length sampling: a point is not finite");
      if (arc + length >= s && length > 0.0) {
        samples.push_back(polyline[i] + (s - arc) / length * (polyline[i + 1] - polyline[i]));
        break;
      }
      arc += length;
      ++i;
    }
  }
  return samples;
}

FiberCalibration calibrate_fiber_in_base(const std::vector<Eigen::Vector3d>& shape_in_fiber,
                                         const std::vector<Eigen::Vector3d>& samples) {
  if (shape_in_fiber.size() < 3 || samples.size() != shape_in_fiber.size()) {
    throw std::invalid_argument("mold calibration: needs one channel point per grating (at least 3), got " +
                                std::to_string(samples.size()) + " for " +
                                std::to_string(shape_in_fiber.size()));
  }
  for (const auto& p : samples) {
    if (!p.allFinite()) throw std::invalid_argument("mold calibration: a channel point is not finite");
  }
  // Collinear samples leave the roll about the line free.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : samples) mean += p;
  mean /= static_cast<double>(samples.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : samples) scatter += (p - mean) * (p - mean).transpose();
  const Eigen::Vector3d spread = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvalues();
  if (spread[1] < 1e-6 * spread[2] || spread[1] < 1.0) {
    throw std::invalid_argument(
        "mold calibration: the channel is (nearly) straight; its bend is what fixes the roll");
  }
  FiberCalibration result;
  result.fiber_in_base = rigid_fit(shape_in_fiber, samples);
  double sum = 0.0;
  for (std::size_t g = 0; g < samples.size(); ++g) {
    const double e = (result.fiber_in_base * shape_in_fiber[g] - samples[g]).norm();
    sum += e * e;
    result.max = std::max(result.max, e);
  }
  result.rms = std::sqrt(sum / static_cast<double>(samples.size()));
  return result;
}

ChannelValidation validate_on_channel(const std::vector<Eigen::Vector3d>& points,
                                      const std::vector<Eigen::Vector3d>& channel) {
  if (points.empty() || channel.size() < 2) {
    throw std::invalid_argument(
        "channel validation: needs points and a channel polyline of 2 points or more");
  }
  std::vector<double> distances;
  distances.reserve(points.size());
  for (const auto& p : points) {
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i + 1 < channel.size(); ++i) {
      const Eigen::Vector3d d = channel[i + 1] - channel[i];
      const double t =
          d.squaredNorm() > 0.0 ? std::clamp((p - channel[i]).dot(d) / d.squaredNorm(), 0.0, 1.0) : 0.0;
      best = std::min(best, (channel[i] + t * d - p).norm());
    }
    distances.push_back(best);
  }
  ChannelValidation v;
  for (const double d : distances) {
    v.mean += d / static_cast<double>(distances.size());
    v.max = std::max(v.max, d);
  }
  for (const double d : distances) v.standard_deviation += (d - v.mean) * (d - v.mean);
  v.standard_deviation =
      std::sqrt(v.standard_deviation / static_cast<double>(std::max<std::size_t>(1, distances.size() - 1)));
  return v;
}

FiberTruth fiber_truth(const MulticoreFiber& fiber, const std::vector<Eigen::Vector3d>& polyline) {
  fiber.validate();
  if (polyline.size() < 3) throw std::invalid_argument("fibre truth: the polyline needs at least 3 points");
  std::vector<double> arc(polyline.size(), 0.0);
  for (std::size_t i = 0; i + 1 < polyline.size(); ++i) {
    const double length = (polyline[i + 1] - polyline[i]).norm();
    if (!std::isfinite(length) || length < 1e-9 || length > 1.0) {
      throw std::invalid_argument("fibre truth: segment " + std::to_string(i) +
                                  " is not finite, repeated or longer than 1 mm");
    }
    arc[i + 1] = arc[i] + length;
  }
  if (arc.back() < fiber.length() - 1e-9) {
    throw std::invalid_argument("fibre truth: the polyline (" + std::to_string(arc.back()) +
                                " mm) is shorter than the fibre (" + std::to_string(fiber.length()) + " mm)");
  }
  // Parallel transport of the frame along the segments: R_i has the i-th segment (chord) as its z
  // axis. {F} sits at the first point with z along the curve's tangent there, which is the first chord
  // turned back by half the turn at the next vertex (the chord's direction is the tangent halfway).
  const std::size_t segments = polyline.size() - 1;
  auto turn = [&](std::size_t i) {  // rotation vector taking chord i to chord i + 1
    const Eigen::Vector3d a = (polyline[i + 1] - polyline[i]).normalized(),
                          b = (polyline[i + 2] - polyline[i + 1]).normalized();
    const Eigen::Vector3d axis = a.cross(b);
    const double angle = std::atan2(axis.norm(), a.dot(b));
    return axis.norm() > 1e-15 ? Eigen::Vector3d(axis.normalized() * angle) : Eigen::Vector3d::Zero();
  };
  const Eigen::Vector3d first_turn = turn(0);
  const Eigen::Vector3d t0 = exp_so3(-0.5 * first_turn) * (polyline[1] - polyline[0]).normalized();
  const Eigen::Vector3d helper = std::abs(t0.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d x0 = (helper - helper.dot(t0) * t0).normalized();
  Eigen::Matrix3d fiber_frame;
  fiber_frame.col(0) = x0;
  fiber_frame.col(1) = t0.cross(x0);
  fiber_frame.col(2) = t0;
  std::vector<Eigen::Matrix3d> frames(segments);
  frames[0] = exp_so3(0.5 * first_turn) * fiber_frame;
  // Curvature at the vertices between segments, in the local frame (unchanged by the transport
  // rotation, whose axis it is).
  std::vector<Eigen::Vector2d> vertex_curvature(polyline.size(), Eigen::Vector2d::Zero());
  for (std::size_t i = 0; i + 1 < segments; ++i) {
    const Eigen::Vector3d w = turn(i);
    frames[i + 1] = exp_so3(w) * frames[i];
    const double span = 0.5 * (arc[i + 2] - arc[i]);
    const Eigen::Vector3d local = frames[i].transpose() * w / span;
    vertex_curvature[i + 1] = local.head<2>();
  }
  vertex_curvature.front() = vertex_curvature[1];
  vertex_curvature.back() = vertex_curvature[polyline.size() - 2];
  FiberTruth truth;
  truth.fiber_pose.linear() = fiber_frame;
  truth.fiber_pose.translation() = polyline[0];
  const Eigen::Isometry3d to_fiber = truth.fiber_pose.inverse();
  std::size_t i = 0;
  for (int g = 0; g < fiber.gratings; ++g) {
    const double s = g * fiber.grating_spacing;
    while (i + 2 < polyline.size() && arc[i + 1] < s) ++i;
    const double t = std::clamp((s - arc[i]) / (arc[i + 1] - arc[i]), 0.0, 1.0);
    truth.points.push_back(to_fiber * (polyline[i] + t * (polyline[i + 1] - polyline[i])));
    truth.curvature.push_back(vertex_curvature[i] + t * (vertex_curvature[i + 1] - vertex_curvature[i]));
  }
  return truth;
}

SimulatedFbgInterrogator::SimulatedFbgInterrogator(const MulticoreFiber& fiber, double noise_pm,
                                                   std::uint64_t seed)
    : fiber_(fiber), noise_pm_(noise_pm), engine_(seed) {
  fiber_.validate();
  if (!std::isfinite(noise_pm) || noise_pm < 0.0)
    throw std::invalid_argument("simulated FBG interrogator: noise must be >= 0");
}

FbgFrame SimulatedFbgInterrogator::reference() const {
  FbgFrame frame;
  frame.gratings = fiber_.gratings;
  frame.cores = MulticoreFiber::cores;
  for (int g = 0; g < fiber_.gratings; ++g) {
    for (int k = 0; k < MulticoreFiber::cores; ++k) frame.wavelengths.push_back(reference_wavelength(g));
  }
  return frame;
}

FbgFrame SimulatedFbgInterrogator::measure(const std::vector<Eigen::Vector3d>& polyline,
                                           double temperature_change, std::uint64_t sequence) {
  return measure(fiber_truth(fiber_, polyline), temperature_change, sequence);
}

FbgFrame SimulatedFbgInterrogator::measure(const FiberTruth& truth, double temperature_change,
                                           std::uint64_t sequence) {
  FbgFrame frame = reference();
  frame.sequence = sequence;
  for (int g = 0; g < fiber_.gratings; ++g) {
    const Eigen::Vector2d& k = truth.curvature[static_cast<std::size_t>(g)];
    for (int c = 0; c < MulticoreFiber::cores; ++c) {
      double strain = 0.0;
      if (c > 0) {
        const double psi = fiber_.outer_core_angles[static_cast<std::size_t>(c - 1)];
        strain = fiber_.core_radius * (k.x() * std::sin(psi) - k.y() * std::cos(psi));
      }
      // Own Box–Muller from 53-bit uniforms: the same numbers on every platform.
      const double u1 = (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53;
      const double u2 = (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53;
      const double noise = noise_pm_ * 1e-3 * std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
      const double lambda = reference_wavelength(g);
      frame.wavelengths[static_cast<std::size_t>(g) * MulticoreFiber::cores + static_cast<std::size_t>(c)] =
          lambda * (1.0 + (1.0 - fiber_.photoelastic) * strain + kThermoOptic * temperature_change) + noise;
    }
  }
  return frame;
}

}  // namespace tendril::ultrasound
