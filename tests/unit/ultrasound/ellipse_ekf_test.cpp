// The Appendix B ellipse EKF + star algorithm (Heunis et al. 2021, §3.2 and Appendix B) on SIMULATED B-mode
// slices of the phantom's 10 mm tube: centre error, contour error, Dice against the true lumen.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <random>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/ultrasound/ellipse_ekf.hpp"
#include "tendril/ultrasound/simulated_bmode.hpp"

namespace {

using namespace tendril::ultrasound;
using tendril::teleop::CenterlinePolyline;

constexpr double kPi = 3.14159265358979323846;

// A straight tube along x, `depth` mm along z from the origin; image poses map {I} (x elevation,
// y lateral, z depth) into this frame, so the identity pose looks straight down at it.
CenterlinePolyline straight_tube(double depth, double radius = 5.0) {
  CenterlinePolyline line;
  for (int i = -40; i <= 40; ++i) {
    line.points.emplace_back(static_cast<double>(i), 0.0, depth);
    line.radii.push_back(radius);
  }
  return line;
}

// Image pose: the image plane cuts the tube at x = along, its normal (the {I} x axis) tilted by
// `tilt` about the depth axis, shifted laterally and in depth by `offset`.
Eigen::Isometry3d image_pose(double along, double tilt, const Eigen::Vector2d& offset) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = Eigen::AngleAxisd(tilt, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  pose.translation() = Eigen::Vector3d(along, -offset.x(), -offset.y());
  return pose;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}
double percentile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(p * static_cast<double>(v.size() - 1))];
}

TEST(EllipseRadius, JacobianMatchesTheSpecsCheckAndFiniteDifferences) {
  const Eigen::Vector3d x(5.3, 4.1, 0.4);
  const Eigen::Vector3d j = ellipse_radius_jacobian(x, 1.1);
  EXPECT_NEAR(j[0], 0.404668, 1e-6);  // derived from A15
  EXPECT_NEAR(j[1], 0.620149, 1e-6);
  EXPECT_NEAR(j[2], 1.212207, 1e-6);
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d dx = Eigen::Vector3d::Zero();
    dx[k] = 1e-6;
    EXPECT_NEAR((ellipse_radius(x + dx, 1.1) - ellipse_radius(x - dx, 1.1)) / 2e-6, j[k], 1e-7);
  }
  EXPECT_NEAR(ellipse_radius({5.0, 5.0, 0.0}, 0.7), 5.0, 1e-12);  // a circle
  EXPECT_NEAR(ellipse_radius({6.0, 4.0, 0.0}, 0.0), 6.0, 1e-12);  // f along θ − φ = 0 (A15)
  EXPECT_NEAR(ellipse_radius({6.0, 4.0, 0.0}, kPi / 2), 4.0, 1e-12);
  EXPECT_NEAR(ellipse_radius({6.0, 4.0, kPi / 2}, kPi / 2), 6.0, 1e-12);  // tilted by φ
}

TEST(SimulatedBMode, IsDeterministicAndShowsADarkLumenInsideABrightWall) {
  const SimulatedBModeProbe probe(straight_tube(30.0), BModeGeometry{});
  const auto pose = image_pose(0.0, 0.0, {0.0, 0.0});
  const BModeImage a = probe.render(pose, 7), b = probe.render(pose, 7), c = probe.render(pose, 8);
  EXPECT_EQ(a.pixels, b.pixels);
  EXPECT_NE(a.pixels, c.pixels);
  const auto truth = probe.truth(pose);
  ASSERT_TRUE(truth.has_value());
  EXPECT_NEAR(truth->centre.x(), 0.0, 1e-9);
  EXPECT_NEAR(truth->centre.y(), 30.0, 1e-9);
  // Mean intensities: lumen ≪ tissue < wall (top of the tube, where the beam meets it head-on).
  auto mean_in = [&](double y0, double z0, double half) {
    double sum = 0.0;
    int n = 0;
    for (double y = y0 - half; y <= y0 + half; y += 0.125) {
      for (double z = z0 - half; z <= z0 + half; z += 0.125) {
        const Eigen::Vector2d px = a.geometry.pixel_of({y, z});
        sum += a.at(static_cast<int>(std::lround(px.x())), static_cast<int>(std::lround(px.y())));
        ++n;
      }
    }
    return sum / n;
  };
  const double lumen = mean_in(0.0, 30.0, 2.0), tissue = mean_in(-12.0, 30.0, 2.0),
               wall = mean_in(0.0, 24.5, 0.3);
  EXPECT_LT(lumen, 0.1);
  EXPECT_GT(tissue, 2.0 * lumen);
  EXPECT_GT(wall, 1.5 * tissue);
  // The true mask: π r² of lumen area within 1 %.
  const LumenMask mask = probe.lumen_mask(pose);
  const double area = std::count(mask.begin(), mask.end(), 1) * 0.125 * 0.125;
  EXPECT_NEAR(area, kPi * 25.0, 0.01 * kPi * 25.0);
}

TEST(SimulatedBMode, RejectsUnusableSetUp) {
  EXPECT_THROW(SimulatedBModeProbe(CenterlinePolyline{}, BModeGeometry{}), UltrasoundSetupError);
  EXPECT_THROW(SimulatedBModeProbe(straight_tube(30.0), BModeGeometry{4, 400, 0.1}), UltrasoundSetupError);
  SimulatedBModeParameters bad;
  bad.noise_sigma = std::nan("");
  EXPECT_THROW(SimulatedBModeProbe(straight_tube(30.0), BModeGeometry{}, bad), UltrasoundSetupError);
  CenterlinePolyline mismatched = straight_tube(30.0);
  mismatched.radii.pop_back();
  EXPECT_THROW(SimulatedBModeProbe(mismatched, BModeGeometry{}), UltrasoundSetupError);
}

// Synthetic slices: slices of the tube, cut square and obliquely (elliptical lumens: f up to 5 / cos 35° =
// 6.1 mm), the seed up to 2 mm off the true centre, Rayleigh speckle and noise. Centre error, mean
// radial contour error and Dice against the true lumen.
TEST(EllipseSliceSegmenter, FindsTheLumenOnSimulatedSlicesWithSpeckle) {
  const BModeGeometry geometry{};
  const SimulatedBModeProbe probe(straight_tube(30.0), geometry);
  EllipseSliceSegmenter segmenter(geometry);
  std::mt19937 engine(42);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<double> centre_errors, contour_errors, dices;
  LumenMask mask;
  for (int k = 0; k < 24; ++k) {
    const double tilt = (unit(engine) * 2.0 - 1.0) * 35.0 * kPi / 180.0;
    const Eigen::Vector2d offset((unit(engine) * 2 - 1) * 6.0, (unit(engine) * 2 - 1) * 6.0);
    const auto pose = image_pose(unit(engine) * 10.0 - 5.0, tilt, offset);
    const auto truth = probe.truth(pose);
    ASSERT_TRUE(truth.has_value());
    const double seed_angle = unit(engine) * 2 * kPi, seed_distance = 2.0 * unit(engine);
    const Eigen::Vector2d seed =
        truth->centre + seed_distance * Eigen::Vector2d(std::cos(seed_angle), std::sin(seed_angle));
    const BModeImage image = probe.render(pose, 1000 + static_cast<std::uint64_t>(k));
    const SliceSegmentation& result = segmenter.segment(image, seed);
    ASSERT_TRUE(result.valid);
    EXPECT_LE(result.iterations, 20);
    centre_errors.push_back((result.centre - truth->centre).norm());
    // Radial error of each contour point against the true ellipse (semi-axes r/cos(tilt) along the
    // image's y axis and r along z, centred at the truth).
    const double f = truth->lumen_radius / std::cos(tilt), h = truth->lumen_radius;
    double sum = 0.0;
    for (const auto& point : result.contour) {
      const Eigen::Vector2d d = point - truth->centre;
      const double theta = std::atan2(d.y(), d.x());
      sum += std::abs(d.norm() - ellipse_radius({f, h, 0.0}, theta));
    }
    contour_errors.push_back(sum / static_cast<double>(result.contour.size()));
    segmenter.lumen_mask(result, mask);
    dices.push_back(dice_coefficient(mask, probe.lumen_mask(pose)));
  }
  const double mean_dice =
      std::accumulate(dices.begin(), dices.end(), 0.0) / static_cast<double>(dices.size());
  const double mean_contour = std::accumulate(contour_errors.begin(), contour_errors.end(), 0.0) /
                              static_cast<double>(contour_errors.size());
  std::printf(
      "slices: centre error median %.3f mm, p95 %.3f mm; mean radial contour error %.3f mm; Dice mean %.3f, "
      "min %.3f\n",
      median(centre_errors), percentile(centre_errors, 0.95), mean_contour, mean_dice,
      *std::min_element(dices.begin(), dices.end()));
  EXPECT_LE(median(centre_errors), 0.5);  // synthetic slices
  EXPECT_LE(percentile(centre_errors, 0.95), 1.0);
  EXPECT_LE(mean_contour, 0.5);
  EXPECT_GE(mean_dice, 0.84);  // the article's Dice
  EXPECT_GE(*std::min_element(dices.begin(), dices.end()), 0.84);
}

TEST(EllipseSliceSegmenter, SegmentsWithoutAllocatingAndRejectsBadSeeds) {
  const BModeGeometry geometry{};
  const SimulatedBModeProbe probe(straight_tube(30.0), geometry);
  EllipseSliceSegmenter segmenter(geometry);
  const auto pose = image_pose(0.0, 0.2, {1.0, -1.0});
  const BModeImage image = probe.render(pose, 3);
  const Eigen::Vector2d seed = probe.truth(pose)->centre + Eigen::Vector2d(1.0, 1.0);
  segmenter.segment(image, seed);  // warm
  const long before = tendril::testing::allocation_count.load();
  for (int k = 0; k < 3; ++k) EXPECT_TRUE(segmenter.segment(image, seed).valid);
  EXPECT_FALSE(segmenter.segment(image, {std::nan(""), 30.0}).valid);
  EXPECT_FALSE(segmenter.segment(image, {100.0, 30.0}).valid);  // outside the 40 mm wide image
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  BModeImage other = image;
  other.geometry.columns = 100;
  EXPECT_FALSE(segmenter.segment(other, seed).valid);
  EllipseEkfParameters bad;
  bad.rays = 2;
  EXPECT_THROW(EllipseSliceSegmenter(geometry, bad), UltrasoundSetupError);
  bad = {};
  bad.measurement_noise = -1.0;
  EXPECT_THROW(EllipseSliceSegmenter(geometry, bad), UltrasoundSetupError);
}

}  // namespace
