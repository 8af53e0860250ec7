// B-mode image geometry checks and the Dice coefficient (Heunis et al. 2021, §4.2).
#include "tendril/ultrasound/bmode_image.hpp"

#include <cmath>
#include <string>

namespace tendril::ultrasound {

void BModeGeometry::validate() const {
  if (columns < 8 || columns > 4096 || rows < 8 || rows > 4096) {
    throw UltrasoundSetupError("B-mode geometry: columns and rows must lie in 8..4096, got " +
                               std::to_string(columns) + " x " + std::to_string(rows));
  }
  if (!std::isfinite(pixel_size) || pixel_size <= 0.0 || pixel_size > 10.0) {
    throw UltrasoundSetupError("B-mode geometry: pixel_size must be in (0, 10] mm, got " +
                               std::to_string(pixel_size));
  }
}

double dice_coefficient(const LumenMask& a, const LumenMask& b) {
  if (a.size() != b.size()) {
    throw UltrasoundSetupError("dice_coefficient: masks of " + std::to_string(a.size()) + " and " +
                               std::to_string(b.size()) + " pixels cannot be compared");
  }
  std::size_t both = 0, count_a = 0, count_b = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const bool in_a = a[i] != 0, in_b = b[i] != 0;
    count_a += in_a;
    count_b += in_b;
    both += in_a && in_b;
  }
  if (count_a + count_b == 0) return 1.0;
  return 2.0 * static_cast<double>(both) / static_cast<double>(count_a + count_b);
}

}  // namespace tendril::ultrasound
