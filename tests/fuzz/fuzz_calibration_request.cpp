// Fuzz target: the shape calibration request (JSON body of POST /robots/{r}/calibrations) and the
// base64 decoder its pictures go through.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "steerable_catheter/calibration_request.hpp"

using namespace tendril::server;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  std::vector<std::uint8_t> bytes;
  if (decode_base64(input, bytes) && bytes.size() > input.size()) std::abort();  // never grows
  const auto json = nlohmann::json::parse(input, nullptr, false);
  if (json.is_discarded()) return 0;
  const auto read = read_calibration_request(json, "/nonexistent-robot-dir", "srmc.json");
  if (const auto* refused = std::get_if<ApiResult>(&read)) {
    if (refused->ok() || refused->code.empty() || refused->message.empty()) std::abort();
    return 0;
  }
  // Accepted: exactly one form of data, all of it finite.
  const auto& r = std::get<CalibrationRequest>(read);
  const int forms = (!r.samples.empty() ? 1 : 0) + (r.grid ? 1 : 0) + (!r.pictures.empty() ? 1 : 0);
  if (forms != 1) std::abort();
  for (const auto& s : r.samples)
    if (!std::isfinite(s.arc_length + s.actuation + s.tangent_angle)) std::abort();
  for (const auto& p : r.pictures)
    if (r.from_images ? p.image.empty() : p.outline.size() < 8) std::abort();
  if (r.from_images && !(r.image_options.mm_per_pixel > 0)) std::abort();
  return 0;
}
