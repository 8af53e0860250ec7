// Fuzz target: FBG interrogator frames (the text link of tendril/ultrasound/fbg_shape.hpp) through
// parsing, formatting and, for four-core frames, the shape reconstruction. Bad input must end in
// FbgFrameError; a parsed frame must format back to itself and reconstruct to finite points.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "tendril/ultrasound/fbg_shape.hpp"

using namespace tendril::ultrasound;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  try {
    const FbgFrame frame = parse_fbg_frame(input);
    const FbgFrame again = parse_fbg_frame(format_fbg_frame(frame));
    if (again.sequence != frame.sequence || again.gratings != frame.gratings || again.cores != frame.cores ||
        again.wavelengths != frame.wavelengths) {
      std::abort();
    }
    if (frame.cores == MulticoreFiber::cores && frame.gratings >= 2) {
      MulticoreFiber fiber;
      fiber.gratings = frame.gratings;
      SimulatedFbgInterrogator interrogator(fiber, 0.0);
      FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
      const FbgShape& shape = reconstructor.reconstruct(frame);
      if (shape.status != FbgShapeStatus::ok) std::abort();  // parsed wavelengths are finite and positive
      for (const auto& p : shape.points) {
        if (!p.allFinite()) std::abort();
      }
    }
  } catch (const FbgFrameError& e) {
    if (std::string_view(e.what()).empty()) std::abort();
  }
  return 0;
}
