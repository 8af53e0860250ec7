// SimulatedFluoroscope: a SIMULATED X-ray fluoroscope (one plane of a bi-plane C-arm). It renders
// what a real detector would show of the catheter and a contrast-filled vessel: a perspective
// (cone-beam) projection from a point source onto a flat detector, Beer–Lambert attenuation, focal
// spot / detector blur, Poisson-like quantum noise, and JPEG encoding.
//
// Geometry (millimetres, in the robot's world frame; the SRMC inserts along +z):
// - the source sits at isocentre − SOD·d, the detector plane is perpendicular to the beam direction d
//   at distance SID from the source; magnification at depth t along the beam is SID / t.
// - AP view: beam along +y, image columns along +x, image up along +z.
//   Lateral view: beam along +x, image columns along −y, image up along +z.
// - pixel (column, row) of the detector centre is ((width−1)/2, (height−1)/2); rows grow downwards.
//
// Image formation: expected counts per pixel = photons_per_pixel · exp(−Σ μ·chord), where the
// catheter, its tip marker and the vessel are tubes whose chord length across the tube is
// 2·sqrt(r² − d²) (d = distance from the axis), drawn in a few bands. The blurred expected image
// is shown as display = counts · display_gain and each pixel gets Gaussian noise with the Poisson
// variance of its count (Var(display) = display · display_gain), so brighter regions are noisier
// in absolute terms, as on a real detector. Radio-opaque objects appear dark.
//
// Not thread-safe: one instance per thread. The header is free of OpenCV types on purpose, so that
// only this library compiles against OpenCV.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace tendril::sim {

enum class FluoroView { kAp, kLateral };

// "ap" / "lateral".
const char* view_name(FluoroView view) noexcept;

struct FluoroscopeGeometry {
  double sid_mm = 1000.0;            // source to detector distance
  double sod_mm = 750.0;             // source to isocentre (object) distance; magnification SID/SOD
  double pixel_spacing_mm = 0.3125;  // detector pixel pitch (160 mm / 512 px by default)
  int width = 512;                   // detector pixels
  int height = 512;
  Eigen::Vector3d isocentre{0.0, 0.0, 60.0};  // mm, world frame
};

struct FluoroscopeOptions {
  FluoroscopeGeometry geometry;
  double instrument_diameter_mm = 1.0;
  double catheter_attenuation_per_mm = 1.0;  // μ of the catheter (braided, radio-opaque)
  double tip_marker_diameter_mm = 1.6;       // platinum marker band at the tip: the darkest spot
  double tip_marker_length_mm = 1.5;
  double tip_marker_attenuation_per_mm = 2.5;
  double contrast_attenuation_per_mm = 0.18;  // iodinated contrast in the vessel lumen
  double tissue_attenuation = 0.8;            // line integral of the uniform tissue background
  bool anatomy = true;                        // smooth low-contrast blobs in the background
  double photons_per_pixel = 1500.0;          // expected counts of an unattenuated pixel
  double display_gain = 0.0;                  // display value per count; 0 = 240 / photons_per_pixel
  double blur_sigma_px = 0.8;                 // focal spot + detector blur (Gaussian σ, pixels)
  std::uint64_t noise_seed = 0x7e5d'7e5dULL;
};

// A contrast-filled vessel: centerline points (mm) and a lumen radius per point.
struct VesselTube {
  std::vector<Eigen::Vector3d> centerline;
  std::vector<double> radius_mm;
};

struct DetectorPoint {
  double column = 0.0;
  double row = 0.0;
  double magnification = 0.0;  // SID / depth
  bool in_front = false;       // false when the point is at or behind the source
};

// The X-ray through a detector point: from the source (world mm) along a unit direction.
struct DetectorRay {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();
};

class FluoroscopeError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

class SimulatedFluoroscope {
 public:
  // `vessels`: contrast-filled branches, drawn once (they do not move). Throws FluoroscopeError on a
  // geometry that cannot image (non-positive distances, SOD ≥ SID, sizes outside 16..4096 px), a
  // vessel with mismatched radii, or non-finite numbers.
  SimulatedFluoroscope(FluoroView view, FluoroscopeOptions options,
                       const std::vector<VesselTube>& vessels = {});
  ~SimulatedFluoroscope();
  SimulatedFluoroscope(SimulatedFluoroscope&&) noexcept;
  SimulatedFluoroscope& operator=(SimulatedFluoroscope&&) noexcept;

  FluoroView view() const noexcept;
  const FluoroscopeOptions& options() const noexcept;
  int width() const noexcept;
  int height() const noexcept;
  double display_gain() const noexcept;

  // Where a world point lands on the detector (sub-pixel).
  DetectorPoint project(const Eigen::Vector3d& world_mm) const noexcept;
  // The inverse: the ray from the source through detector point (column, row); every world point on
  // it projects there. Two planes' rays through the same object point meet at it (triangulation).
  DetectorRay ray(double column, double row) const noexcept;

  // Renders one exposure of the catheter whose backbone is `backbone` (world mm, base to tip; an
  // empty span shows only the vessel and background). Returns the 8-bit grey image, row-major,
  // width × height bytes; valid until the next render.
  std::span<const std::uint8_t> render(std::span<const Eigen::Vector3d> backbone);
  // Same, without quantum noise: the expected display value (for tests and for calibration).
  std::span<const std::uint8_t> render_noiseless(std::span<const Eigen::Vector3d> backbone);

  // JPEG of the last render (baseline, 8-bit grey) at `quality` 1..100, appended to `out` after clearing it.
  void encode_jpeg(int quality, std::vector<std::uint8_t>& out) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Points on the vessel wall: rings of `points_per_ring` around the centerline, one ring every
// `spacing_mm` of arc length. For foxglove.PointCloud (/maps/vessel).
std::vector<Eigen::Vector3f> vessel_wall_points(const VesselTube& vessel, double spacing_mm = 0.5,
                                                int points_per_ring = 16);

}  // namespace tendril::sim
