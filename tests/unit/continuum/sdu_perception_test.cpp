// Perception from the SDUs: points in {0}, the voxel map, RANSAC planes, the bracing check, the Hall
// path, and the mapping error of a simulated scan beside the dissertation's 9.73 mm RMS.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/continuum/sdu_perception.hpp"
#include "tendril/continuum/sdu_simulation.hpp"

namespace tendril::continuum {
namespace {

TEST(SduPoints, RangeLandsOnTheSensorsLineOfSight) {
  SduSegmentModel m;
  SduSample s;
  s.received = true;
  s.tof_status.fill(TofStatus::kNoTarget);
  s.tof_status[2] = TofStatus::kValid;  // 90°: looks along +y
  s.tof_mm[2] = 50.0;
  s.tof_status[3] = TofStatus::kValid;
  s.tof_mm[3] = std::nan("");  // never a point
  s.tof_status[4] = TofStatus::kValid;
  s.tof_mm[4] = 400.0;  // beyond the range: never a point
  std::array<Eigen::Vector3d, kTofPerSdu> out;
  const auto pose = disk_pose(m, {}, 4);
  ASSERT_EQ(sample_points(m, pose, s, 130.0, out), 1U);
  EXPECT_NEAR((out[0] - Eigen::Vector3d(0, 79 + 50, 370)).norm(), 0.0, 1e-9);
}

TEST(SduVoxelMap, MergesKeepsWhatWasMappedWhenFullAndRefusesNonFinite) {
  VoxelMap map(10.0, 3);
  EXPECT_EQ(map.insert({1, 1, 1}), MapInsert::kNewVoxel);
  EXPECT_EQ(map.insert({3, 1, 1}), MapInsert::kMerged);
  EXPECT_EQ(map.insert({25, 1, 1}), MapInsert::kNewVoxel);
  EXPECT_EQ(map.insert({-5, 1, 1}), MapInsert::kNewVoxel);  // negative coordinates are their own voxel
  EXPECT_EQ(map.insert({100, 1, 1}), MapInsert::kFull);
  EXPECT_EQ(map.insert({2, 2, 2}), MapInsert::kMerged);  // a known voxel still takes points when full
  EXPECT_EQ(map.insert({std::nan(""), 0, 0}), MapInsert::kRejected);
  EXPECT_EQ(map.size(), 3U);
  EXPECT_EQ(map.refused_full(), 1U);
  EXPECT_EQ(map.refused_invalid(), 1U);
  const auto pts = map.points();
  ASSERT_EQ(pts.size(), 3U);
  EXPECT_NEAR((pts[0] - Eigen::Vector3d(2, 4.0 / 3, 4.0 / 3)).norm(), 0.0, 1e-9);
  EXPECT_THROW(VoxelMap(0.0, 10), std::invalid_argument);
  EXPECT_THROW(VoxelMap(5.0, 0), std::invalid_argument);
}

TEST(SduVoxelMap, InsertingNeverAllocates) {
  VoxelMap map(5.0, 100'000);
  const long before = tendril::testing::allocation_count.load();
  for (int i = 0; i < 50'000; ++i) map.insert({i * 0.7, (i % 97) * 3.0, (i % 13) * 11.0});
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
}

std::vector<Eigen::Vector3d> noisy_patch(const Eigen::Vector3d& centre, const Eigen::Vector3d& normal,
                                         double side, double step, double noise, std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, noise);
  const Eigen::Vector3d e1 = normal.unitOrthogonal(), e2 = normal.cross(e1);
  std::vector<Eigen::Vector3d> pts;
  for (double u = -side / 2; u <= side / 2 + 1e-9; u += step)
    for (double v = -side / 2; v <= side / 2 + 1e-9; v += step)
      pts.push_back(centre + u * e1 + v * e2 + n(rng) * normal);
  return pts;
}

TEST(SduPlanes, RansacFindsPlanesAndHonoursTheReferenceNormal) {
  std::mt19937_64 rng(5);
  auto floor = noisy_patch({0, 0, 0}, Eigen::Vector3d::UnitZ(), 400, 20, 3.0, rng);
  const auto wall = noisy_patch({0, 300, 150}, Eigen::Vector3d::UnitY(), 300, 20, 3.0, rng);
  std::vector<Eigen::Vector3d> all = floor;
  all.insert(all.end(), wall.begin(), wall.end());
  RansacParameters p;
  p.reference_normal = Eigen::Vector3d::UnitY();  // ask for the wall although the floor has more points
  const auto r = fit_plane_ransac(all, p);
  ASSERT_TRUE(std::holds_alternative<PlaneFit>(r));
  const auto& fit = std::get<PlaneFit>(r);
  EXPECT_GT(fit.plane.normal.dot(Eigen::Vector3d::UnitY()), 0.999);
  EXPECT_NEAR(fit.plane.offset_mm, 300.0, 1.0);
  EXPECT_EQ(fit.inliers.size(), wall.size());  // 40 mm inlier distance: the floor is 150 mm away
  // Without a reference the dissertation's procedure peels both planes off, larger first.
  const auto planes = extract_planes(all, RansacParameters{}, 3);
  ASSERT_TRUE(std::holds_alternative<std::vector<PlaneFit>>(planes));
  const auto& list = std::get<std::vector<PlaneFit>>(planes);
  ASSERT_GE(list.size(), 2U);
  // The wall's lowest 40 mm lie within the floor's inlier band and tilt its refit a little.
  EXPECT_GT(std::abs(list[0].plane.normal.z()), 0.99);
  EXPECT_GT(std::abs(list[1].plane.normal.y()), 0.99);
}

TEST(SduPlanes, AMapThatCannotBeBuiltIsADefinedError) {
  const std::vector<Eigen::Vector3d> none;
  const auto r = fit_plane_ransac(none, RansacParameters{});
  ASSERT_TRUE(std::holds_alternative<MapError>(r));
  EXPECT_EQ(std::get<MapError>(r), MapError::kNoPoints);
  EXPECT_STREQ(to_string(MapError::kNoPoints), "the map holds no points yet");
  const VoxelMap empty(5.0, 100);
  const auto b = check_bracing_in_map(empty, RansacParameters{}, BracingParameters{});
  ASSERT_TRUE(std::holds_alternative<MapError>(b));
  EXPECT_EQ(std::get<MapError>(b), MapError::kNoPoints);
  const std::vector<Eigen::Vector3d> two{{0, 0, 0}, {1, 0, 0}};
  EXPECT_EQ(std::get<MapError>(fit_plane_ransac(two, RansacParameters{})), MapError::kTooFewPoints);
  RansacParameters bad;
  bad.inlier_distance_mm = std::nan("");
  std::mt19937_64 rng(1);
  EXPECT_EQ(
      std::get<MapError>(fit_plane_ransac(noisy_patch({}, Eigen::Vector3d::UnitZ(), 100, 10, 0, rng), bad)),
      MapError::kInvalidInput);
}

TEST(SduBracing, A200mmPlateIsAdmissibleA100mmPlateAndAThinBeamAreNot) {
  std::mt19937_64 rng(9);
  BracingParameters bp;
  RansacParameters rp;
  rp.min_inliers = 10;
  auto check = [&](const std::vector<Eigen::Vector3d>& pts) {
    const auto fit = fit_plane_ransac(pts, rp);
    EXPECT_TRUE(std::holds_alternative<PlaneFit>(fit));
    return check_bracing(pts, std::get<PlaneFit>(fit), bp);
  };
  const auto big =
      check(noisy_patch({10, 20, 30}, Eigen::Vector3d(0.2, 0.1, 1).normalized(), 200, 8, 2.0, rng));
  EXPECT_TRUE(big.admissible) << big.reason;
  EXPECT_GE(big.largest_square_mm, 150.0);
  const auto small = check(noisy_patch({0, 0, 0}, Eigen::Vector3d::UnitZ(), 100, 8, 2.0, rng));
  EXPECT_FALSE(small.admissible) << small.reason;
  // A beam 40 mm wide and 600 mm long: plenty of area, no 150 mm square.
  std::vector<Eigen::Vector3d> beam;
  for (double x = -300; x <= 300; x += 8)
    for (double y = -20; y <= 20; y += 8) beam.push_back({x, y, 0});
  const auto b = check(beam);
  EXPECT_FALSE(b.admissible) << b.reason;
  // A big plate with a hole in the middle wide enough to hold no 150 mm square anywhere.
  std::vector<Eigen::Vector3d> frame;
  for (double x = -150; x <= 150; x += 8)
    for (double y = -150; y <= 150; y += 8)
      if (std::abs(x) > 60 || std::abs(y) > 60) frame.push_back({x, y, 0});
  const auto f = check(frame);
  EXPECT_FALSE(f.admissible) << f.reason;
  std::printf(
      "bracing: 200 mm plate %.0f mm, 100 mm plate %.0f mm, 40 mm beam %.0f mm, 300 mm frame with a "
      "120 mm hole %.0f mm (largest continuous square; admissible from 150 mm)\n",
      big.largest_square_mm, small.largest_square_mm, b.largest_square_mm, f.largest_square_mm);
}

TEST(SduHall, UnbiasForceAndContactLocalisation) {
  SduSegmentModel m;
  HallModel hall;
  SimulatedSduNode node(m, TofModel{}, hall, 21);
  HallUnbiaser u;
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(u.add(node.sense_forces({}, 0.0)));
  const HallBias bias = u.bias();
  for (std::size_t j = 0; j < kHallPerSdu; ++j) EXPECT_NEAR(bias.b0_mT[j][2], node.rest_field()[j][2], 0.002);
  // ΔB = 2.6 mT ↔ 10 N.
  SduSample s;
  s.received = true;
  s.hall_ok.fill(true);
  for (std::size_t j = 0; j < kHallPerSdu; ++j) s.hall_mT[j] = bias.b0_mT[j];
  s.hall_mT[5][2] += 2.6;
  const auto f = hall_forces(s, bias);
  EXPECT_NEAR(f[5], 10.0, 1e-9);
  EXPECT_NEAR(f[0], 0.0, 1e-12);
  s.hall_ok[1] = false;
  s.hall_mT[2][2] = std::nan("");
  const auto g = hall_forces(s, bias);
  EXPECT_TRUE(std::isnan(g[1]));
  EXPECT_TRUE(std::isnan(g[2]));
  // An invalid reading never enters the baseline.
  EXPECT_FALSE(u.add(s));
  // Localisation: 3 N on disk 3, window 6, beats 1 N elsewhere; the point is on the sleeve at 292.5°.
  std::array<std::array<double, kHallPerSdu>, kSdusPerSegment> forces{};
  forces[1][2] = 1.0;
  forces[3][6] = 3.0;
  const auto poses = disk_poses(m, {});
  const auto c = locate_contact(m, poses, forces, 0.5);
  ASSERT_TRUE(c.contact);
  EXPECT_EQ(c.disk, 3);
  EXPECT_EQ(c.slot, 6);
  EXPECT_NEAR(c.slot_angle_rad * 180 / M_PI, 292.5, 1e-9);
  const double a = c.slot_angle_rad;
  EXPECT_NEAR((c.point - Eigen::Vector3d(79 * std::cos(a), 79 * std::sin(a), 296)).norm(), 0.0, 1e-9);
  EXPECT_NEAR((c.from_centre.normalized() - c.normal).norm(), 0.0, 1e-12);
  EXPECT_FALSE(locate_contact(m, poses, forces, 5.0).contact);
}

// The dissertation's mapping set-up (§3.5) in simulation: vertical walls (normal [0, 1, 0]) and slanted ones
// (normal [0.98, 0, 0.22]), each half aluminium and half poster board 9.25 mm in front of it; the segment
// bends, turns its bending plane and rolls while the 5 SDUs range; the map is the points in {0}; the
// error is each point's distance to its parent ground-truth plane.
TEST(SduMapping, SimulatedScanErrorBesideTheDissertations973mm) {
  SduSegmentModel m;
  Scene scene;
  const Eigen::Vector3d n1(0, 1, 0);
  const Eigen::Vector3d n2 = Eigen::Vector3d(0.98, 0, 0.22).normalized();
  // Walls as thin boxes; their faces towards the robot are the ground-truth planes.
  std::vector<Plane> truth;
  auto wall = [&](const Eigen::Vector3d& normal, double offset, const Eigen::Vector3d& along, double from,
                  double to) {
    SceneBox b;
    const Eigen::Vector3d up = normal.cross(along).normalized();
    Eigen::Matrix3d r;
    r.col(0) = along;
    r.col(1) = up;
    r.col(2) = normal;
    b.pose.linear() = r;
    b.half_extent_mm = Eigen::Vector3d((to - from) / 2, 400, 5);
    // The face nearer the robot lies on normal·x = offset; the wall reaches 600 mm up its own slope.
    b.pose.translation() =
        (offset + 5) * normal + ((from + to) / 2) * along + (up.z() >= 0 ? 200.0 : -200.0) * up;
    scene.add(b);
    truth.push_back(Plane{-normal, -offset});  // the face at normal·x = offset, facing −normal
  };
  // Vertical walls at y = 185 (aluminium, x < 0) and 175.75 (poster board, x > 0), facing −y.
  wall(n1, 185.0, Eigen::Vector3d::UnitX(), -400, 0);
  wall(n1, 175.75, Eigen::Vector3d::UnitX(), 0, 400);
  // Slanted walls on the −x side, facing +x, leaning away: n2·x = −117.7 (aluminium, y < 0; 170 mm from
  // the backbone at mid-height) and −108.45 (board, y > 0).
  wall(-n2, 117.7, Eigen::Vector3d::UnitY(), -400, 0);
  wall(-n2, 108.45, Eigen::Vector3d::UnitY(), 0, 400);

  std::array<SimulatedSduNode, kSdusPerSegment> nodes{
      SimulatedSduNode(m, TofModel{}, HallModel{}, 1), SimulatedSduNode(m, TofModel{}, HallModel{}, 2),
      SimulatedSduNode(m, TofModel{}, HallModel{}, 3), SimulatedSduNode(m, TofModel{}, HallModel{}, 4),
      SimulatedSduNode(m, TofModel{}, HallModel{}, 5)};
  VoxelMap map(5.0, 200'000);
  std::vector<Eigen::Vector3d> raw;
  std::array<Eigen::Vector3d, kTofPerSdu> pts;
  // About the dissertation's sweep rates (bend ±0.02 rad/s, plane ±0.1 rad/s, roll ±0.1 rad/s) over 60 s; a
  // sample every 40 ms keeps the sanitized test short (the map's density, not its error, depends on it).
  for (int k = 0; k < 1500; ++k) {
    const double t = k * 0.04;
    // Bent at most 0.35 rad so that the sleeve never touches a wall.
    const SegmentConfiguration q{0.6 * std::sin(0.1 * t * 1.7), 0.2 + 0.15 * std::sin(0.08 * t),
                                 1.2 * std::sin(0.1 * t)};
    const auto poses = disk_poses(m, q);
    for (std::size_t i = 0; i < kSdusPerSegment; ++i) {
      const auto s = nodes[i].sense(scene, poses[i], t);
      const auto wire = decode_sdu_frames(encode_sdu_sample(i, s), 0);  // through the CAN frames' 1 mm
      const std::size_t n = sample_points(m, poses[i], wire, 130.0, pts);
      for (std::size_t p = 0; p < n; ++p) {
        raw.push_back(pts[p]);
        map.insert(pts[p]);
      }
    }
  }
  ASSERT_GT(raw.size(), 1000U);
  const double rms_raw = rms_to_nearest_plane(raw, truth);
  const auto voxels = map.points();
  const double rms_map = rms_to_nearest_plane(voxels, truth);
  // The dissertation's evaluation (§3.5): RANSAC (40 mm, reference normals n̂₁ then n̂₂ on the rest) splits the
  // points into the vertical and the slanted set; each point's parent is the nearer of that set's two
  // ground-truth planes (aluminium, poster board); the error is the RMS of the orthogonal residuals.
  RansacParameters rp;
  rp.reference_normal = n1;
  const auto vertical = fit_plane_ransac(raw, rp);
  ASSERT_TRUE(std::holds_alternative<PlaneFit>(vertical));
  std::vector<bool> taken(raw.size(), false);
  std::vector<Eigen::Vector3d> vertical_set, rest;
  for (auto i : std::get<PlaneFit>(vertical).inliers) taken[i] = true;
  for (std::size_t i = 0; i < raw.size(); ++i) (taken[i] ? vertical_set : rest).push_back(raw[i]);
  rp.reference_normal = n2;
  const auto slanted = fit_plane_ransac(rest, rp);
  ASSERT_TRUE(std::holds_alternative<PlaneFit>(slanted));
  std::vector<Eigen::Vector3d> slanted_set;
  for (auto i : std::get<PlaneFit>(slanted).inliers) slanted_set.push_back(rest[i]);
  const std::vector<Plane> vertical_truth{truth[0], truth[1]}, slanted_truth{truth[2], truth[3]};
  const double rms_v = rms_to_nearest_plane(vertical_set, vertical_truth);
  const double rms_s = rms_to_nearest_plane(slanted_set, slanted_truth);
  const double n_v = static_cast<double>(vertical_set.size()), n_s = static_cast<double>(slanted_set.size());
  const double rms_seed = std::sqrt((rms_v * rms_v * n_v + rms_s * rms_s * n_s) / (n_v + n_s));
  const double angle_v =
      std::acos(std::min(1.0, std::abs(std::get<PlaneFit>(vertical).plane.normal.dot(n1))));
  const double angle_s = std::acos(std::min(1.0, std::abs(std::get<PlaneFit>(slanted).plane.normal.dot(n2))));
  std::printf(
      "simulated mapping: %zu points (%zu voxels of 5 mm); the dissertation's evaluation: %zu vertical + %zu "
      "slanted "
      "points, RMS %.2f mm (vertical %.2f, slanted %.2f; dissertation 9.73 mm with an optical tracker at "
      "8.08 Hz); "
      "every point to its nearest true plane %.2f mm raw, %.2f mm voxel means; RANSAC normals %.1f and %.1f "
      "deg "
      "from the true ones\n",
      raw.size(), voxels.size(), vertical_set.size(), slanted_set.size(), rms_seed, rms_v, rms_s, rms_raw,
      rms_map, angle_v * 180 / M_PI, angle_s * 180 / M_PI);
  EXPECT_GT(n_v + n_s, 0.9 * static_cast<double>(raw.size()));  // RANSAC classified nearly every point
  EXPECT_LT(rms_seed, 9.73);  // the simulation knows the disk poses exactly: it must beat the tracked rig
  EXPECT_GT(rms_seed, 0.3);   // ...but the cone's error is there
  // The 40 mm band takes in points of the other wall near the corner, which tilts the refit a little.
  EXPECT_LT(angle_v, 10 * M_PI / 180);
  EXPECT_LT(angle_s, 10 * M_PI / 180);
}

}  // namespace
}  // namespace tendril::continuum
