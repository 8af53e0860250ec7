#include "tendril/teleop/vessel_centerline.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <random>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Points closer than this (mm) are treated as the same point.
constexpr double kDuplicateDistance = 1e-9;

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t' || s.front() == '\r')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

// Parses one number; false if the field is not entirely a number.
bool parse_number(std::string_view field, double& value) {
  const std::string text(trim(field));
  if (text.empty()) return false;
  char* end = nullptr;
  value = std::strtod(text.c_str(), &end);
  return end == text.c_str() + text.size();
}

std::vector<std::string_view> split_fields(std::string_view line) {
  std::vector<std::string_view> fields;
  std::size_t start = 0;
  while (true) {
    const auto comma = line.find(',', start);
    fields.push_back(
        line.substr(start, comma == std::string_view::npos ? std::string_view::npos : comma - start));
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return fields;
}

double median(std::vector<double> values) {
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

double polyline_length(const std::vector<Eigen::Vector3d>& points) {
  double length = 0.0;
  for (std::size_t i = 1; i < points.size(); ++i) length += (points[i] - points[i - 1]).norm();
  return length;
}

}  // namespace

std::vector<CenterlinePolyline> parse_centerline_csv(std::string_view csv_text, double branch_jump_factor) {
  if (!(std::isfinite(branch_jump_factor) && branch_jump_factor > 1.0)) {
    throw VesselInputError("centerline CSV: branch_jump_factor must be > 1, got " +
                           std::to_string(branch_jump_factor));
  }
  CenterlinePolyline all;
  std::size_t columns = 0;
  bool first_content_line = true;
  std::size_t line_number = 0;
  std::size_t start = 0;
  while (start <= csv_text.size()) {
    const auto newline = csv_text.find('\n', start);
    const auto raw =
        csv_text.substr(start, newline == std::string_view::npos ? std::string_view::npos : newline - start);
    start = newline == std::string_view::npos ? csv_text.size() + 1 : newline + 1;
    ++line_number;
    const auto line = trim(raw);
    if (line.empty() || line.front() == '#') continue;
    const auto fields = split_fields(line);
    double values[4] = {0, 0, 0, 0};
    bool numeric = fields.size() == 3 || fields.size() == 4;
    for (std::size_t f = 0; numeric && f < fields.size(); ++f) numeric = parse_number(fields[f], values[f]);
    if (!numeric) {
      if (first_content_line) {  // a header such as "x,y,z,radius"
        first_content_line = false;
        continue;
      }
      throw VesselInputError("centerline CSV line " + std::to_string(line_number) +
                             ": expected 3 or 4 comma-separated numbers (x,y,z[,radius] in mm), got '" +
                             std::string(line) + "'");
    }
    first_content_line = false;
    if (columns == 0) columns = fields.size();
    if (fields.size() != columns) {
      throw VesselInputError("centerline CSV line " + std::to_string(line_number) + ": has " +
                             std::to_string(fields.size()) + " columns but earlier rows have " +
                             std::to_string(columns));
    }
    for (std::size_t f = 0; f < columns; ++f) {
      if (!std::isfinite(values[f])) {
        throw VesselInputError("centerline CSV line " + std::to_string(line_number) +
                               ": value is not finite");
      }
    }
    all.points.emplace_back(values[0], values[1], values[2]);
    if (columns == 4) {
      if (values[3] < 0.0) {
        throw VesselInputError("centerline CSV line " + std::to_string(line_number) + ": negative radius");
      }
      all.radii.push_back(values[3]);
    }
  }
  if (all.points.empty()) throw VesselInputError("centerline CSV: no points (empty input)");

  // Split where a step is much longer than the typical spacing (a jump to another branch).
  std::vector<double> steps;
  for (std::size_t i = 1; i < all.points.size(); ++i) {
    const double step = (all.points[i] - all.points[i - 1]).norm();
    if (step > kDuplicateDistance) steps.push_back(step);
  }
  std::vector<CenterlinePolyline> branches(1);
  const double jump =
      steps.empty() ? std::numeric_limits<double>::infinity() : branch_jump_factor * median(steps);
  for (std::size_t i = 0; i < all.points.size(); ++i) {
    if (i > 0 && (all.points[i] - all.points[i - 1]).norm() > jump) branches.emplace_back();
    branches.back().points.push_back(all.points[i]);
    if (!all.radii.empty()) branches.back().radii.push_back(all.radii[i]);
  }
  return branches;
}

std::size_t nearest_branch(const std::vector<CenterlinePolyline>& branches, const Eigen::Vector3d& point) {
  std::size_t best = branches.size();
  double best_distance = std::numeric_limits<double>::infinity();
  for (std::size_t b = 0; b < branches.size(); ++b) {
    const auto& p = branches[b].points;
    if (p.empty()) continue;
    const double d = std::min((p.front() - point).norm(), (p.back() - point).norm());
    if (d < best_distance) {
      best_distance = d;
      best = b;
    }
  }
  if (best == branches.size()) throw VesselInputError("nearest_branch: no branches with points");
  return best;
}

CenterlinePolyline orient_from(const CenterlinePolyline& branch, const Eigen::Vector3d& point) {
  CenterlinePolyline out = branch;
  if (!out.points.empty() && (out.points.back() - point).norm() < (out.points.front() - point).norm()) {
    std::reverse(out.points.begin(), out.points.end());
    std::reverse(out.radii.begin(), out.radii.end());
  }
  return out;
}

VesselCenterline VesselCenterline::from_polyline(const CenterlinePolyline& polyline, double ds) {
  if (!(std::isfinite(ds) && ds > 0.0)) {
    throw VesselInputError("vessel centerline: sample spacing ds must be > 0 mm, got " + std::to_string(ds));
  }
  if (polyline.points.empty()) throw VesselInputError("vessel centerline: no points (empty input)");
  const bool with_radius = !polyline.radii.empty();
  if (with_radius && polyline.radii.size() != polyline.points.size()) {
    throw VesselInputError("vessel centerline: " + std::to_string(polyline.radii.size()) + " radii for " +
                           std::to_string(polyline.points.size()) + " points");
  }
  std::vector<Eigen::Vector3d> points;
  std::vector<double> radii;
  for (std::size_t i = 0; i < polyline.points.size(); ++i) {
    const auto& p = polyline.points[i];
    if (!p.allFinite() || (with_radius && !std::isfinite(polyline.radii[i]))) {
      throw VesselInputError("vessel centerline: point " + std::to_string(i) + " is not finite");
    }
    if (!points.empty() && (p - points.back()).norm() <= kDuplicateDistance) continue;
    points.push_back(p);
    if (with_radius) radii.push_back(polyline.radii[i]);
  }
  if (points.size() < 3) {
    throw VesselInputError("vessel centerline: needs at least 3 distinct points, got " +
                           std::to_string(points.size()) + " (repeated points count once)");
  }
  const double total = polyline_length(points);
  if (total < kMinimumPlausibleLengthMm) {
    throw VesselInputError("vessel centerline: total length " + std::to_string(total) +
                           " is below 1 mm; coordinates look like metres, but millimetres are expected "
                           "(multiply by 1000)");
  }
  if (total > kMaximumPlausibleLengthMm) {
    throw VesselInputError("vessel centerline: total length " + std::to_string(total) +
                           " mm is more than 10 m; millimetres are expected (was it in micrometres?)");
  }
  if (total / ds > static_cast<double>(kMaximumSamples)) {
    throw VesselInputError("vessel centerline: ds = " + std::to_string(ds) + " mm gives more than " +
                           std::to_string(kMaximumSamples) + " samples over " + std::to_string(total) +
                           " mm");
  }
  const auto samples = static_cast<std::size_t>(std::floor(total / ds + 1e-4)) + 1;
  if (samples < 3) {
    throw VesselInputError("vessel centerline: length " + std::to_string(total) +
                           " mm is too short for ds = " + std::to_string(ds) + " mm (fewer than 3 samples)");
  }

  VesselCenterline out;
  out.ds_ = ds;
  out.points_.reserve(samples);
  std::size_t segment = 0;
  double segment_start = 0.0;  // arc length at points[segment]
  for (std::size_t k = 0; k < samples; ++k) {
    const double s = ds * static_cast<double>(k);
    double segment_length = (points[segment + 1] - points[segment]).norm();
    while (segment + 2 < points.size() && s > segment_start + segment_length) {
      segment_start += segment_length;
      ++segment;
      segment_length = (points[segment + 1] - points[segment]).norm();
    }
    const double t = std::clamp((s - segment_start) / segment_length, 0.0, 1.0);
    out.points_.push_back(points[segment] + t * (points[segment + 1] - points[segment]));
    if (with_radius) out.radii_.push_back(radii[segment] + t * (radii[segment + 1] - radii[segment]));
  }
  // A path that doubles back within two samples has no tangent there (the central difference
  // vanishes) and is no vessel: refuse it rather than plan on it.
  for (std::size_t k = 1; k + 1 < out.points_.size(); ++k) {
    const Eigen::Vector3d before = out.points_[k] - out.points_[k - 1],
                          after = out.points_[k + 1] - out.points_[k];
    if (before.dot(after) < -0.5 * before.norm() * after.norm()) {
      throw VesselInputError(
          "vessel centerline: the path turns back on itself by more than 120° near arc length " +
          std::to_string(out.arc_length(k)) + " mm (a smaller ds, or a jump to another branch?)");
    }
  }
  out.compute_tangents_and_angles();
  return out;
}

VesselCenterline VesselCenterline::from_csv(std::string_view csv_text, double ds, std::size_t branch_index,
                                            double branch_jump_factor) {
  const auto branches = parse_centerline_csv(csv_text, branch_jump_factor);
  if (branch_index >= branches.size()) {
    throw VesselInputError("vessel centerline: branch " + std::to_string(branch_index) +
                           " requested but the CSV has " + std::to_string(branches.size()) + " branch(es)");
  }
  return from_polyline(branches[branch_index], ds);
}

VesselCenterline VesselCenterline::from_csv_nearest(std::string_view csv_text, double ds,
                                                    const Eigen::Vector3d& start_point,
                                                    double branch_jump_factor) {
  const auto branches = parse_centerline_csv(csv_text, branch_jump_factor);
  return from_polyline(orient_from(branches[nearest_branch(branches, start_point)], start_point), ds);
}

void VesselCenterline::compute_tangents_and_angles() {
  const std::size_t n = points_.size();
  tangents_.resize(n);
  yaw_.resize(n);
  pitch_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    // Second-order differences everywhere: central inside, one-sided three-point at the ends.
    if (i == 0) {
      tangents_[i] = (-3.0 * points_[0] + 4.0 * points_[1] - points_[2]).normalized();
    } else if (i + 1 == n) {
      tangents_[i] = (3.0 * points_[n - 1] - 4.0 * points_[n - 2] + points_[n - 3]).normalized();
    } else {
      tangents_[i] = (points_[i + 1] - points_[i - 1]).normalized();
    }
  }
  double previous_yaw = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d& z2 = tangents_[i];
    // Eq. 4.2: x̂₁ is the normalised projection of ẑ₂ onto the x₀-y₀ plane.
    const double horizontal = std::hypot(z2.x(), z2.y());
    Eigen::Vector3d x1;
    if (horizontal > 1e-12) {
      x1 = Eigen::Vector3d(z2.x(), z2.y(), 0.0) / horizontal;
      previous_yaw = std::atan2(x1.y(), x1.x());  // eq. 4.3, α
    } else {
      x1 = Eigen::Vector3d(std::cos(previous_yaw), std::sin(previous_yaw), 0.0);
    }
    yaw_[i] = previous_yaw;
    pitch_[i] = std::atan2(z2.dot(x1), z2.z());  // eq. 4.3, β
  }
}

Eigen::Matrix3d VesselCenterline::local_frame(std::size_t i) const noexcept {
  return (Eigen::AngleAxisd(yaw_[i], Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch_[i], Eigen::Vector3d::UnitY()))
      .toRotationMatrix();
}

VesselCenterline VesselCenterline::transformed(const Eigen::Matrix3d& rotation,
                                               const Eigen::Vector3d& translation) const {
  VesselCenterline out = *this;
  for (auto& p : out.points_) p = rotation * p + translation;
  out.compute_tangents_and_angles();
  return out;
}

Eigen::Isometry3d VesselCenterline::insertion_alignment() const {
  Eigen::Isometry3d alignment = Eigen::Isometry3d::Identity();
  alignment.linear() =
      Eigen::Quaterniond::FromTwoVectors(tangents_.front(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  alignment.translation() = -(alignment.linear() * points_.front());
  return alignment;
}

VesselCenterline VesselCenterline::aligned_to_insertion() const {
  const Eigen::Isometry3d alignment = insertion_alignment();
  return transformed(alignment.linear(), alignment.translation());
}

Eigen::Isometry3d placement_at_entry(const CenterlinePolyline& vessel, const Eigen::Isometry3d& entry,
                                     double ds) {
  return entry * VesselCenterline::from_polyline(vessel, ds).insertion_alignment();
}

CenterlinePolyline transformed(const CenterlinePolyline& vessel, const Eigen::Isometry3d& placement) {
  CenterlinePolyline out;
  out.radii = vessel.radii;
  out.points.reserve(vessel.points.size());
  for (const auto& p : vessel.points) out.points.push_back(placement * p);
  return out;
}

CenterlinePolyline make_synthetic_ica(std::uint32_t seed, const SyntheticIcaOptions& options) {
  const auto& o = options;
  if (!(o.length > 0.0 && o.point_spacing > 0.0 && o.min_bend_radius > 0.0 &&
        o.max_bend_radius >= o.min_bend_radius && o.min_vessel_radius > 0.0 &&
        o.max_vessel_radius >= o.min_vessel_radius && o.point_spacing < o.length)) {
    throw VesselInputError("make_synthetic_ica: lengths and radii must be positive and min <= max");
  }
  std::mt19937 engine(seed);
  // std::uniform_real_distribution is implementation-defined; this mapping is the same everywhere.
  auto uniform = [&engine](double lo, double hi) {
    return lo + (hi - lo) * (static_cast<double>(engine()) / 4294967296.0);
  };
  CenterlinePolyline out;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();  // columns: normal, binormal, tangent
  const double radius_phase = uniform(0.0, 2.0 * kPi);
  double s = 0.0;
  auto emit = [&] {
    out.points.push_back(position);
    const double mid = 0.5 * (o.min_vessel_radius + o.max_vessel_radius);
    const double amplitude = 0.5 * (o.max_vessel_radius - o.min_vessel_radius);
    out.radii.push_back(mid + amplitude * std::sin(2.0 * kPi * s / 60.0 + radius_phase));
  };
  emit();
  bool straight = true;  // alternate straight runs and bends, starting straight at the insertion point
  while (s < o.length - 1e-9) {
    double piece_length;
    double curvature = 0.0;
    if (straight) {
      piece_length = uniform(5.0, 15.0);
    } else {
      const double bend_radius = uniform(o.min_bend_radius, o.max_bend_radius);
      curvature = 1.0 / bend_radius;
      piece_length = bend_radius * uniform(0.5 * kPi, 1.0 * kPi);  // 90°–180° turns, as in the siphon
      // Each bend in its own plane: roll the frame about the tangent.
      frame = frame * Eigen::AngleAxisd(uniform(-kPi, kPi), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    }
    straight = !straight;
    piece_length = std::min(piece_length, o.length - s);
    const auto steps =
        std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(piece_length / o.point_spacing)));
    const double h = piece_length / static_cast<double>(steps);
    for (std::size_t k = 0; k < steps; ++k) {
      // Circular-arc step in the frame's normal-tangent plane whose chord is exactly h, so the
      // polyline (what from_polyline measures) has exactly the requested length.
      const double angle = curvature > 0.0 ? 2.0 * std::asin(std::min(1.0, 0.5 * curvature * h)) : 0.0;
      const Eigen::Vector3d local = curvature > 0.0 ? Eigen::Vector3d((1.0 - std::cos(angle)) / curvature,
                                                                      0.0, std::sin(angle) / curvature)
                                                    : Eigen::Vector3d(0.0, 0.0, h);
      position += frame * local;
      frame = frame * Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
      s += h;
      emit();
    }
  }
  return out;
}

}  // namespace tendril::teleop
