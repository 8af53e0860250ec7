// Fuzz target: fluoroscopy segmentation parameters as the console sends them and sessions store them
// ({"ap": {…}, "lateral": {…}}). Bad input must end in SegmentationParameterError with a message;
// whatever is accepted must validate and survive a JSON round trip unchanged.
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "tendril/teleop/perception/fluoroscopy_segmentation_parameters.hpp"

using namespace tendril::teleop::perception;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  try {
    const auto parameters = parse_biplane_segmentation_parameters(input);
    parameters.validate();  // throws only if the parser let a bad value through: caught below as a failure
    if (biplane_segmentation_parameters_from_json(to_json(parameters)) != parameters) std::abort();
  } catch (const SegmentationParameterError& e) {
    if (std::string_view(e.what()).empty()) std::abort();
  }
  return 0;
}
