// Per-view segmentation parameters (IMG-02): validation with the field and range named, JSON round
// trip, partial updates as the console sends them, and refusal of anything that is not them.
#include "tendril/teleop/perception/fluoroscopy_segmentation_parameters.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "tendril/teleop/perception/fluoroscopy_segmenter.hpp"

namespace tendril::teleop::perception {
namespace {

// The field and the message of the error `change` provokes.
std::pair<std::string, std::string> error_of(
    const std::function<void(FluoroscopySegmentationParameters&)>& change) {
  FluoroscopySegmentationParameters p;
  change(p);
  try {
    p.validate();
  } catch (const SegmentationParameterError& e) {
    return {e.field(), e.what()};
  }
  return {"", ""};
}

TEST(FluoroscopySegmentationParameters, DefaultsAreValid) {
  EXPECT_NO_THROW(FluoroscopySegmentationParameters{}.validate());
  EXPECT_NO_THROW(BiplaneSegmentationParameters{}.validate());
}

TEST(FluoroscopySegmentationParameters, BadValuesNameTheFieldAndTheRange) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto [field, message] = error_of([&](auto& p) { p.background_weight = nan; });
  EXPECT_EQ(field, "background_weight");
  EXPECT_NE(message.find("from 0 to 1"), std::string::npos) << message;
  EXPECT_NE(message.find("nan"), std::string::npos) << message;

  std::tie(field, message) = error_of([](auto& p) { p.threshold = 0; });
  EXPECT_EQ(field, "threshold");
  EXPECT_NE(message.find("from 1 to 255, got 0"), std::string::npos) << message;

  std::tie(field, message) = error_of([](auto& p) {
    p.canny_low = 120;
    p.canny_high = 60;
  });
  EXPECT_EQ(field, "canny_low");
  EXPECT_NE(message.find("canny_high"), std::string::npos) << message;

  EXPECT_EQ(error_of([](auto& p) { p.canny_high = std::numeric_limits<double>::infinity(); }).first,
            "canny_high");
  EXPECT_EQ(error_of([](auto& p) { p.roi.width = -5; }).first, "roi.width");
  EXPECT_EQ(error_of([](auto& p) { p.downsample = 0; }).first, "downsample");
  EXPECT_EQ(error_of([](auto& p) { p.morphology_px = 16; }).first, "morphology_px");
  EXPECT_EQ(error_of([](auto& p) { p.min_blob_px = -1; }).first, "min_blob_px");
  EXPECT_EQ(error_of([](auto& p) { p.spline_knot_spacing_px = 1.0; }).first, "spline_knot_spacing_px");
  EXPECT_EQ(error_of([](auto& p) { p.spline_points = 1; }).first, "spline_points");
  EXPECT_EQ(error_of([](auto& p) { p.vessel_threshold = 256; }).first, "vessel_threshold");
  EXPECT_EQ(error_of([&](auto& p) { p.vessel_max_width_px = nan; }).first, "vessel_max_width_px");
  EXPECT_EQ(error_of([](auto& p) { p.entry = static_cast<ImageEdge>(9); }).first, "entry");

  // The segmenter refuses them at construction and keeps its old ones on set_parameters.
  FluoroscopySegmentationParameters bad;
  bad.spline_points = 0;
  EXPECT_THROW(FluoroscopySegmenter{bad}, SegmentationParameterError);
  FluoroscopySegmenter segmenter;
  EXPECT_THROW(segmenter.set_parameters(bad), SegmentationParameterError);
  EXPECT_EQ(segmenter.parameters().spline_points, FluoroscopySegmentationParameters{}.spline_points);
}

TEST(FluoroscopySegmentationParameters, JsonRoundTripAndPartialUpdate) {
  BiplaneSegmentationParameters p;
  p.ap.roi = {10, 20, 900, 800};
  p.ap.entry = ImageEdge::kLeft;
  p.ap.threshold = 50;
  p.lateral.background_subtraction = false;
  p.lateral.background_weight = 0.25;
  p.lateral.canny_low = 12.5;
  p.lateral.spline_points = 100;
  const auto json = to_json(p);
  EXPECT_EQ(json.at("ap").at("roi").at("width"), 900);
  EXPECT_EQ(json.at("ap").at("entry"), "left");
  EXPECT_EQ(biplane_segmentation_parameters_from_json(json), p);
  EXPECT_EQ(parse_biplane_segmentation_parameters(json.dump()), p);

  // The console sends only what changed; the rest stays.
  const auto updated =
      parse_biplane_segmentation_parameters(R"({"lateral": {"threshold": 60, "roi": {"x": 5}}})", p);
  EXPECT_EQ(updated.lateral.threshold, 60);
  EXPECT_EQ(updated.lateral.roi.x, 5);
  EXPECT_EQ(updated.lateral.canny_low, 12.5);
  EXPECT_EQ(updated.ap, p.ap);
}

TEST(FluoroscopySegmentationParameters, JsonRefusesWhatIsNotParameters) {
  const auto field_of = [](const std::string& text) {
    try {
      (void)parse_biplane_segmentation_parameters(text);
    } catch (const SegmentationParameterError& e) {
      EXPECT_FALSE(std::string(e.what()).empty());
      return e.field() + " | " + e.what();
    }
    return std::string("accepted");
  };
  EXPECT_EQ(
      field_of(R"({"lateral": {"threshold": 300}})")
          .rfind("lateral.threshold | lateral.threshold: expected an integer from 1 to 255, got 300", 0),
      0U);
  EXPECT_EQ(field_of(R"({"ap": {"treshold": 30}})")
                .rfind("ap.treshold | ap.treshold: unknown key; expected one of roi,", 0),
            0U);
  EXPECT_EQ(field_of(R"({"ap": {"threshold": "30"}})")
                .rfind("ap.threshold | ap.threshold: expected an integer, got \"30\"", 0),
            0U);
  EXPECT_EQ(field_of(R"({"ap": {"threshold": 30.5}})").rfind("ap.threshold |", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": {"entry": "middle"}})").rfind("ap.entry |", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": {"roi": {"x": 1, "depth": 2}}})").rfind("ap.roi.depth |", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": {"canny_low": 500, "canny_high": 100}})").rfind("ap.canny_low |", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": {"threshold": 30, "threshold": 40}})").rfind("threshold | ", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": [1, 2]})").rfind("ap | ap: expected an object", 0), 0U);
  EXPECT_EQ(field_of(R"({"frontal": {}})").rfind("frontal |", 0), 0U);
  EXPECT_EQ(field_of(R"({"ap": {"threshold": 99999999999999999999}})").rfind("ap.threshold |", 0), 0U);
  EXPECT_NE(field_of(R"({"ap": )").find("not valid JSON"), std::string::npos);
  EXPECT_NE(field_of(std::string(100, '[')).find("deeper than"), std::string::npos);
  EXPECT_EQ(field_of("{}"), "accepted");
}

}  // namespace
}  // namespace tendril::teleop::perception
