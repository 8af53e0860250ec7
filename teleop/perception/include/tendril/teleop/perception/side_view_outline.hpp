// The image path of the shape calibration (Abah 2022, §4.5.2): a photograph of one bending segment,
// taken parallel to its bending plane, becomes the segment's backbone as points (x, z) in mm, ready
// for teleop::extract_tangent_angles (smoothing, truncation of the straight part, θ(s) by forward
// differences) and the least-squares fit of the shape matrix.
//
// Steps: decode (PNG or JPEG, sized from the header first; colour is turned to grey), threshold
// (Otsu unless a level is given), keep the largest connected catheter region that touches the edge
// the catheter enters from, thin it to a one-pixel skeleton (Zhang–Suen, with the entry edge
// extended so the skeleton reaches it), and walk the skeleton's longest path from the entry edge, so
// spurs from a rough outline are dropped.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace tendril::teleop::perception {

enum class ImageEdge { kBottom, kTop, kLeft, kRight };

// "bottom", "top", "left", "right"; throws SideViewImageError otherwise.
ImageEdge parse_image_edge(const std::string& name);

struct SideViewImageOptions {
  double mm_per_pixel = 0.0;             // scale in the bending plane (required, > 0)
  ImageEdge entry = ImageEdge::kBottom;  // the edge the catheter enters the picture from
  // Mirror the image's lateral axis: false = a bend with θ < π/2 (toward +x) shows to the right of
  // the insertion direction as seen in the picture (for entry from the bottom: to the right).
  bool mirror = false;
  bool dark_catheter = true;  // the catheter is darker than the background (backlit rig)
  int threshold = -1;         // grey level 0..255; −1 = Otsu
  std::size_t max_pixels = std::size_t{4096} * 4096;
};

struct SideViewOutline {
  std::vector<Eigen::Vector2d> points;  // backbone (x, z) in mm, from the entry edge to the tip
  int width = 0, height = 0;
  int threshold = 0;                // the level used
  std::size_t catheter_pixels = 0;  // area of the region kept
  double tube_width_mm = 0.0;       // area / skeleton length: a check of the scale and threshold
};

class SideViewImageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Throws SideViewImageError with a message for a person: not PNG/JPEG, damaged or oversized, a bad
// option, no catheter region touching the entry edge, or a skeleton too short to use (< 8 points).
SideViewOutline extract_side_view_outline(std::span<const std::uint8_t> encoded_image,
                                          const SideViewImageOptions& options);

}  // namespace tendril::teleop::perception
