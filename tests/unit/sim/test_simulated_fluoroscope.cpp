// SimulatedFluoroscope: projection geometry, what the image shows, noise statistics, JPEG output.
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "tendril/drivers/sim/simulated_fluoroscope.hpp"

namespace tendril::sim {
namespace {

FluoroscopeOptions plain_options(int size = 256) {
  FluoroscopeOptions o;
  o.geometry.width = o.geometry.height = size;
  o.geometry.pixel_spacing_mm = 0.25;
  o.geometry.sid_mm = 1000;
  o.geometry.sod_mm = 750;
  o.geometry.isocentre = {0, 0, 60};
  o.anatomy = false;  // uniform background so that image statistics are predictable
  return o;
}

// A straight catheter along +z through the isocentre: base 15 mm below, tip 15 mm above.
std::vector<Eigen::Vector3d> straight_catheter() {
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i <= 30; ++i) points.emplace_back(0.0, 0.0, 45.0 + i);
  return points;
}

double mean_in(std::span<const std::uint8_t> image, int width, int c0, int r0, int c1, int r1) {
  double sum = 0;
  int n = 0;
  for (int r = r0; r <= r1; ++r)
    for (int c = c0; c <= c1; ++c, ++n) sum += image[static_cast<std::size_t>(r) * width + c];
  return sum / n;
}

TEST(SimulatedFluoroscope, IsocentreProjectsToTheDetectorCentre) {
  for (auto view : {FluoroView::kAp, FluoroView::kLateral}) {
    SimulatedFluoroscope fluoro(view, plain_options());
    const auto p = fluoro.project({0, 0, 60});
    ASSERT_TRUE(p.in_front);
    EXPECT_NEAR(p.column, 127.5, 1e-9);
    EXPECT_NEAR(p.row, 127.5, 1e-9);
    EXPECT_NEAR(p.magnification, 1000.0 / 750.0, 1e-12);
  }
}

TEST(SimulatedFluoroscope, ARayThroughADetectorPointProjectsBackOntoItAndTwoPlanesMeetAtThePoint) {
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options());
  SimulatedFluoroscope lateral(FluoroView::kLateral, plain_options());
  for (const Eigen::Vector3d p :
       {Eigen::Vector3d(0, 0, 60), Eigen::Vector3d(7.5, -4.0, 71.0), Eigen::Vector3d(-12.0, 9.0, 48.5)}) {
    for (const auto* fluoro : {&ap, &lateral}) {
      const auto d = fluoro->project(p);
      const auto ray = fluoro->ray(d.column, d.row);
      EXPECT_NEAR(ray.direction.norm(), 1.0, 1e-12);
      // The point lies on the ray, and every point of the ray projects to the same pixel.
      const Eigen::Vector3d rel = p - ray.origin;
      EXPECT_NEAR((rel - rel.dot(ray.direction) * ray.direction).norm(), 0.0, 1e-9);
      const auto far = fluoro->project(ray.origin + 900.0 * ray.direction);
      EXPECT_NEAR(far.column, d.column, 1e-9);
      EXPECT_NEAR(far.row, d.row, 1e-9);
    }
  }
}

TEST(SimulatedFluoroscope, PerspectiveProjectionMagnifiesWithDepth) {
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options());
  // 10 mm along +x at the isocentre plane: 10 · SID/SOD on the detector = 13.333 mm = 53.33 px right.
  auto p = ap.project({10, 0, 60});
  EXPECT_NEAR(p.column, 127.5 + 10.0 * (1000.0 / 750.0) / 0.25, 1e-9);
  EXPECT_NEAR(p.row, 127.5, 1e-9);
  // +z is up in the image: rows decrease.
  p = ap.project({0, 0, 70});
  EXPECT_NEAR(p.row, 127.5 - 10.0 * (1000.0 / 750.0) / 0.25, 1e-9);
  // 50 mm nearer the detector (+y for AP): depth 800 mm, magnification 1.25.
  p = ap.project({10, 50, 60});
  EXPECT_NEAR(p.magnification, 1.25, 1e-12);
  EXPECT_NEAR(p.column, 127.5 + 10.0 * 1.25 / 0.25, 1e-9);
  // Behind the source: not imaged.
  EXPECT_FALSE(ap.project({0, -800, 60}).in_front);

  // Lateral: beam along +x, image columns along −y, so +y goes left and x only changes magnification.
  SimulatedFluoroscope lateral(FluoroView::kLateral, plain_options());
  p = lateral.project({0, 10, 60});
  EXPECT_NEAR(p.column, 127.5 - 10.0 * (1000.0 / 750.0) / 0.25, 1e-9);
  p = lateral.project({50, 0, 60});
  EXPECT_NEAR(p.column, 127.5, 1e-9);
  EXPECT_NEAR(p.magnification, 1.25, 1e-12);
}

TEST(SimulatedFluoroscope, CatheterIsDarkWhereItProjectsAndTipMarkerIsDarkest) {
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options());
  const auto catheter = straight_catheter();
  const auto image = ap.render_noiseless(catheter);
  ASSERT_EQ(image.size(), 256u * 256u);
  const int w = ap.width();
  const double background = mean_in(image, w, 10, 10, 30, 30);
  // exp(−0.8) of 240 is 108: the uniform tissue background.
  EXPECT_NEAR(background, 240.0 * std::exp(-0.8), 1.5);
  const auto mid = ap.project({0, 0, 55});  // on the catheter body, away from the tip
  const int c = static_cast<int>(std::lround(mid.column)), r = static_cast<int>(std::lround(mid.row));
  const double on_catheter = image[static_cast<std::size_t>(r) * w + c];
  EXPECT_LT(on_catheter, 0.6 * background) << "the catheter should be clearly darker than the background";
  // 10 px to the side (2.5 mm at the detector, ~1.9 mm at the object) is background again.
  EXPECT_NEAR(image[static_cast<std::size_t>(r) * w + c + 10], background, 1.5);
  const auto tip = ap.project({0, 0, 74.6});
  const double at_tip = image[static_cast<std::size_t>(std::lround(tip.row)) * w + std::lround(tip.column)];
  EXPECT_LT(at_tip, on_catheter - 10) << "the tip marker should be darker than the catheter body";
  // Beyond the tip: background.
  const auto beyond = ap.project({0, 0, 80});
  EXPECT_NEAR(image[static_cast<std::size_t>(std::lround(beyond.row)) * w + std::lround(beyond.column)],
              background, 1.5);
}

TEST(SimulatedFluoroscope, CatheterMovesWithTheBackboneAndLeavesNoTrace) {
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options());
  auto catheter = straight_catheter();
  std::vector<std::uint8_t> first;
  {
    const auto image = ap.render_noiseless(catheter);
    first.assign(image.begin(), image.end());
  }
  for (auto& p : catheter) p.x() += 10.0;  // move 10 mm right
  const auto image = ap.render_noiseless(catheter);
  const int w = ap.width();
  const auto old_place = ap.project({0, 0, 55});
  const auto new_place = ap.project({10, 0, 55});
  const std::size_t old_index =
      static_cast<std::size_t>(std::lround(old_place.row)) * w + std::lround(old_place.column);
  const std::size_t new_index =
      static_cast<std::size_t>(std::lround(new_place.row)) * w + std::lround(new_place.column);
  EXPECT_LT(first[old_index], 70);
  EXPECT_GT(image[old_index], 100) << "the previous frame's catheter must be gone";
  EXPECT_LT(image[new_index], 70);
  EXPECT_EQ(ap.render_noiseless({}).size(), image.size());
}

TEST(SimulatedFluoroscope, LateralViewSeesDepthThatApCannot) {
  // A catheter displaced along y is at the same AP column but moves in the lateral view.
  auto catheter = straight_catheter();
  for (auto& p : catheter) p.y() += 8.0;
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options());
  SimulatedFluoroscope lateral(FluoroView::kLateral, plain_options());
  const auto ap_image = ap.render_noiseless(catheter);
  const auto lat_image = lateral.render_noiseless(catheter);
  const int w = ap.width();
  const int row = static_cast<int>(std::lround(ap.project({0, 8, 55}).row));
  EXPECT_LT(ap_image[static_cast<std::size_t>(row) * w + 128], 70);  // column still ~127.5 in AP
  const auto lat = lateral.project({0, 8, 55});
  EXPECT_LT(lat.column, 127.5 - 30);
  EXPECT_LT(lat_image[static_cast<std::size_t>(std::lround(lat.row)) * w + std::lround(lat.column)], 70);
  EXPECT_GT(lat_image[static_cast<std::size_t>(row) * w + 128], 100);
}

TEST(SimulatedFluoroscope, ContrastFilledVesselIsDarkerThanTissueAndHasTubeProfile) {
  VesselTube vessel;
  for (int i = 0; i <= 60; ++i) {
    vessel.centerline.emplace_back(-15.0 + 0.5 * i, 0.0, 60.0);  // horizontal in AP
    vessel.radius_mm.push_back(2.5);
  }
  SimulatedFluoroscope ap(FluoroView::kAp, plain_options(), {vessel});
  const auto image = ap.render_noiseless({});
  const int w = ap.width();
  const double background = mean_in(image, w, 10, 10, 30, 30);
  const auto centre = ap.project({0, 0, 60});
  const auto near_wall = ap.project({0, 0, 62.2});
  const auto outside = ap.project({0, 0, 64});
  auto at = [&](const DetectorPoint& p) {
    return static_cast<double>(
        image[static_cast<std::size_t>(std::lround(p.row)) * w + std::lround(p.column)]);
  };
  // Centre chord 5 mm of contrast at 0.18/mm: transmission exp(−0.9) = 0.41.
  EXPECT_NEAR(at(centre), background * std::exp(-0.9), 6.0);
  EXPECT_LT(at(centre), at(near_wall));
  EXPECT_LT(at(near_wall), background - 5);
  EXPECT_NEAR(at(outside), background, 1.5);
}

TEST(SimulatedFluoroscope, QuantumNoiseHasPoissonVariance) {
  auto options = plain_options(256);
  options.blur_sigma_px = 0;  // noise is added after the blur anyway; keep the mean exact
  for (double photons : {300.0, 3000.0}) {
    options.photons_per_pixel = photons;
    SimulatedFluoroscope fluoro(FluoroView::kAp, options);
    const auto image = fluoro.render({});
    const double n = static_cast<double>(image.size());
    const double mean = std::accumulate(image.begin(), image.end(), 0.0) / n;
    double var = 0;
    for (auto v : image) var += (v - mean) * (v - mean);
    var /= n - 1;
    const double expected_mean = 240.0 * std::exp(-0.8);
    // Var(display) = display · gain with gain = 240 / photons; + 1/12 from rounding to integers.
    const double expected_var = expected_mean * fluoro.display_gain() + 1.0 / 12.0;
    EXPECT_NEAR(mean, expected_mean, 0.3) << photons;
    EXPECT_NEAR(var / expected_var, 1.0, 0.08) << "photons " << photons << " var " << var;
  }
  // Successive frames have fresh noise.
  SimulatedFluoroscope fluoro(FluoroView::kAp, options);
  std::vector<std::uint8_t> a;
  {
    const auto image = fluoro.render({});
    a.assign(image.begin(), image.end());
  }
  const auto b = fluoro.render({});
  EXPECT_FALSE(std::equal(a.begin(), a.end(), b.begin()));
}

TEST(SimulatedFluoroscope, JpegDecodesToTheDetectorSize) {
  auto options = plain_options(512);
  options.geometry.height = 384;
  options.anatomy = true;
  SimulatedFluoroscope fluoro(FluoroView::kLateral, options);
  const auto raw = fluoro.render(straight_catheter());
  std::vector<std::uint8_t> jpeg;
  fluoro.encode_jpeg(80, jpeg);
  ASSERT_GT(jpeg.size(), 1000u);
  EXPECT_EQ(jpeg[0], 0xFF);
  EXPECT_EQ(jpeg[1], 0xD8);  // SOI marker
  const cv::Mat decoded = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(decoded.empty());
  EXPECT_EQ(decoded.cols, 512);
  EXPECT_EQ(decoded.rows, 384);
  EXPECT_EQ(decoded.channels(), 1);
  // Lossy, but close to what was rendered on average.
  double diff = 0;
  for (int r = 0; r < decoded.rows; ++r)
    for (int c = 0; c < decoded.cols; ++c)
      diff += std::abs(decoded.at<std::uint8_t>(r, c) - raw[static_cast<std::size_t>(r) * 512 + c]);
  EXPECT_LT(diff / (512.0 * 384.0), 6.0);
  EXPECT_THROW(fluoro.encode_jpeg(0, jpeg), FluoroscopeError);
}

TEST(SimulatedFluoroscope, RejectsImpossibleGeometry) {
  auto options = plain_options();
  options.geometry.sod_mm = 1200;  // object beyond the detector
  EXPECT_THROW(SimulatedFluoroscope(FluoroView::kAp, options), FluoroscopeError);
  options = plain_options();
  options.geometry.width = 8;
  EXPECT_THROW(SimulatedFluoroscope(FluoroView::kAp, options), FluoroscopeError);
  options = plain_options();
  options.geometry.pixel_spacing_mm = std::nan("");
  EXPECT_THROW(SimulatedFluoroscope(FluoroView::kAp, options), FluoroscopeError);
  VesselTube bad;
  bad.centerline = {{0, 0, 0}, {0, 0, 1}};
  bad.radius_mm = {1.0};
  EXPECT_THROW(SimulatedFluoroscope(FluoroView::kAp, plain_options(), {bad}), FluoroscopeError);
}

TEST(SimulatedFluoroscope, VesselWallPointsLieAtTheRadius) {
  VesselTube vessel;
  for (int i = 0; i <= 20; ++i) {
    vessel.centerline.emplace_back(0.0, 0.0, i * 1.0);
    vessel.radius_mm.push_back(2.0);
  }
  const auto points = vessel_wall_points(vessel, 0.5, 12);
  EXPECT_EQ(points.size(), 41u * 12u);  // rings at 0, 0.5, ..., 20 mm
  for (const auto& p : points) EXPECT_NEAR(std::hypot(p.x(), p.y()), 2.0, 1e-5);
}

}  // namespace
}  // namespace tendril::sim
