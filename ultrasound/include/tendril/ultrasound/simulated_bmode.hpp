// SIMULATED B-mode ultrasound probe: renders the cross-section of a tube-shaped vessel (a centerline
// with a lumen radius, e.g. the phantom's silicone tube of Heunis et al. 2021, §4.1: 10 mm inner diameter, 1
// mm wall) cut by the probe's image plane. It is a simulation, not a scanner driver; the tests and the
// digital twin (our set-up) use it so that pose errors show up as image offsets.
//
// What it models, per pixel (centre at depth z):
//   echo = lumen (blood, anechoic) | wall (bright; part of it specular, strongest where the beam meets
//          the wall head-on, the top and bottom of the tube, weaker at its sides) | tissue (mid grey);
//   amplitude = echo · speckle · e^{−α z} + noise, clamped to [0, 1], where speckle is Rayleigh
//   distributed with unit mean (fully developed speckle) and noise is additive Gaussian (electronic).
// α is the attenuation left after the scanner's time-gain compensation. The cut is exact for a
// locally straight tube: the distance of a pixel's point to the vessel axis (through the point where
// the axis crosses the plane, along the local tangent) against the lumen radius, so an oblique cut
// gives the right ellipse. Deterministic for a given seed on every platform (own mapping of
// std::mt19937_64 output; the standard distributions are implementation-defined).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <optional>

#include "tendril/teleop/vessel_centerline.hpp"
#include "tendril/ultrasound/bmode_image.hpp"

namespace tendril::ultrasound {

struct SimulatedBModeParameters {
  double lumen_radius = 5.0;    // mm, used where the centerline carries no radii (10 mm ID tube)
  double wall_thickness = 1.0;  // mm (the article's silicone tube)
  double tissue_echo = 0.35;    // mean echo of the surrounding tissue
  double lumen_echo = 0.03;     // mean echo inside the lumen (water/blood: nearly anechoic)
  double wall_echo = 1.0;       // mean echo of the wall where the beam meets it head-on
  double wall_specular = 0.6;   // fraction of the wall echo that falls with the incidence angle
  double attenuation = 0.015;   // 1/mm of amplitude after time-gain compensation
  double noise_sigma = 0.04;    // additive Gaussian noise (of the [0, 1] scale)
  // SIMULATED calibration error: the scanner's true mm per pixel over the geometry's pixel size, along
  // a row and down a column (1: the nominal pixel size is exact).
  double lateral_scale = 1.0, axial_scale = 1.0;
};

// Where the vessel crosses one image plane: the truth a segmentation is scored against.
struct SliceTruth {
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();      // (y, z) mm in {I}: where the axis crosses the plane
  Eigen::Vector3d axis_point = Eigen::Vector3d::Zero();  // the same point in the vessel's frame
  Eigen::Vector3d tangent = Eigen::Vector3d::UnitX();    // unit axis direction there (vessel frame)
  double lumen_radius = 0.0;                             // mm
};

class SimulatedBModeProbe {
 public:
  // `vessel` is the tube's centerline in the frame the image poses are given in (the tissue frame {P}
  // in the digital twin). Throws UltrasoundSetupError for fewer than 2 points, non-finite values,
  // radii that do not match the points, or parameters that are negative or not finite.
  SimulatedBModeProbe(teleop::CenterlinePolyline vessel, const BModeGeometry& geometry,
                      const SimulatedBModeParameters& parameters = {});

  const BModeGeometry& geometry() const noexcept { return geometry_; }
  const SimulatedBModeParameters& parameters() const noexcept { return parameters_; }

  // The crossing nearest to the image centre among those inside the image, or nothing when the plane
  // misses the vessel inside the field of view. `image_pose` maps {I} into the vessel's frame.
  std::optional<SliceTruth> truth(const Eigen::Isometry3d& image_pose) const;

  // Renders one SIMULATED frame. Without a crossing the image holds tissue only.
  BModeImage render(const Eigen::Isometry3d& image_pose, std::uint64_t seed) const;

  // The true lumen (pixels whose centre lies inside the tube) for the same pose; all zero without a
  // crossing.
  LumenMask lumen_mask(const Eigen::Isometry3d& image_pose) const;

 private:
  teleop::CenterlinePolyline vessel_;
  BModeGeometry geometry_;
  SimulatedBModeParameters parameters_;
};

}  // namespace tendril::ultrasound
