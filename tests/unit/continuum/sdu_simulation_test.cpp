// The SIMULATED disk nodes: ray casting against the scene, the ToF error model of Abah 2022, §3.3.2, the Hall
// response of §3.3.1 and the slope calibration that recovers it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "tendril/continuum/sdu_perception.hpp"
#include "tendril/continuum/sdu_simulation.hpp"

namespace tendril::continuum {
namespace {

TEST(SduScene, RaysHitPlanesBoxesAndCylinders) {
  Scene scene;
  scene.add(ScenePlane{Eigen::Vector3d(0, 0, -10), Eigen::Vector3d::UnitZ()});
  SceneBox box;
  box.pose.translation() = Eigen::Vector3d(100, 0, 0);
  box.half_extent_mm = Eigen::Vector3d(10, 10, 10);
  scene.add(box);
  scene.add(SceneCylinder{Eigen::Vector3d(0, 60, 0), Eigen::Vector3d::UnitZ(), 20.0, 100.0,
                          SurfaceFinish::kGlossy});
  const Eigen::Vector3d o = Eigen::Vector3d::Zero();
  EXPECT_NEAR(scene.cast(o, -Eigen::Vector3d::UnitZ(), 200)->distance_mm, 10.0, 1e-9);
  EXPECT_NEAR(scene.cast(o, Eigen::Vector3d::UnitX(), 200)->distance_mm, 90.0, 1e-9);
  const auto hit = scene.cast(o, Eigen::Vector3d::UnitY(), 200);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->distance_mm, 40.0, 1e-9);
  EXPECT_EQ(hit->finish, SurfaceFinish::kGlossy);
  EXPECT_FALSE(scene.cast(o, Eigen::Vector3d::UnitX(), 50));  // beyond the range
  EXPECT_FALSE(scene.cast(o, -Eigen::Vector3d::UnitY(), 500));
  // Penetration: 5 mm into the cylinder, 2 mm below the floor.
  EXPECT_NEAR(scene.penetration(Eigen::Vector3d(0, 45, 0)), 5.0, 1e-9);
  EXPECT_NEAR(scene.penetration(Eigen::Vector3d(0, -300, -12)), 2.0, 1e-9);
  EXPECT_EQ(scene.penetration(Eigen::Vector3d(0, -300, 0)), 0.0);
  EXPECT_THROW(scene.add(SceneCylinder{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), 1.0, 1.0}),
               std::invalid_argument);
  EXPECT_THROW(scene.move_cylinder(7, Eigen::Vector3d::Zero()), std::out_of_range);
}

TEST(SduToFModel, ErrorGrowsFromTheAxisToTheDissertationsConeEdge) {
  TofModel m;
  EXPECT_NEAR(tof_error_mm(m, SurfaceFinish::kMatte, 0.0), 0.01, 1e-12);
  EXPECT_NEAR(tof_error_mm(m, SurfaceFinish::kMatte, m.matte_half_angle_rad), 12.5, 1e-12);
  EXPECT_NEAR(tof_error_mm(m, SurfaceFinish::kGlossy, 0.0), 0.019, 1e-12);
  EXPECT_NEAR(tof_error_mm(m, SurfaceFinish::kGlossy, m.glossy_half_angle_rad), 15.6, 1e-12);
}

// A node facing a wall reads its distance on the axis; a rod at the cone's edge reads long by up to the
// edge error; a glossy rod outside ±11.9° is not seen at all, a matte one is (up to ±16.5°).
TEST(SduToFModel, SimulatedNodeSeesWithTheDissertationsCone) {
  SduSegmentModel seg;
  TofModel tof;
  tof.noise_sd_mm = 0.0;
  SimulatedSduNode node(seg, tof, HallModel{}, 7);
  const Eigen::Isometry3d disk = Eigen::Isometry3d::Identity();
  Scene wall;
  wall.add(
      ScenePlane{Eigen::Vector3d(79 + 60, 0, 0), -Eigen::Vector3d::UnitX()});  // 60 mm in front of slot 0
  auto s = node.sense(wall, disk, 0.0);
  ASSERT_EQ(s.tof_status[0], TofStatus::kValid);
  EXPECT_NEAR(s.tof_mm[0], 60.0, 0.02);
  EXPECT_EQ(s.tof_status[4], TofStatus::kNoTarget);  // looking away

  // A vertical rod 80 mm out, 14° off slot 0's axis (inside the matte cone, outside the glossy one).
  const double off = 14.0 * M_PI / 180.0, range = 80.0, r_rod = 25.4;
  const Eigen::Vector3d origin(79, 0, 0);
  const Eigen::Vector3d centre = origin + (range + r_rod) * Eigen::Vector3d(std::cos(off), std::sin(off), 0);
  Scene matte, glossy;
  matte.add(SceneCylinder{centre, Eigen::Vector3d::UnitZ(), r_rod, 200.0, SurfaceFinish::kMatte});
  glossy.add(SceneCylinder{centre, Eigen::Vector3d::UnitZ(), r_rod, 200.0, SurfaceFinish::kGlossy});
  s = node.sense(matte, disk, 0.0);
  ASSERT_EQ(s.tof_status[0], TofStatus::kValid);
  EXPECT_GT(s.tof_mm[0], range - 1.0);         // reads long, never short
  EXPECT_LT(s.tof_mm[0], range + 12.5 + 1.0);  // by at most the edge error
  // The rod's near surface spans angles around 14°: the glossy cone (11.9°) still catches its edge,
  // so move it further out of the cone to show the narrower cone.
  const double off2 = 28.0 * M_PI / 180.0;  // the rod spans 14°–42° off the axis
  const Eigen::Vector3d centre2 =
      origin + (range + r_rod) * Eigen::Vector3d(std::cos(off2), std::sin(off2), 0);
  Scene matte2, glossy2;
  matte2.add(SceneCylinder{centre2, Eigen::Vector3d::UnitZ(), r_rod, 200.0, SurfaceFinish::kMatte});
  glossy2.add(SceneCylinder{centre2, Eigen::Vector3d::UnitZ(), r_rod, 200.0, SurfaceFinish::kGlossy});
  EXPECT_EQ(node.sense(matte2, disk, 0.0).tof_status[0], TofStatus::kValid);
  EXPECT_EQ(node.sense(glossy2, disk, 0.0).tof_status[0], TofStatus::kNoTarget);
  // Beyond the usable 130 mm: no target.
  Scene far;
  far.add(ScenePlane{Eigen::Vector3d(79 + 140, 0, 0), -Eigen::Vector3d::UnitX()});
  EXPECT_EQ(node.sense(far, disk, 0.0).tof_status[0], TofStatus::kNoTarget);
}

TEST(SduHallModel, ResponseIsTheDissertationsSlopeWithItsBow) {
  HallModel m;
  EXPECT_NEAR(hall_field_change_mT(m, 0.0), 0.0, 1e-12);
  EXPECT_NEAR(hall_field_change_mT(m, 10.0), 2.6, 1e-12);  // 2.6 mT at 10 N
  EXPECT_GT(hall_field_change_mT(m, 5.0), 0.26 * 5.0);     // the bow
}

// Abah 2022, §3.3.1: a probe pressed in steps to 10 N and back, 5 times, on all 8 windows; a least-squares
// line recovers the slope (0.26 mT/N) and the F-linearity (4.52 %).
TEST(SduHallCalibration, RecoversTheSlopeFromSimulatedLoading) {
  SduSegmentModel seg;
  SimulatedSduNode node(seg, TofModel{}, HallModel{}, 11);
  double slope_sum = 0.0, lin_sum = 0.0, blin_sum = 0.0;
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    std::vector<double> f, b;
    for (int rep = 0; rep < 5; ++rep) {
      for (int k = 0; k <= 200; ++k) {  // 0 → 10 N → 0 in 0.1 N steps
        const double force = k <= 100 ? 0.1 * k : 0.1 * (200 - k);
        std::array<double, kHallPerSdu> forces{};
        forces[j] = force;
        const auto s = node.sense_forces(forces, 0.0);
        f.push_back(force);
        b.push_back(s.hall_mT[j][2]);
      }
    }
    const auto cal = calibrate_hall_slope(f, b);
    EXPECT_NEAR(cal.slope_mT_per_N, 0.26, 0.005) << "window " << j;
    EXPECT_NEAR(cal.intercept_mT, node.rest_field()[j][2] + 0.26 * 6 * 0.0452 * 10 / 6, 0.02);
    EXPECT_NEAR(cal.f_linearity_pct, 4.52, 1.0) << "window " << j;  // the bow plus the noise's extremes
    slope_sum += cal.slope_mT_per_N;
    lin_sum += cal.f_linearity_pct;
    blin_sum += cal.b_linearity_pct;
  }
  std::printf(
      "Hall calibration over 8 windows x 5 runs: slope %.4f mT/N (dissertation 0.26 +- 0.03), F-linearity "
      "%.2f %% "
      "(dissertation 4.52 +- 0.56), B-linearity %.2f %% (dissertation 4.47 +- 0.57)\n",
      slope_sum / 8, lin_sum / 8, blin_sum / 8);
  EXPECT_NEAR(lin_sum / 8, 4.52, 0.56);  // within the dissertation's spread over the windows
  EXPECT_THROW(calibrate_hall_slope(std::vector<double>{1, 1}, std::vector<double>{2, 3}),
               std::invalid_argument);
  EXPECT_THROW(calibrate_hall_slope(std::vector<double>{1}, std::vector<double>{2}), std::invalid_argument);
}

TEST(SduHallModel, PressingASleeveWindowIsFeltByThatWindowMost) {
  SduSegmentModel seg;
  HallModel hall;
  hall.noise_sd_mT = 0.0;
  SimulatedSduNode node(seg, TofModel{}, hall, 3);
  // A box pushed 1 mm into the sleeve at Hall slot 2 (112.5°).
  const double a = hall_slot_angle(seg, 2);
  SceneBox box;
  box.half_extent_mm = Eigen::Vector3d(10, 10, 10);
  box.pose.rotate(Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()));
  box.pose.pretranslate((79 - 1 + 10) * Eigen::Vector3d(std::cos(a), std::sin(a), 0));
  Scene scene;
  scene.add(box);
  node.sense(scene, Eigen::Isometry3d::Identity(), 0.0);
  const auto& f = node.true_force();
  EXPECT_NEAR(f[2], 5.0, 0.3);  // 1 mm × 5 N/mm
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    if (j != 2) {
      EXPECT_LT(f[j], f[2]) << j;
    }
  }
}

}  // namespace
}  // namespace tendril::continuum
