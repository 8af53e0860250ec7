// Pre-operative planning (Heunis et al. 2021, §2.4): ICP on a calibration stick,
// Algorithm 1 on a noisy tube-wall cloud, Algorithm 2 on a cylinder "limb".
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "tendril/ultrasound/preoperative_plan.hpp"

namespace {

using namespace tendril::ultrasound;
using Eigen::Vector3d;

constexpr double kPi = 3.14159265358979323846;

// Centerline of the test vessel in {P}: a gentle quartic in x over 125 mm, 30 mm under y = 0.
Vector3d true_centre(double x) {
  const double v = x / 125.0;
  return {x, -30.0 + 3.0 * v * v - 2.0 * v * v * v * v, 4.0 * v - 6.0 * v * v + 3.0 * v * v * v * v};
}

// Wall points of a 10 mm-ID tube around true_centre (rings across x), with Gaussian noise.
std::vector<Vector3d> tube_wall(int count, double noise, std::mt19937& engine) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, noise);
  std::vector<Vector3d> points;
  for (int i = 0; i < count; ++i) {
    const double x = -5.0 + 135.0 * unit(engine), angle = 2.0 * kPi * unit(engine);
    points.push_back(true_centre(x) + 5.0 * Vector3d(0.0, std::cos(angle), std::sin(angle)) +
                     Vector3d(gauss(engine), gauss(engine), gauss(engine)));
  }
  return points;
}

// An asymmetric calibration stick: three rods of different lengths and a sphere (no symmetry for
// ICP to fall into).
std::vector<Vector3d> calibration_stick() {
  std::vector<Vector3d> points;
  for (double t = 0.0; t <= 80.0; t += 1.0) points.emplace_back(t, 0.0, 0.0);
  for (double t = 1.0; t <= 40.0; t += 1.0) points.emplace_back(0.0, t, 0.0);
  for (double t = 1.0; t <= 20.0; t += 1.0) points.emplace_back(0.0, 0.0, t);
  for (int i = 0; i < 60; ++i) {
    const double a = 2.0 * kPi * i / 60.0, b = std::acos(1.0 - 2.0 * ((i * 37) % 60 + 0.5) / 60.0);
    points.push_back(Vector3d(80.0, 0.0, 0.0) +
                     6.0 * Vector3d(std::sin(b) * std::cos(a), std::sin(b) * std::sin(a), std::cos(b)));
  }
  return points;
}

Eigen::Isometry3d ct_offset() {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = Eigen::AngleAxisd(15.0 * kPi / 180.0, Vector3d(1.0, 2.0, 0.5).normalized()).toRotationMatrix();
  t.translation() = Vector3d(12.0, -10.0, 12.0);  // 20 mm
  return t;
}

TEST(Icp, RegistersTheCalibrationStickFromA20mm15DegreeOffset) {
  std::mt19937 engine(5);
  std::normal_distribution<double> gauss(0.0, 0.2 / std::sqrt(3.0));  // 0.2 mm RMS noise (3-D)
  const auto stick = calibration_stick();
  const Eigen::Isometry3d tissue_to_ct = ct_offset();
  std::vector<Vector3d> scanned;
  for (const auto& p : stick)
    scanned.push_back(tissue_to_ct * p + Vector3d(gauss(engine), gauss(engine), gauss(engine)));
  const IcpResult result = icp(stick, scanned);
  EXPECT_TRUE(result.converged);
  EXPECT_LT(result.rms, 0.3);  // ICP registration
  const Eigen::Isometry3d error = result.transform * tissue_to_ct;
  EXPECT_LT(error.translation().norm(), 0.3);
  EXPECT_LT(Eigen::AngleAxisd(error.linear()).angle(), 0.5 * kPi / 180.0);
  EXPECT_THROW(icp(stick, {Vector3d::Zero()}), PlanningInputError);
}

TEST(RigidFit, RecoversAKnownTransformAndRejectsBadInput) {
  std::vector<Vector3d> a = {{0, 0, 0}, {10, 0, 0}, {0, 5, 0}, {0, 0, 3}}, b;
  for (const auto& p : a) b.push_back(ct_offset() * p);
  EXPECT_TRUE(rigid_fit(a, b).isApprox(ct_offset(), 1e-12));
  EXPECT_NEAR(rigid_fit(a, b).linear().determinant(), 1.0, 1e-12);
  EXPECT_THROW(rigid_fit(a, {b[0], b[1]}), PlanningInputError);
  b[2].x() = std::nan("");
  EXPECT_THROW(rigid_fit(a, b), PlanningInputError);
}

// Algorithm 1: 5000 wall points with 0.2 mm noise, through the CT frame and back by ICP's transform.
TEST(Algorithm1, FitsTheCenterlineFromTheWallCloudWithTheErrataFixed) {
  std::mt19937 engine(11);
  const auto wall = tube_wall(5000, 0.2, engine);
  const Eigen::Isometry3d tissue_to_ct = ct_offset();
  std::vector<Vector3d> wall_ct;
  for (const auto& p : wall) wall_ct.push_back(tissue_to_ct * p);
  CentroidPlanOptions options;
  options.count = 16;
  options.start_x = 0.0;
  options.end_x = 125.0;
  const auto centroids = arterial_centroids(wall_ct, tissue_to_ct.inverse(), options);
  ASSERT_EQ(centroids.size(), 16u);
  double worst = 0.0;
  for (std::size_t i = 0; i < centroids.size(); ++i) {
    worst = std::max(worst, (centroids[i] - true_centre(centroids[i].x())).norm());
    if (i > 0) EXPECT_NEAR(centroids[i].x() - centroids[i - 1].x(), 125.0 / 15.0, 0.1);  // evenly in x
  }
  std::printf("Algorithm 1: worst centroid distance to the true centerline %.3f mm\n", worst);
  EXPECT_LT(worst, 0.2);
  // Points past the endpoint do not bend the fit — the cloud extends to 130 mm here.
  EXPECT_NEAR(centroids.back().x(), 125.0, 0.1);
  options.end_x = -100.0;
  EXPECT_THROW(arterial_centroids(wall_ct, tissue_to_ct.inverse(), options), PlanningInputError);
  options.end_x = 125.0;
  options.count = 1;
  EXPECT_THROW(arterial_centroids(wall_ct, tissue_to_ct.inverse(), options), PlanningInputError);
}

// The limb of the digital twin (our set-up): a half-cylinder, r = 60 mm, axis along x.
std::vector<Vector3d> cylinder_surface(double spacing) {
  std::vector<Vector3d> points;
  for (double x = -10.0; x <= 135.0; x += spacing) {
    for (double a = -1.2; a <= 1.2; a += spacing / 60.0)
      points.emplace_back(x, -60.0 + 60.0 * std::cos(a), 60.0 * std::sin(a));
  }
  return points;
}

TEST(Algorithm2, PosesLookAtTheCentroidsAcrossTheVessel) {
  std::vector<Vector3d> centroids;
  for (int i = 0; i < 16; ++i) centroids.push_back(true_centre(125.0 * i / 15.0));
  const auto surface = cylinder_surface(0.5);
  ViaPointOptions options;
  options.nearest = 1;  // the paper's argmin
  const auto plan = probe_via_points(surface, centroids, options);
  ASSERT_EQ(plan.size(), 16u);
  for (std::size_t i = 0; i < plan.size(); ++i) {
    const auto& R = plan[i].rotation;
    EXPECT_TRUE((R.transpose() * R).isIdentity(1e-9));
    EXPECT_NEAR(R.determinant(), 1.0, 1e-9);
    const Vector3d to_centroid = (centroids[i] - plan[i].surface_point).normalized();
    EXPECT_LT(std::acos(std::min(1.0, R.col(2).dot(to_centroid))), 0.5 * kPi / 180.0);  // z at c_i
    // s_i within the cloud's spacing of the vertical through c_i.
    EXPECT_LT((plan[i].surface_point - centroids[i]).cross(Vector3d::UnitY()).norm(), 0.5);
    EXPECT_GT(plan[i].surface_point.y(), centroids[i].y());
    // y ⟂ the sweep direction, x ≈ along the vessel: the image plane is a cross-section.
    const std::size_t a = i + 1 < plan.size() ? i : i - 1;
    EXPECT_NEAR(R.col(1).dot((plan[a + 1].surface_point - plan[a].surface_point).normalized()), 0.0, 1e-9);
    EXPECT_GT(R.col(0).x(), 0.95);
    // pose() maps the probe's own axis into {P}: the centroid lies on the probe's z axis.
    const Vector3d in_probe = plan[i].pose().inverse() * centroids[i];
    EXPECT_NEAR(in_probe.x(), 0.0, 1e-9);
    EXPECT_NEAR(in_probe.y(), 0.0, 1e-9);
    EXPECT_GT(in_probe.z(), 20.0);
  }
  EXPECT_THROW(probe_via_points(surface, {centroids[0]}), PlanningInputError);
  EXPECT_THROW(probe_via_points({}, centroids), PlanningInputError);
  EXPECT_THROW(probe_via_points({Vector3d(0.0, -100.0, 0.0)}, centroids), PlanningInputError);  // none above
}

}  // namespace
