// Fuzz target: centerline CSV uploads (POST /vessels, text/csv) through parsing, branch splitting and
// resampling. Bad input must end in VesselInputError, never a crash or a non-finite sample.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "tendril/teleop/vessel_centerline.hpp"

using namespace tendril::teleop;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  try {
    const auto branches = parse_centerline_csv(input);
    if (branches.empty()) std::abort();
    for (const auto& branch : branches) {
      if (branch.points.empty()) std::abort();
      if (!branch.radii.empty() && branch.radii.size() != branch.points.size()) std::abort();
      try {
        const auto vessel = VesselCenterline::from_polyline(branch, 0.5);
        if (vessel.size() < 3) std::abort();
        for (std::size_t i = 0; i < vessel.size(); ++i) {
          if (!vessel.points()[i].allFinite() || !vessel.tangents()[i].allFinite()) std::abort();
          if (std::abs(vessel.tangents()[i].norm() - 1.0) > 1e-6) std::abort();
        }
      } catch (const VesselInputError& e) {
        if (std::string_view(e.what()).empty()) std::abort();
      }
    }
  } catch (const VesselInputError& e) {
    if (std::string_view(e.what()).empty()) std::abort();
  }
  return 0;
}
