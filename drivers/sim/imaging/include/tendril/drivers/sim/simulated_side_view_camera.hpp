// SimulatedSideViewCamera: a SIMULATED camera looking at one bending segment of the bare catheter
// tip from the side, parallel to its bending plane — the rig of the shape calibration (Abah 2022,
// §4.5.2: step the actuation line, take an image at each step, threshold, fit). It draws the tube
// as a dark band on a lit background from the segment's true shape (a modal model θ(s, q)), with a
// length of straight tube before the segment, a soft edge (Gaussian optical blur), uneven
// illumination and sensor noise, and encodes the frame as PNG.
//
// Image geometry: the catheter enters from the bottom edge, image up = +z (the insertion axis),
// image right = +x (the side a bend with θ < π/2 turns to), `mm_per_pixel` at the bending plane.
// The straight tube's axis is at column `base_column`, the segment base `straight_mm` above the
// bottom edge.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <vector>

#include "tendril/teleop/modal_catheter_kinematics.hpp"

namespace tendril::sim {

struct SideViewCameraOptions {
  int width = 800;
  int height = 1100;
  double mm_per_pixel = 0.025;
  double base_column = 150.0;     // column of the straight tube's axis (pixels)
  double straight_mm = 3.0;       // visible straight tube below the segment base
  double tube_diameter_mm = 0.6;  // the bare NiTi tip (Abah 2022, §4.4.1: 0.6 mm proximal tube)
  double blur_sigma_px = 1.2;     // optics
  double noise_sigma = 3.0;       // grey levels, Gaussian
  double background = 215.0;      // grey level of the lit background at the centre
  double vignetting = 0.12;       // fractional fall-off of the background toward the corners
  double tube_grey = 40.0;        // grey level of the tube
  std::uint64_t noise_seed = 0x51de;
};

class SideViewCameraError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

class SimulatedSideViewCamera {
 public:
  // `shape`: the segments' true shapes. Throws SideViewCameraError for sizes outside 32..4096 px,
  // non-positive scales, or a base column outside the image.
  SimulatedSideViewCamera(const teleop::ModalCatheterParameters& shape, SideViewCameraOptions options = {});

  const SideViewCameraOptions& options() const noexcept { return options_; }

  // PNG (8-bit grey) of `segment` at actuation `actuation_mm`; each call draws new noise.
  std::vector<std::uint8_t> capture_png(teleop::CatheterSegment segment, double actuation_mm);
  // The true backbone in the image's (x, z) frame (mm), base of the straight tube first; what an
  // ideal extraction would find (for tests).
  std::vector<Eigen::Vector2d> true_backbone(teleop::CatheterSegment segment, double actuation_mm,
                                             double spacing_mm = 0.01) const;

 private:
  teleop::ModalCatheterKinematics shape_;
  SideViewCameraOptions options_;
  std::uint64_t frames_ = 0;
};

}  // namespace tendril::sim
