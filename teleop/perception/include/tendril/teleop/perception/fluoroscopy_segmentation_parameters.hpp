// Per-view parameters of the fluoroscopy segmentation (Abah 2022, §4.8.1–4.8.2): the surgeon
// sets the crop (region of interest), threshold and Canny thresholds for each view (AP, lateral); they
// are kept and reused for every frame. Here they are a plain value with a validator and JSON
// (de)serialisation, so that the console can edit them live and the session can save them.
//
// JSON (one view; every key optional when reading, missing keys keep the base value, unknown keys are
// refused):
//   {"roi": {"x": 0, "y": 0, "width": 0, "height": 0}, "entry": "bottom", "downsample": 2,
//    "background_subtraction": true, "background_weight": 1.0, "threshold": 35, "morphology_px": 2,
//    "canny_low": 40, "canny_high": 100, "min_blob_px": 150, "spline_knot_spacing_px": 48,
//    "spline_points": 64, "vessel_threshold": 25, "vessel_max_width_px": 96}
// Both views: {"ap": {…}, "lateral": {…}}.
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <string_view>

#include "tendril/teleop/perception/side_view_outline.hpp"  // ImageEdge

namespace tendril::teleop::perception {

// A bad parameter: `field()` is its JSON path ("threshold", "roi.width", "lateral.canny_low"), the
// message names the field, the allowed range and the value given.
class SegmentationParameterError : public std::invalid_argument {
 public:
  SegmentationParameterError(std::string field, const std::string& message);
  const std::string& field() const noexcept { return field_; }

 private:
  std::string field_;
};

// Full-resolution pixels of the frame. width/height 0 = up to the right/bottom edge of the frame.
struct RegionOfInterest {
  int x = 0;
  int y = 0;
  int width = 0;
  int height = 0;
  bool operator==(const RegionOfInterest&) const = default;
};

struct FluoroscopySegmentationParameters {
  RegionOfInterest roi;                  // crop: excludes the fluoroscope's on-screen widgets
  ImageEdge entry = ImageEdge::kBottom;  // the ROI edge the catheter enters the picture from
  // Detection runs on the ROI averaged over downsample × downsample blocks (1..8); the backbone is
  // then refined on full-resolution pixels, so this trades speed, not accuracy, while the catheter
  // stays ≥ 2 detection pixels wide.
  int downsample = 2;
  // Difference image = 100 · ln(reference / frame), saturated to 0..255: the catheter's own X-ray
  // attenuation (μ·chord × 100; a 1 mm braided catheter ≈ 100 at its axis). The reference is
  // roadmap^w · 255^(1−w) with w = background_weight when background subtraction is on (w = 1: pure
  // subtraction of the empty-vessel roadmap, as in digital subtraction angiography; w = 0 or
  // subtraction off: everything darker than white, vessel included).
  bool background_subtraction = true;
  double background_weight = 1.0;  // 0..1
  int threshold = 35;              // 1..255 on the difference image
  // Opening kernel (detection px) that drops noise specks, 0..15; 0 or 1 = none. Larger than the
  // catheter's width on the detection image it erases the catheter: 2 keeps anything 2 px wide.
  int morphology_px = 2;
  // Canny hysteresis thresholds (gradient magnitude of the difference image, L2, 0..2000, low ≤ high):
  // the catheter's outline; the share of the backbone with outline on both sides is its quality.
  double canny_low = 40.0;
  double canny_high = 100.0;
  int min_blob_px = 150;                 // smallest catheter region kept, full-resolution pixels, 0..10⁷
  double spline_knot_spacing_px = 48.0;  // smoothing: cubic B-spline knot spacing, 4..4000 px
  int spline_points = 64;                // points of the output polylines, 2..4096
  int vessel_threshold = 25;             // 1..255 on the roadmap's vessel image (100 · ln of contrast)
  double vessel_max_width_px = 96.0;     // widest vessel lumen on the image, 4..1024 px (full resolution)

  // Throws SegmentationParameterError naming the first bad field.
  void validate() const;

  bool operator==(const FluoroscopySegmentationParameters&) const = default;
};

struct BiplaneSegmentationParameters {
  FluoroscopySegmentationParameters ap;
  FluoroscopySegmentationParameters lateral;
  void validate() const;  // fields named "ap.…" / "lateral.…"
  bool operator==(const BiplaneSegmentationParameters&) const = default;
};

nlohmann::json to_json(const FluoroscopySegmentationParameters& parameters);
nlohmann::json to_json(const BiplaneSegmentationParameters& parameters);

// `base` with the keys of `json` applied, validated. Throws SegmentationParameterError (field and
// message for a person) on a non-object, an unknown key, a wrong type or a value out of range.
FluoroscopySegmentationParameters segmentation_parameters_from_json(
    const nlohmann::json& json, const FluoroscopySegmentationParameters& base = {});
BiplaneSegmentationParameters biplane_segmentation_parameters_from_json(
    const nlohmann::json& json, const BiplaneSegmentationParameters& base = {});

// JSON text (from the console or a session file) → parameters; malformed JSON is a
// SegmentationParameterError too (field "").
BiplaneSegmentationParameters parse_biplane_segmentation_parameters(
    std::string_view json_text, const BiplaneSegmentationParameters& base = {});

// "bottom", "top", "left", "right".
const char* image_edge_name(ImageEdge edge) noexcept;

}  // namespace tendril::teleop::perception
