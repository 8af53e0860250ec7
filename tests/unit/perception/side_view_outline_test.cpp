// Side-view photographs to backbone points, and the whole image calibration of Abah 2022, §4.5.2:
// images of a segment with a known shape matrix, stepped by dq = 0.1 mm up to ≈ 80° of bend,
// thresholded, thinned, smoothed, θ(s) by forward differences, then the Kronecker least squares.
#include "tendril/teleop/perception/side_view_outline.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "tendril/drivers/sim/simulated_side_view_camera.hpp"
#include "tendril/teleop/shape_calibration.hpp"

namespace tendril::teleop::perception {
namespace {

using teleop::CatheterSegment;
constexpr double kDeg = std::numbers::pi / 180.0;

// A proximal-like segment (L = 10.5 mm), cubic in s and linear in q: ≈ 80° at q ≈ 0.95 mm.
teleop::ModalCatheterParameters true_shape() {
  Eigen::MatrixXd A(4, 2);
  A << std::numbers::pi / 2, 0.0,  //
      0.0, -0.10,                  //
      0.0, -0.006,                 //
      0.0, 0.0002;
  teleop::ModalCatheterParameters p;
  p.proximal = {A, 10.5};
  p.distal = {A, 10.5};
  p.simpson_intervals = 64;
  return p;
}

sim::SideViewCameraOptions camera_options() {
  sim::SideViewCameraOptions o;
  o.width = 560;
  o.height = 620;
  o.mm_per_pixel = 0.025;
  o.base_column = 60.0;
  return o;
}

// Largest distance from an extracted point to the true backbone polyline (mm).
double worst_distance(const std::vector<Eigen::Vector2d>& points, const std::vector<Eigen::Vector2d>& truth) {
  double worst = 0.0;
  for (const auto& p : points) {
    double best = 1e9;
    for (const auto& t : truth) best = std::min(best, (p - t).norm());
    worst = std::max(worst, best);
  }
  return worst;
}

TEST(SideViewOutline, TheSkeletonFollowsTheTrueBackbone) {
  sim::SimulatedSideViewCamera camera(true_shape(), camera_options());
  const auto png = camera.capture_png(CatheterSegment::kProximal, 0.6);
  SideViewImageOptions o;
  o.mm_per_pixel = 0.025;
  const auto outline = extract_side_view_outline(png, o);
  ASSERT_GT(outline.points.size(), 300U);
  // The truth in the same frame: x from the straight tube's axis, z from the bottom edge.
  auto truth = camera.true_backbone(CatheterSegment::kProximal, 0.6);
  for (auto& t : truth) t.y() += camera.options().straight_mm;
  EXPECT_LT(worst_distance(outline.points, truth), 1.5 * 0.025);  // within 1.5 pixels everywhere
  // The entry end sits at the bottom edge; the tip end within a tube radius of the true tip.
  EXPECT_LT(outline.points.front().y(), 2 * 0.025);
  EXPECT_LT((outline.points.back() - truth.back()).norm(), 0.6);
  // Area over skeleton length gives the tube's width back (0.6 mm, drawn anti-aliased and blurred,
  // so about a pixel wider at the threshold): scale and threshold are sane.
  EXPECT_NEAR(outline.tube_width_mm, 0.6, 0.1);
  EXPECT_EQ(outline.width, 560);
}

TEST(SideViewOutline, AJpegOfThePictureGivesTheSameBackbone) {
  sim::SimulatedSideViewCamera camera(true_shape(), camera_options());
  const auto png = camera.capture_png(CatheterSegment::kProximal, 0.8);
  std::vector<std::uint8_t> jpeg;
  cv::imencode(".jpg", cv::imdecode(png, cv::IMREAD_GRAYSCALE), jpeg, {cv::IMWRITE_JPEG_QUALITY, 90});
  SideViewImageOptions o;
  o.mm_per_pixel = 0.025;
  const auto from_png = extract_side_view_outline(png, o);
  const auto from_jpeg = extract_side_view_outline(jpeg, o);
  EXPECT_EQ(from_jpeg.width, 560);
  EXPECT_EQ(from_jpeg.height, 620);
  EXPECT_LT(worst_distance(from_jpeg.points, from_png.points), 0.025);
}

TEST(SideViewOutline, EntryEdgeAndMirrorNormaliseTheView) {
  sim::SimulatedSideViewCamera camera(true_shape(), camera_options());
  const auto png = camera.capture_png(CatheterSegment::kProximal, 0.5);
  SideViewImageOptions o;
  o.mm_per_pixel = 0.025;
  const auto reference = extract_side_view_outline(png, o);
  // The same picture turned so the catheter enters from the left, and mirrored.
  const std::vector<std::uint8_t> data(png.begin(), png.end());
  auto transformed = [&](int rotate, bool flip) {
    cv::Mat image = cv::imdecode(data, cv::IMREAD_GRAYSCALE);
    if (rotate >= 0) cv::rotate(image, image, rotate);
    if (flip) cv::flip(image, image, 1);
    std::vector<std::uint8_t> out;
    cv::imencode(".png", image, out);
    return out;
  };
  SideViewImageOptions left = o;
  left.entry = ImageEdge::kLeft;
  const auto from_left = extract_side_view_outline(transformed(cv::ROTATE_90_CLOCKWISE, false), left);
  SideViewImageOptions mirrored = o;
  mirrored.mirror = true;
  const auto from_mirror = extract_side_view_outline(transformed(-1, true), mirrored);
  for (const auto* other : {&from_left, &from_mirror}) {
    ASSERT_NEAR(static_cast<double>(other->points.size()), static_cast<double>(reference.points.size()), 5.0);
    EXPECT_LT(worst_distance(other->points, reference.points), 2 * 0.025);
    EXPECT_GT(other->points.back().x(), 1.0);  // the bend still goes toward +x
  }
}

TEST(SideViewOutline, RefusesWhatIsNotACatheterPicture) {
  SideViewImageOptions o;
  o.mm_per_pixel = 0.025;
  const std::vector<std::uint8_t> garbage{'n', 'o', 't', ' ', 'a', 'n', ' ', 'i', 'm', 'a', 'g', 'e'};
  EXPECT_THROW(extract_side_view_outline(garbage, o), SideViewImageError);
  EXPECT_THROW(extract_side_view_outline({}, o), SideViewImageError);
  // A blank frame: nothing dark reaches the entry edge.
  cv::Mat blank(100, 100, CV_8U, cv::Scalar(200));
  blank.at<std::uint8_t>(10, 10) = 20;
  std::vector<std::uint8_t> png;
  cv::imencode(".png", blank, png);
  try {
    extract_side_view_outline(png, o);
    FAIL() << "a blank frame was accepted";
  } catch (const SideViewImageError& e) {
    EXPECT_NE(std::string(e.what()).find("entry edge"), std::string::npos) << e.what();
  }
  // Only PNG and JPEG; the size is taken from the header, so a file claiming a huge picture is
  // refused before it is decoded, and a cut-short one says it is damaged.
  std::vector<std::uint8_t> bmp;
  cv::imencode(".bmp", blank, bmp);
  EXPECT_THROW(extract_side_view_outline(bmp, o), SideViewImageError);
  auto huge = png;
  for (std::size_t i : {16U, 20U}) {  // IHDR width and height: 0x00100000 = 1 048 576 each
    huge[i] = 0x00, huge[i + 1] = 0x10, huge[i + 2] = 0x00, huge[i + 3] = 0x00;
  }
  try {
    extract_side_view_outline(huge, o);
    FAIL() << "a PNG claiming 2^40 pixels was accepted";
  } catch (const SideViewImageError& e) {
    EXPECT_NE(std::string(e.what()).find("1048576×1048576"), std::string::npos) << e.what();
  }
  const std::vector<std::uint8_t> cut(png.begin(), png.begin() + 40);
  EXPECT_THROW(extract_side_view_outline(cut, o), SideViewImageError);
  SideViewImageOptions no_scale;
  EXPECT_THROW(extract_side_view_outline(png, no_scale), SideViewImageError);
  EXPECT_THROW(parse_image_edge("diagonal"), SideViewImageError);
}

// The dissertation's experiment in simulation: dq = 0.1 mm steps until ≈ 80°, one picture each, fitted with
// n = 4, m = 2. The dissertation reports a mean fit error of 0.021° (proximal) and 0.057° (distal); the
// fit must be of that order on the simulated camera and give back the true tip angles.
TEST(ImageCalibration, PicturesOfAKnownSegmentFitBackToItsShapeMatrix) {
  const auto shape = true_shape();
  const teleop::ModalCatheterKinematics truth(shape);
  sim::SimulatedSideViewCamera camera(shape, camera_options());
  std::vector<teleop::ShapeSample> samples;
  std::vector<double> actuations;
  for (int k = 1;; ++k) {
    const double q = 0.1 * k;
    actuations.push_back(q);
    SideViewImageOptions o;
    o.mm_per_pixel = 0.025;
    const auto outline = extract_side_view_outline(camera.capture_png(CatheterSegment::kProximal, q), o);
    teleop::TangentExtractionOptions t;
    t.base_arc_length = camera.options().straight_mm;  // the rig fixes where the segment starts
    t.sample_spacing = o.mm_per_pixel;                 // as the calibration job does
    teleop::append_shape_samples(teleop::extract_tangent_angles(outline.points, t), q, samples);
    if (std::numbers::pi / 2 - truth.tip_angle(CatheterSegment::kProximal, q) >= 80.0 * kDeg) break;
  }
  const auto fit = teleop::fit_shape_matrix(samples);
  double tip_error = 0.0;
  const teleop::ModalCatheterParameters fitted{
      {fit.shape_matrix, 10.5}, {fit.shape_matrix, 10.5}, 0.0, 0.0, 64};
  const teleop::ModalCatheterKinematics model(fitted);
  for (double q : actuations)
    tip_error = std::max(tip_error, std::abs(model.tip_angle(CatheterSegment::kProximal, q) -
                                             truth.tip_angle(CatheterSegment::kProximal, q)));
  std::printf(
      "[ measured ] image calibration: %zu images, %zu samples, mean fit %.3f deg, max %.3f deg, worst "
      "tip error %.3f deg\n",
      actuations.size(), fit.sample_count, fit.mean_abs_error_deg, fit.max_abs_error_deg, tip_error / kDeg);
  EXPECT_GE(actuations.size(), 9U);
  EXPECT_LT(fit.mean_abs_error_deg, 0.08);  // seed: 0.021° and 0.057°
  EXPECT_LT(tip_error, 0.3 * kDeg);
}

}  // namespace
}  // namespace tendril::teleop::perception
