// B-mode ultrasound (US) images as the reconstruction reads them, and the image frame {I} of Heunis et al.
// 2021 §2.3: the image plane is the y–z plane of {I} (x = 0 in-plane, x the elevation axis), y lateral along
// the array, z the depth from the transducer face. Pixel (u, v) — column u, row v — maps to {I} as [0, s·(u −
// u₀), s·v] mm with u₀ the centre column, so the probe axis (y = 0) runs down the middle of the image and row
// 0 is the transducer face. The L14-5 linear array of the article gives a Cartesian image, so one pixel size
// s serves both axes (the article's s_u = s_v).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <stdexcept>
#include <vector>

namespace tendril::ultrasound {

// Thrown at set-up for geometry or parameters that cannot describe an image or a filter.
class UltrasoundSetupError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

struct BModeGeometry {
  int columns = 320;          // lateral pixels: 40 mm at 0.125 mm
  int rows = 400;             // depth pixels: 50 mm, past the article's 20–40 mm focus depth
  double pixel_size = 0.125;  // mm per pixel, both axes

  double width() const noexcept { return pixel_size * columns; }
  double depth() const noexcept { return pixel_size * rows; }
  double centre_column() const noexcept { return 0.5 * (columns - 1); }
  std::size_t pixel_count() const noexcept {
    return static_cast<std::size_t>(columns) * static_cast<std::size_t>(rows);
  }
  // (y, z) in mm of the centre of pixel (column, row), in {I}.
  Eigen::Vector2d plane_point(double column, double row) const noexcept {
    return {pixel_size * (column - centre_column()), pixel_size * row};
  }
  // Fractional (column, row) of an in-plane point (y, z).
  Eigen::Vector2d pixel_of(const Eigen::Vector2d& yz) const noexcept {
    return {yz.x() / pixel_size + centre_column(), yz.y() / pixel_size};
  }
  // Throws UltrasoundSetupError unless 8 ≤ columns, rows ≤ 4096 and 0 < pixel_size ≤ 10 mm.
  void validate() const;
};

// Row-major intensities in [0, 1] (log-compressed echo amplitude as a scanner displays it).
struct BModeImage {
  BModeGeometry geometry;
  std::vector<float> pixels;  // rows × columns

  float at(int column, int row) const noexcept {
    return pixels[static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry.columns) +
                  static_cast<std::size_t>(column)];
  }
};

// A binary lumen mask over an image's pixels (1 = lumen), row-major like BModeImage::pixels.
using LumenMask = std::vector<unsigned char>;

// Sørensen–Dice coefficient 2|A∩B| / (|A| + |B|) of two masks of one size; 1 when both are empty.
// Throws UltrasoundSetupError when the sizes differ.
double dice_coefficient(const LumenMask& a, const LumenMask& b);

}  // namespace tendril::ultrasound
