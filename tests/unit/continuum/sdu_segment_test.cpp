// Constant-curvature kinematics of the SDU segment: disk poses, sensor frames, the tracker chain.
#include <gtest/gtest.h>

#include <cmath>

#include "tendril/continuum/sdu_segment.hpp"

namespace tendril::continuum {
namespace {

TEST(SduSegment, StraightSegmentStacksTheDisksUpTheBackbone) {
  SduSegmentModel m;
  m.validate();
  const auto poses = disk_poses(m, {});
  for (std::size_t i = 0; i < kSdusPerSegment; ++i) {
    EXPECT_NEAR((poses[i].translation() - Eigen::Vector3d(0, 0, m.disk_arc_mm[i])).norm(), 0.0, 1e-9);
    EXPECT_TRUE(poses[i].linear().isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  }
  EXPECT_DOUBLE_EQ(m.disk_arc_mm.back(), 370.0);  // the top SDU sits at the tip
}

TEST(SduSegment, BentSegmentFollowsACircularArc) {
  SduSegmentModel m;
  SegmentConfiguration q{0.0, M_PI / 2, 0.0};  // a quarter circle in the x-z plane
  const double r = m.length_mm / q.bending_rad;
  const auto tip = backbone_pose(m, q, m.length_mm);
  EXPECT_NEAR(tip.translation().x(), r, 1e-9);
  EXPECT_NEAR(tip.translation().z(), r, 1e-9);
  EXPECT_NEAR(tip.translation().y(), 0.0, 1e-9);
  // The tangent turned by θ: now along +x.
  EXPECT_NEAR((tip.linear().col(2) - Eigen::Vector3d::UnitX()).norm(), 0.0, 1e-12);
  // Every disk lies on the circle of radius r about (r, 0, 0).
  for (const auto& p : disk_poses(m, q))
    EXPECT_NEAR((p.translation() - Eigen::Vector3d(r, 0, 0)).norm(), r, 1e-9);
}

TEST(SduSegment, BendingPlaneAndStageRollTurnTheArcAboutTheBase) {
  SduSegmentModel m;
  const SegmentConfiguration in_x{0.0, 0.6, 0.0};
  const SegmentConfiguration in_y{0.0, 0.6, M_PI / 2};
  const SegmentConfiguration rolled{M_PI / 2, 0.6, 0.0};
  const Eigen::Vector3d px = backbone_pose(m, in_x, m.length_mm).translation();
  const Eigen::Vector3d py = backbone_pose(m, in_y, m.length_mm).translation();
  const Eigen::Vector3d pr = backbone_pose(m, rolled, m.length_mm).translation();
  EXPECT_NEAR(py.x(), 0.0, 1e-9);
  EXPECT_NEAR(py.y(), px.x(), 1e-9);
  EXPECT_NEAR((pr - py).norm(), 0.0, 1e-9);
  // Without torsion: a disk's slot 0 stays in the plane spanned by base x and the tangent when δ = 0.
  const auto d = disk_pose(m, in_x, 2);
  EXPECT_NEAR(d.linear().col(0).y(), 0.0, 1e-12);
  // ...and the stage roll turns the slots with it.
  const auto dr = disk_pose(m, SegmentConfiguration{M_PI / 2, 0.0, 0.0}, 2);
  EXPECT_NEAR((dr.linear().col(0) - Eigen::Vector3d::UnitY()).norm(), 0.0, 1e-12);
}

TEST(SduSegment, SensorFramesLookRadiallyOutFromTheRim) {
  SduSegmentModel m;
  for (std::size_t j = 0; j < kTofPerSdu; ++j) {
    const auto s = tof_sensor_in_disk(m, j);
    const double a = j * M_PI / 4;
    EXPECT_NEAR((s.translation() - 79.0 * Eigen::Vector3d(std::cos(a), std::sin(a), 0)).norm(), 0.0, 1e-9);
    EXPECT_NEAR((s.linear().col(2) - Eigen::Vector3d(std::cos(a), std::sin(a), 0)).norm(), 0.0, 1e-12);
    EXPECT_NEAR(s.linear().determinant(), 1.0, 1e-12);
    // Hall windows sit half-way between ToF windows, ≥ 30° from their neighbours (Abah 2022, §3.2.2).
    EXPECT_NEAR(hall_slot_angle(m, j) - tof_slot_angle(m, j), M_PI / 8, 1e-12);
  }
}

TEST(SduSegment, TrackerChainGivesTheSamePoseAsTheKinematics) {
  SduSegmentModel m;
  const SegmentConfiguration q{0.3, 0.7, -0.4};
  const Eigen::Isometry3d base_d = disk_pose(m, q, 3);
  // A camera somewhere, a marker on the disk 108.5 mm out (Abah 2022, §3.5).
  Eigen::Isometry3d camera_T_base = Eigen::Isometry3d::Identity();
  camera_T_base.rotate(Eigen::AngleAxisd(0.9, Eigen::Vector3d(1, 2, 3).normalized()));
  camera_T_base.pretranslate(Eigen::Vector3d(100, -400, 1200));
  Eigen::Isometry3d marker_T_disk = Eigen::Isometry3d::Identity();
  marker_T_disk.translation() = Eigen::Vector3d(-108.5, 0, 0);
  const Eigen::Isometry3d camera_T_marker = camera_T_base * base_d * marker_T_disk.inverse();
  const auto got = disk_pose_from_tracker(camera_T_base, camera_T_marker, marker_T_disk);
  EXPECT_TRUE(got.isApprox(base_d, 1e-9));
}

TEST(SduSegment, ValidationNamesTheField) {
  SduSegmentModel m;
  m.disk_arc_mm[2] = 100.0;  // below disk 1
  try {
    m.validate();
    FAIL() << "accepted disks out of order";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("disk_arc_mm[2]"), std::string::npos) << e.what();
  }
  SduSegmentModel bad;
  bad.length_mm = std::nan("");
  EXPECT_THROW(bad.validate(), std::invalid_argument);
}

TEST(SduSegment, TipRateMatchesAFiniteStep) {
  SduSegmentModel m;
  const SegmentConfiguration q{0.0, 0.5, 0.2};
  SegmentConfiguration q2 = q;
  q2.bending_rad += 1e-4;
  const Eigen::Vector3d fd =
      (backbone_pose(m, q2, m.length_mm).translation() - backbone_pose(m, q, m.length_mm).translation()) /
      1e-4;
  EXPECT_NEAR((tip_position_per_bending(m, q) - fd).norm(), 0.0, 0.05);
  // Straight: the tip moves L/2 per radian, sideways.
  EXPECT_NEAR(tip_position_per_bending(m, {}).norm(), m.length_mm / 2, 1e-3);
}

}  // namespace
}  // namespace tendril::continuum
