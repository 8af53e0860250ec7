// SIMULATED B-mode probe (see the header for the model).
#include "tendril/ultrasound/simulated_bmode.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

namespace tendril::ultrasound {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Uniform in (0, 1) from 53 bits of the engine, the same on every platform.
double open_uniform(std::mt19937_64& engine) {
  return (static_cast<double>(engine() >> 11) + 0.5) * 0x1.0p-53;
}

void check_finite_non_negative(double value, const char* name) {
  if (!std::isfinite(value) || value < 0.0) {
    throw UltrasoundSetupError(std::string("simulated B-mode: ") + name + " must be finite and >= 0, got " +
                               std::to_string(value));
  }
}

}  // namespace

SimulatedBModeProbe::SimulatedBModeProbe(teleop::CenterlinePolyline vessel, const BModeGeometry& geometry,
                                         const SimulatedBModeParameters& parameters)
    : vessel_(std::move(vessel)), geometry_(geometry), parameters_(parameters) {
  geometry_.validate();
  if (vessel_.points.size() < 2) {
    throw UltrasoundSetupError("simulated B-mode: the vessel centerline needs at least 2 points, got " +
                               std::to_string(vessel_.points.size()));
  }
  if (!vessel_.radii.empty() && vessel_.radii.size() != vessel_.points.size()) {
    throw UltrasoundSetupError("simulated B-mode: " + std::to_string(vessel_.radii.size()) + " radii for " +
                               std::to_string(vessel_.points.size()) + " centerline points");
  }
  for (std::size_t i = 0; i < vessel_.points.size(); ++i) {
    if (!vessel_.points[i].allFinite() || (!vessel_.radii.empty() && !(vessel_.radii[i] > 0.0))) {
      throw UltrasoundSetupError("simulated B-mode: centerline point " + std::to_string(i) +
                                 " is not finite or has a radius that is not positive");
    }
  }
  check_finite_non_negative(parameters_.lumen_radius, "lumen_radius");
  check_finite_non_negative(parameters_.wall_thickness, "wall_thickness");
  check_finite_non_negative(parameters_.tissue_echo, "tissue_echo");
  check_finite_non_negative(parameters_.lumen_echo, "lumen_echo");
  check_finite_non_negative(parameters_.wall_echo, "wall_echo");
  check_finite_non_negative(parameters_.wall_specular, "wall_specular");
  check_finite_non_negative(parameters_.attenuation, "attenuation");
  check_finite_non_negative(parameters_.noise_sigma, "noise_sigma");
  for (const double scale : {parameters_.lateral_scale, parameters_.axial_scale}) {
    if (!std::isfinite(scale) || scale < 0.5 || scale > 2.0)
      throw UltrasoundSetupError("simulated B-mode: a pixel scale factor must be in [0.5, 2], got " +
                                 std::to_string(scale));
  }
  if (parameters_.wall_specular > 1.0) {
    throw UltrasoundSetupError("simulated B-mode: wall_specular is a fraction in [0, 1], got " +
                               std::to_string(parameters_.wall_specular));
  }
}

std::optional<SliceTruth> SimulatedBModeProbe::truth(const Eigen::Isometry3d& image_pose) const {
  const Eigen::Vector3d origin = image_pose.translation();
  const Eigen::Vector3d normal = image_pose.linear().col(0);
  std::optional<SliceTruth> best;
  double best_distance = 0.0;
  const double half_width = 0.5 * geometry_.width();
  for (std::size_t i = 0; i + 1 < vessel_.points.size(); ++i) {
    const Eigen::Vector3d& a = vessel_.points[i];
    const Eigen::Vector3d& b = vessel_.points[i + 1];
    const double da = normal.dot(a - origin), db = normal.dot(b - origin);
    if ((da > 0.0 && db > 0.0) || (da < 0.0 && db < 0.0) || da == db) continue;
    const double t = da / (da - db);
    const Eigen::Vector3d point = a + t * (b - a);
    const Eigen::Vector3d local = image_pose.inverse() * point;
    if (std::abs(local.y()) > half_width || local.z() < 0.0 || local.z() > geometry_.depth()) continue;
    const double distance = Eigen::Vector2d(local.y(), local.z() - 0.5 * geometry_.depth()).norm();
    if (best && distance >= best_distance) continue;
    SliceTruth truth;
    truth.centre = {local.y(), local.z()};
    truth.axis_point = point;
    truth.tangent = (b - a).normalized();
    truth.lumen_radius = vessel_.radii.empty()
                             ? parameters_.lumen_radius
                             : vessel_.radii[i] + t * (vessel_.radii[i + 1] - vessel_.radii[i]);
    best = truth;
    best_distance = distance;
  }
  return best;
}

namespace {

// Distance of the in-plane point (y, z) to the vessel axis, and the in-plane direction away from it.
struct AxisDistance {
  double distance;
  double depth_cosine;  // |cos| of the angle between the wall normal (in-plane) and the beam (z)
};

AxisDistance axis_distance(const Eigen::Isometry3d& pose, const SliceTruth& truth, double y, double z) {
  const Eigen::Vector3d point = pose * Eigen::Vector3d(0.0, y, z);
  Eigen::Vector3d radial = point - truth.axis_point;
  radial -= radial.dot(truth.tangent) * truth.tangent;
  const double distance = radial.norm();
  double depth_cosine = 1.0;
  if (distance > 1e-9) {
    // The wall normal seen in the image plane: the radial direction's in-plane part.
    const Eigen::Vector3d in_image = pose.linear().transpose() * radial;
    const Eigen::Vector2d in_plane(in_image.y(), in_image.z());
    if (in_plane.norm() > 1e-9) depth_cosine = std::abs(in_plane.y()) / in_plane.norm();
  }
  return {distance, depth_cosine};
}

}  // namespace

BModeImage SimulatedBModeProbe::render(const Eigen::Isometry3d& image_pose, std::uint64_t seed) const {
  BModeImage image;
  image.geometry = geometry_;
  image.pixels.resize(geometry_.pixel_count());
  const std::optional<SliceTruth> crossing = truth(image_pose);
  std::mt19937_64 engine(seed);
  const double rayleigh_sigma = std::sqrt(2.0 / kPi);  // unit-mean Rayleigh
  const auto& p = parameters_;
  for (int row = 0; row < geometry_.rows; ++row) {
    for (int column = 0; column < geometry_.columns; ++column) {
      const Eigen::Vector2d yz =
          geometry_.plane_point(column, row)
              .cwiseProduct(Eigen::Vector2d(parameters_.lateral_scale, parameters_.axial_scale));
      double echo = p.tissue_echo;
      if (crossing) {
        const AxisDistance d = axis_distance(image_pose, *crossing, yz.x(), yz.y());
        if (d.distance < crossing->lumen_radius) {
          echo = p.lumen_echo;
        } else if (d.distance < crossing->lumen_radius + p.wall_thickness) {
          echo = p.wall_echo * (1.0 - p.wall_specular + p.wall_specular * d.depth_cosine);
        }
      }
      // Three uniforms per pixel, always drawn, so one pixel's draw never shifts another's.
      const double u1 = open_uniform(engine), u2 = open_uniform(engine), u3 = open_uniform(engine);
      const double speckle = rayleigh_sigma * std::sqrt(-2.0 * std::log(u1));
      const double noise = p.noise_sigma * std::sqrt(-2.0 * std::log(u2)) * std::cos(2.0 * kPi * u3);
      const double value = echo * speckle * std::exp(-p.attenuation * yz.y()) + noise;
      image.pixels[static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry_.columns) +
                   static_cast<std::size_t>(column)] = static_cast<float>(std::clamp(value, 0.0, 1.0));
    }
  }
  return image;
}

LumenMask SimulatedBModeProbe::lumen_mask(const Eigen::Isometry3d& image_pose) const {
  LumenMask mask(geometry_.pixel_count(), 0);
  const std::optional<SliceTruth> crossing = truth(image_pose);
  if (!crossing) return mask;
  for (int row = 0; row < geometry_.rows; ++row) {
    for (int column = 0; column < geometry_.columns; ++column) {
      const Eigen::Vector2d yz =
          geometry_.plane_point(column, row)
              .cwiseProduct(Eigen::Vector2d(parameters_.lateral_scale, parameters_.axial_scale));
      if (axis_distance(image_pose, *crossing, yz.x(), yz.y()).distance < crossing->lumen_radius) {
        mask[static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry_.columns) +
             static_cast<std::size_t>(column)] = 1;
      }
    }
  }
  return mask;
}

}  // namespace tendril::ultrasound
