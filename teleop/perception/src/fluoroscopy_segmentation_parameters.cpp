// Kept apart from the OpenCV code: the parameter reader (and its fuzz target) needs only this.
#include "tendril/teleop/perception/fluoroscopy_segmentation_parameters.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <utility>

#include "tendril/teleop/strict_json.hpp"

namespace tendril::teleop::perception {

namespace {

std::string number_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

std::string shown(const nlohmann::json& v) {
  std::string text = v.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  if (text.size() > 60) text = text.substr(0, 57) + "...";
  return text;
}

[[noreturn]] void fail(const std::string& prefix, const std::string& field, const std::string& message) {
  const std::string path = prefix + field;
  throw SegmentationParameterError(path, path + ": " + message);
}

void check_integer(const std::string& prefix, const char* field, int value, int lo, int hi) {
  if (value < lo || value > hi)
    fail(prefix, field,
         "expected an integer from " + std::to_string(lo) + " to " + std::to_string(hi) + ", got " +
             std::to_string(value));
}

void check_number(const std::string& prefix, const char* field, double value, double lo, double hi) {
  if (!std::isfinite(value) || value < lo || value > hi)
    fail(prefix, field,
         "expected a number from " + number_text(lo) + " to " + number_text(hi) + ", got " +
             number_text(value));
}

void validate_view(const FluoroscopySegmentationParameters& p, const std::string& prefix) {
  constexpr int kMaxImageSide = 16384;
  check_integer(prefix, "roi.x", p.roi.x, 0, kMaxImageSide - 1);
  check_integer(prefix, "roi.y", p.roi.y, 0, kMaxImageSide - 1);
  check_integer(prefix, "roi.width", p.roi.width, 0, kMaxImageSide);
  check_integer(prefix, "roi.height", p.roi.height, 0, kMaxImageSide);
  if (p.entry != ImageEdge::kBottom && p.entry != ImageEdge::kTop && p.entry != ImageEdge::kLeft &&
      p.entry != ImageEdge::kRight)
    fail(prefix, "entry", "expected \"bottom\", \"top\", \"left\" or \"right\"");
  check_integer(prefix, "downsample", p.downsample, 1, 8);
  check_number(prefix, "background_weight", p.background_weight, 0.0, 1.0);
  check_integer(prefix, "threshold", p.threshold, 1, 255);
  check_integer(prefix, "morphology_px", p.morphology_px, 0, 15);
  check_number(prefix, "canny_low", p.canny_low, 0.0, 2000.0);
  check_number(prefix, "canny_high", p.canny_high, 0.0, 2000.0);
  if (p.canny_low > p.canny_high)
    fail(prefix, "canny_low",
         "must not exceed canny_high (" + number_text(p.canny_high) + "), got " + number_text(p.canny_low));
  check_integer(prefix, "min_blob_px", p.min_blob_px, 0, 10'000'000);
  check_number(prefix, "spline_knot_spacing_px", p.spline_knot_spacing_px, 4.0, 4000.0);
  check_integer(prefix, "spline_points", p.spline_points, 2, 4096);
  check_integer(prefix, "vessel_threshold", p.vessel_threshold, 1, 255);
  check_number(prefix, "vessel_max_width_px", p.vessel_max_width_px, 4.0, 1024.0);
}

// Reads one key of an object into a field, with the type check and the field's path in the message.
struct ObjectReader {
  const nlohmann::json& object;
  std::string prefix;

  const nlohmann::json* find(const char* key) const {
    const auto it = object.find(key);
    return it == object.end() ? nullptr : &*it;
  }
  void integer(const char* key, int& out) const {
    const auto* v = find(key);
    if (!v) return;
    if (!v->is_number_integer()) fail(prefix, key, "expected an integer, got " + shown(*v));
    const auto wide =
        v->is_number_unsigned()
            ? static_cast<long long>(std::min<std::uint64_t>(v->get<std::uint64_t>(), std::uint64_t{1} << 40))
            : v->get<long long>();
    if (wide < -(1LL << 31) || wide > (1LL << 31) - 1)
      fail(prefix, key, "expected an integer in range, got " + shown(*v));
    out = static_cast<int>(wide);
  }
  void number(const char* key, double& out) const {
    const auto* v = find(key);
    if (!v) return;
    if (!v->is_number()) fail(prefix, key, "expected a number, got " + shown(*v));
    out = v->get<double>();
  }
  void boolean(const char* key, bool& out) const {
    const auto* v = find(key);
    if (!v) return;
    if (!v->is_boolean()) fail(prefix, key, "expected true or false, got " + shown(*v));
    out = v->get<bool>();
  }
};

void require_known_keys(const nlohmann::json& object, const std::string& prefix,
                        std::initializer_list<const char*> known) {
  for (const auto& item : object.items()) {
    bool ok = false;
    for (const char* k : known) ok = ok || item.key() == k;
    if (ok) continue;
    std::string list;
    for (const char* k : known) list += std::string(list.empty() ? "" : ", ") + k;
    fail(prefix, item.key(), "unknown key; expected one of " + list);
  }
}

FluoroscopySegmentationParameters view_from_json(const nlohmann::json& json,
                                                 const FluoroscopySegmentationParameters& base,
                                                 const std::string& prefix) {
  if (!json.is_object())
    throw SegmentationParameterError(
        prefix.empty() ? "" : prefix.substr(0, prefix.size() - 1),
        (prefix.empty() ? std::string("segmentation parameters") : prefix.substr(0, prefix.size() - 1)) +
            ": expected an object, got " + shown(json));
  require_known_keys(json, prefix,
                     {"roi", "entry", "downsample", "background_subtraction", "background_weight",
                      "threshold", "morphology_px", "canny_low", "canny_high", "min_blob_px",
                      "spline_knot_spacing_px", "spline_points", "vessel_threshold", "vessel_max_width_px"});
  FluoroscopySegmentationParameters p = base;
  const ObjectReader r{json, prefix};
  if (const auto* roi = r.find("roi")) {
    if (!roi->is_object())
      fail(prefix, "roi", "expected {\"x\", \"y\", \"width\", \"height\"}, got " + shown(*roi));
    require_known_keys(*roi, prefix + "roi.", {"x", "y", "width", "height"});
    const ObjectReader rr{*roi, prefix + "roi."};
    rr.integer("x", p.roi.x);
    rr.integer("y", p.roi.y);
    rr.integer("width", p.roi.width);
    rr.integer("height", p.roi.height);
  }
  if (const auto* entry = r.find("entry")) {
    if (!entry->is_string())
      fail(prefix, "entry", "expected \"bottom\", \"top\", \"left\" or \"right\", got " + shown(*entry));
    try {
      p.entry = parse_image_edge(entry->get<std::string>());
    } catch (const SideViewImageError&) {
      fail(prefix, "entry", "expected \"bottom\", \"top\", \"left\" or \"right\", got " + shown(*entry));
    }
  }
  r.integer("downsample", p.downsample);
  r.boolean("background_subtraction", p.background_subtraction);
  r.number("background_weight", p.background_weight);
  r.integer("threshold", p.threshold);
  r.integer("morphology_px", p.morphology_px);
  r.number("canny_low", p.canny_low);
  r.number("canny_high", p.canny_high);
  r.integer("min_blob_px", p.min_blob_px);
  r.number("spline_knot_spacing_px", p.spline_knot_spacing_px);
  r.integer("spline_points", p.spline_points);
  r.integer("vessel_threshold", p.vessel_threshold);
  r.number("vessel_max_width_px", p.vessel_max_width_px);
  validate_view(p, prefix);
  return p;
}

}  // namespace

SegmentationParameterError::SegmentationParameterError(std::string field, const std::string& message)
    : std::invalid_argument(message), field_(std::move(field)) {}

const char* image_edge_name(ImageEdge edge) noexcept {
  switch (edge) {
    case ImageEdge::kBottom:
      return "bottom";
    case ImageEdge::kTop:
      return "top";
    case ImageEdge::kLeft:
      return "left";
    case ImageEdge::kRight:
      return "right";
  }
  return "bottom";
}

void FluoroscopySegmentationParameters::validate() const { validate_view(*this, ""); }

void BiplaneSegmentationParameters::validate() const {
  validate_view(ap, "ap.");
  validate_view(lateral, "lateral.");
}

nlohmann::json to_json(const FluoroscopySegmentationParameters& p) {
  return {{"roi", {{"x", p.roi.x}, {"y", p.roi.y}, {"width", p.roi.width}, {"height", p.roi.height}}},
          {"entry", image_edge_name(p.entry)},
          {"downsample", p.downsample},
          {"background_subtraction", p.background_subtraction},
          {"background_weight", p.background_weight},
          {"threshold", p.threshold},
          {"morphology_px", p.morphology_px},
          {"canny_low", p.canny_low},
          {"canny_high", p.canny_high},
          {"min_blob_px", p.min_blob_px},
          {"spline_knot_spacing_px", p.spline_knot_spacing_px},
          {"spline_points", p.spline_points},
          {"vessel_threshold", p.vessel_threshold},
          {"vessel_max_width_px", p.vessel_max_width_px}};
}

nlohmann::json to_json(const BiplaneSegmentationParameters& p) {
  return {{"ap", to_json(p.ap)}, {"lateral", to_json(p.lateral)}};
}

FluoroscopySegmentationParameters segmentation_parameters_from_json(
    const nlohmann::json& json, const FluoroscopySegmentationParameters& base) {
  return view_from_json(json, base, "");
}

BiplaneSegmentationParameters biplane_segmentation_parameters_from_json(
    const nlohmann::json& json, const BiplaneSegmentationParameters& base) {
  if (!json.is_object())
    throw SegmentationParameterError(
        "", "segmentation parameters: expected {\"ap\": {…}, \"lateral\": {…}}, got " + shown(json));
  require_known_keys(json, "", {"ap", "lateral"});
  BiplaneSegmentationParameters out = base;
  if (const auto it = json.find("ap"); it != json.end()) out.ap = view_from_json(*it, base.ap, "ap.");
  if (const auto it = json.find("lateral"); it != json.end())
    out.lateral = view_from_json(*it, base.lateral, "lateral.");
  return out;
}

BiplaneSegmentationParameters parse_biplane_segmentation_parameters(
    std::string_view json_text, const BiplaneSegmentationParameters& base) {
  // The parameters are two small objects; anything far larger or deeper is not them (refused before
  // parsing and as soon as the parser gets that deep, so hostile text cannot make it allocate much).
  constexpr std::size_t kMaxBytes = std::size_t{64} * 1024;
  constexpr int kMaxDepth = 8;
  if (json_text.size() > kMaxBytes)
    throw SegmentationParameterError("", "segmentation parameters: " + std::to_string(json_text.size()) +
                                             " bytes of JSON; at most " + std::to_string(kMaxBytes) +
                                             " are accepted");
  // A key given twice is refused (as the REST bodies are): which of the two was meant is unknowable.
  auto parsed = parse_strict_json(json_text, kMaxDepth);
  switch (parsed.error) {
    case StrictJsonError::kNone:
      break;
    case StrictJsonError::kTooDeep:
      throw SegmentationParameterError(
          "", "segmentation parameters: JSON nests deeper than " + std::to_string(kMaxDepth) + " levels");
    case StrictJsonError::kSyntax:
    case StrictJsonError::kNumberOutOfRange:
      throw SegmentationParameterError(
          "", "segmentation parameters: not valid JSON (" + parsed.parser_message + ")");
    case StrictJsonError::kDuplicateKey:
      throw SegmentationParameterError(parsed.duplicate_key,
                                       "segmentation parameters: the key \"" + parsed.duplicate_key +
                                           "\" appears twice in one object; give each key once");
  }
  return biplane_segmentation_parameters_from_json(parsed.value, base);
}

}  // namespace tendril::teleop::perception
