// Fuzz target: STL uploads (POST /vessels, model/stl), ASCII and binary, through parsing and
// centerline extraction. Bad input must end in VesselInputError, never a crash or a non-finite point.
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "tendril/teleop/vessel_mesh.hpp"

using namespace tendril::teleop;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  StlCenterlineOptions options;
  options.limits.max_triangles = 5'000;  // keeps each run fast; the cap's own path is exercised too
  try {
    const auto branches = read_stl_centerline(input, options);
    if (branches.size() != 1) std::abort();
    const auto& line = branches.front();
    if (line.points.size() < 2 || line.radii.size() != line.points.size()) std::abort();
    for (std::size_t i = 0; i < line.points.size(); ++i) {
      if (!line.points[i].allFinite() || !(line.radii[i] >= 0.0)) std::abort();
    }
  } catch (const VesselInputError& e) {
    if (std::string_view(e.what()).empty()) std::abort();
  }
  return 0;
}
