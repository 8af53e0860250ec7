// κ(s) for the tip EKF: curvature along in-plane arc length of a planar or projected centerline.
#include "tendril/teleop/perception/planar_curvature.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop::perception {
namespace {

constexpr double kPi = std::numbers::pi;

std::vector<Eigen::Vector2d> circle_arc(double radius, double sweep, double point_spacing,
                                        double sign = 1.0) {
  std::vector<Eigen::Vector2d> points;
  const int n = static_cast<int>(std::ceil(radius * sweep / point_spacing));
  for (int i = 0; i <= n; ++i) {
    const double phi = sweep * i / n;
    // Starts at the origin heading along +x, turning left (sign +1) or right (−1).
    points.emplace_back(radius * std::sin(phi), sign * radius * (1.0 - std::cos(phi)));
  }
  return points;
}

TEST(PlanarCurvature, CircleHasCurvatureOneOverRadiusWithItsSign) {
  for (const double sign : {1.0, -1.0}) {
    const PlanarCurvatureProfile profile =
        PlanarCurvatureProfile::from_polyline(circle_arc(20.0, 1.5 * kPi, 0.05, sign));
    EXPECT_NEAR(profile.length(), 20.0 * 1.5 * kPi, 0.3);
    for (const double s : {0.0, 5.0, 33.3, 60.0, 90.0}) {
      EXPECT_NEAR(profile.curvature_at(s), sign / 20.0, 1e-3) << "s " << s;
      EXPECT_NEAR(profile.heading_at(s), sign * s / 20.0, 2e-3) << "s " << s;
    }
    // The heading is continuous past ±π (here it reaches ±1.5π).
    EXPECT_NEAR(profile.heading_at(profile.length()), sign * 1.5 * kPi, 0.02);
    EXPECT_NEAR(profile.mean_curvature(30.0, 33.0), sign / 20.0, 1e-4);
    const Eigen::Vector2d p = profile.point_at(20.0 * kPi / 2.0);
    EXPECT_NEAR(p.x(), 20.0, 1e-3);
    EXPECT_NEAR(p.y(), sign * 20.0, 1e-3);
  }
}

TEST(PlanarCurvature, StraightContinuationOutsideTheCurve) {
  const PlanarCurvatureProfile profile =
      PlanarCurvatureProfile::from_polyline(circle_arc(10.0, kPi / 2, 0.05));
  const double end = profile.length();
  EXPECT_DOUBLE_EQ(profile.curvature_at(end + 1.0), 0.0);
  EXPECT_DOUBLE_EQ(profile.curvature_at(-1.0), 0.0);
  EXPECT_DOUBLE_EQ(profile.heading_at(end + 5.0), profile.heading_at(end));
  // Half a step inside, half beyond: the mean curvature counts only the turn inside.
  EXPECT_NEAR(end, 10.0 * kPi / 2.0, 0.01);  // the samples reach the curve's end
  EXPECT_NEAR(profile.heading_at(end), kPi / 2.0, 1e-3);
  EXPECT_NEAR(profile.mean_curvature(end - 1.5, end + 1.5), 0.1 * 1.5 / 3.0, 1e-3);
  const Eigen::Vector2d beyond = profile.point_at(end + 2.0);
  EXPECT_NEAR(beyond.x(), 10.0, 1e-2);  // the end is (10, 10) heading along +y
  EXPECT_NEAR(beyond.y(), 12.0, 1e-2);
  EXPECT_LE(profile.spacing(), PlanarCurvatureProfile::kDefaultSpacing);
  EXPECT_TRUE(std::isnan(profile.curvature_at(std::numeric_limits<double>::quiet_NaN())));
  EXPECT_TRUE(std::isnan(profile.mean_curvature(std::numeric_limits<double>::quiet_NaN(), 3.0)));
}

TEST(PlanarCurvature, ProjectionForeshortensArcLengthAndKeepsThePlanarShape) {
  const double tilt = kPi / 3.0;
  std::vector<Eigen::Vector3d> straight;
  for (int i = 0; i <= 400; ++i) {
    // A straight vessel rising at 60° out of the image plane: in-plane length = cos 60° × vessel length.
    const double t = 0.25 * i;
    straight.emplace_back(t * std::cos(tilt), 0.0, t * std::sin(tilt));
  }
  const PlanarCurvatureProfile line =
      PlanarCurvatureProfile::from_projection(straight, Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY());
  EXPECT_NEAR(line.vessel_length(), 100.0, 1e-9);
  EXPECT_NEAR(line.length(), 50.0, 0.25);
  EXPECT_NEAR(line.in_plane_arc_length(30.0), 15.0, 1e-9);
  EXPECT_NEAR(line.curvature_at(20.0), 0.0, 1e-9);

  // A circle lying in the image plane keeps κ = 1/R whatever the depth coordinate is.
  std::vector<Eigen::Vector3d> arc;
  for (const Eigen::Vector2d& p : circle_arc(15.0, kPi, 0.05)) arc.emplace_back(p.x(), 7.0, p.y());
  const PlanarCurvatureProfile lateral =
      PlanarCurvatureProfile::from_projection(arc, Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitZ());
  EXPECT_NEAR(lateral.curvature_at(20.0), 1.0 / 15.0, 1e-3);
  EXPECT_NEAR(lateral.in_plane_arc_length(20.0), 20.0, 1e-3);
}

TEST(PlanarCurvature, AStretchSeenEndOnMapsToNoInPlaneLength) {
  // 10 mm along x, 10 mm along the beam (y), 10 mm along x: insertion through the middle stretch does
  // not move the tip in the image.
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i <= 100; ++i) points.emplace_back(0.1 * i, 0.0, 0.0);
  for (int i = 1; i <= 100; ++i) points.emplace_back(10.0, 0.1 * i, 0.0);
  for (int i = 1; i <= 100; ++i) points.emplace_back(10.0 + 0.1 * i, 10.0, 0.0);
  const PlanarCurvatureProfile profile =
      PlanarCurvatureProfile::from_projection(points, Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitZ());
  EXPECT_NEAR(profile.vessel_length(), 30.0, 1e-9);
  EXPECT_NEAR(profile.length(), 20.0, 1e-9);
  EXPECT_NEAR(profile.in_plane_arc_length(5.0), 5.0, 1e-9);
  EXPECT_NEAR(profile.in_plane_arc_length(15.0), 10.0, 1e-9);
  EXPECT_NEAR(profile.in_plane_arc_length(25.0), 15.0, 1e-9);
  EXPECT_DOUBLE_EQ(profile.in_plane_arc_length(99.0), profile.length());
}

TEST(PlanarCurvature, UnusableInputIsRefused) {
  using teleop::VesselInputError;
  const std::vector<Eigen::Vector2d> good = circle_arc(10.0, 1.0, 0.1);
  EXPECT_THROW((void)PlanarCurvatureProfile::from_polyline(good, 0.0), VesselInputError);
  EXPECT_THROW((void)PlanarCurvatureProfile::from_polyline(good, std::numeric_limits<double>::quiet_NaN()),
               VesselInputError);
  std::vector<Eigen::Vector2d> with_nan = good;
  with_nan[3].y() = std::numeric_limits<double>::infinity();
  EXPECT_THROW((void)PlanarCurvatureProfile::from_polyline(with_nan), VesselInputError);
  const std::vector<Eigen::Vector2d> two_points{{0.0, 0.0}, {0.0, 0.0}, {5.0, 0.0}};
  EXPECT_THROW((void)PlanarCurvatureProfile::from_polyline(two_points), VesselInputError);
  const std::vector<Eigen::Vector2d> too_short{{0.0, 0.0}, {0.1, 0.0}, {0.2, 0.01}};
  EXPECT_THROW((void)PlanarCurvatureProfile::from_polyline(too_short, 0.25), VesselInputError);
  // A vessel along the beam has no length in the image.
  std::vector<Eigen::Vector3d> end_on;
  end_on.reserve(50);
  for (int i = 0; i < 50; ++i) end_on.emplace_back(1.0, 0.2 * i, 2.0);
  EXPECT_THROW((void)PlanarCurvatureProfile::from_projection(end_on, Eigen::Vector3d::UnitX(),
                                                             Eigen::Vector3d::UnitZ()),
               VesselInputError);
  std::vector<Eigen::Vector3d> fine;
  fine.reserve(50);
  for (int i = 0; i < 50; ++i) fine.emplace_back(0.2 * i, 0.0, 0.0);
  EXPECT_THROW(
      (void)PlanarCurvatureProfile::from_projection(fine, Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitX()),
      VesselInputError);
  EXPECT_THROW((void)PlanarCurvatureProfile::from_projection(fine, 2.0 * Eigen::Vector3d::UnitX(),
                                                             Eigen::Vector3d::UnitY()),
               VesselInputError);
}

}  // namespace
}  // namespace tendril::teleop::perception
