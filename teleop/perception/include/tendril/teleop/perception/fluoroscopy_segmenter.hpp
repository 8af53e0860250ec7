// Catheter and vessel segmentation of one fluoroscopy view (Abah 2022, §4.8.1). One
// FluoroscopySegmenter per view (AP, lateral), fed 8-bit grey frames in the imaging thread.
//
// Catheter, per frame: region of interest → background subtraction against the empty-vessel roadmap
// in the log domain (X-ray attenuation multiplies, so ln(roadmap/frame) is the catheter's own line
// integral, whether it lies over tissue or over contrast) on the ROI averaged down by `downsample` →
// threshold → morphological opening → largest connected region (≥ min_blob_px) → Zhang–Suen thinning
// → longest skeleton path (its diameter: spurs dropped), from its end nearer the entry edge → each point
// moved to the attenuation-weighted centre across the catheter on full-resolution pixels → the tip
// found past the skeleton's end (half-maximum of the attenuation, less the end's half-width) → smoothing
// cubic B-spline (least squares, knots every spline_knot_spacing_px) → tip = spline end, direction =
// its unit tangent. Canny on the difference image gives the outline; the share of the backbone with
// outline on both sides, times the contrast margin over the threshold, is the quality.
//
// Vessel, per roadmap: ln(roadmap) → black-hat (closing minus image, rectangle wider than the widest
// lumen: removes the smooth background, leaves the contrast) → vessel_threshold → largest region →
// thinning → longest path, from its end nearer the entry edge → spline.
//
// Pixels: (column, row), row 0 at the top, full-resolution frame coordinates (not ROI coordinates).
// Not thread-safe: one instance per thread. OpenCV stays private; per-frame buffers live in the object
// and are reused (the imaging thread, not the control loop, runs it).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tendril/teleop/perception/fluoroscopy_segmentation_parameters.hpp"

namespace tendril::teleop::perception {

// A borrowed 8-bit grey image, row-major; `stride` is bytes from one row to the next (≥ width).
// SimulatedFluoroscope::render gives width × height contiguous bytes: grey_image(span, w, h).
struct GreyImageView {
  const std::uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride = 0;
};

// A view of contiguous width × height bytes (data.size() must be ≥ width·height; checked on use).
GreyImageView grey_image(std::span<const std::uint8_t> data, int width, int height) noexcept;

enum class SegmentationFailure {
  kNone,
  kNoRoadmap,          // segment() before set_roadmap()
  kInvalidFrame,       // null data, sizes ≤ 0 or stride < width
  kFrameSizeMismatch,  // frame and roadmap differ in size
  kRoiOutsideFrame,    // the region of interest does not overlap the frame (or is < 8 px)
  kBlankFrame,         // the ROI is one uniform grey level: no picture from the source
  kNoCatheterInRoi,    // nothing differs from the roadmap by > threshold over ≥ min_blob_px
  kCatheterTooShort,   // a region was found but its skeleton is < 3 points long
};

// "none", "no_roadmap", "invalid_frame", "frame_size_mismatch", "roi_outside_frame", "blank_frame",
// "no_catheter_in_roi", "catheter_too_short".
const char* failure_name(SegmentationFailure failure) noexcept;

struct CatheterSegmentation {
  bool found = false;
  SegmentationFailure failure = SegmentationFailure::kNone;
  std::string message;  // for a person: what was looked for and not found; empty when found
  // Backbone from the insertion side to the tip: spline_points points, (column, row) pixels.
  std::vector<Eigen::Vector2d> polyline;
  Eigen::Vector2d tip = Eigen::Vector2d::Zero();
  Eigen::Vector2d tip_direction = Eigen::Vector2d::Zero();  // unit vector, pointing out of the tip
  double quality = 0.0;           // 0..1: outline support × contrast margin (see the header comment)
  double length_px = 0.0;         // arc length of the polyline
  double width_px = 0.0;          // region area / skeleton length (the imaged catheter's width)
  double mean_attenuation = 0.0;  // mean difference-image value on the backbone (100 · μ·chord)
  std::size_t region_pixels = 0;  // full-resolution pixels of the region kept
  std::size_t other_regions = 0;  // further regions ≥ min_blob_px that were not kept
};

struct VesselCenterlineResult {
  bool found = false;
  std::string message;
  std::vector<Eigen::Vector2d> polyline;  // from the entry side, spline_points points, pixels
  double length_px = 0.0;
  std::size_t region_pixels = 0;
};

class FluoroscopySegmenter {
 public:
  // Throws SegmentationParameterError on bad parameters.
  explicit FluoroscopySegmenter(const FluoroscopySegmentationParameters& parameters = {});
  ~FluoroscopySegmenter();
  FluoroscopySegmenter(FluoroscopySegmenter&&) noexcept;
  FluoroscopySegmenter& operator=(FluoroscopySegmenter&&) noexcept;

  // Validated (throws SegmentationParameterError, leaving the old ones in place); takes effect on the
  // next frame (the roadmap's derived images are recomputed then).
  void set_parameters(const FluoroscopySegmentationParameters& parameters);
  const FluoroscopySegmentationParameters& parameters() const noexcept;

  // Copies the empty-vessel image (contrast in, no catheter). Throws SegmentationParameterError
  // (field "roadmap") on an invalid view or when the ROI does not overlap it.
  void set_roadmap(GreyImageView roadmap);
  bool has_roadmap() const noexcept;

  // The catheter in `frame` (same size as the roadmap). Never throws for bad input: the result says
  // why nothing was found. The reference stays valid until the next call on this object.
  const CatheterSegmentation& segment(GreyImageView frame);

  // The vessel centerline of the roadmap (recomputed only when the roadmap or parameters change).
  const VesselCenterlineResult& vessel_centerline();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::teleop::perception
