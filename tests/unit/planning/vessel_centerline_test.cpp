#include "tendril/teleop/vessel_centerline.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>

#include <cmath>
#include <sstream>
#include <string>

namespace tendril::teleop {
namespace {

constexpr double kPi = 3.14159265358979323846;

std::string csv_of(const CenterlinePolyline& line, double scale = 1.0) {
  std::ostringstream out;
  out.precision(17);
  for (std::size_t i = 0; i < line.points.size(); ++i) {
    out << line.points[i].x() * scale << "," << line.points[i].y() * scale << ","
        << line.points[i].z() * scale;
    if (!line.radii.empty()) out << "," << line.radii[i];
    out << "\n";
  }
  return out.str();
}

TEST(VesselCenterline, PlacedAtAnEntryTheStartIsTheEntryAndTheFirstTangentItsZ) {
  // A vessel starting at (5, -3, 2) heading along +x, then bending.
  CenterlinePolyline v;
  for (int i = 0; i <= 40; ++i) v.points.emplace_back(5.0 + i, -3.0 + 0.01 * i * i, 2.0);
  v.radii.assign(v.points.size(), 2.5);
  Eigen::Isometry3d entry = Eigen::Isometry3d::Identity();
  entry.translation() = Eigen::Vector3d(0.0, 0.0, 40.8);  // a catheter's insertion point
  const auto placement = placement_at_entry(v, entry);
  const auto placed = transformed(v, placement);
  EXPECT_NEAR((placed.points.front() - Eigen::Vector3d(0.0, 0.0, 40.8)).norm(), 0.0, 1e-9);
  const Eigen::Vector3d first_tangent = (placed.points[1] - placed.points[0]).normalized();
  EXPECT_GT(first_tangent.z(), 0.99) << first_tangent.transpose();
  EXPECT_EQ(placed.radii, v.radii);
  // The planner's insertion frame is the same placement with the entry at the origin.
  const auto resampled = VesselCenterline::from_polyline(v, 0.5);
  const auto aligned = resampled.aligned_to_insertion();
  const Eigen::Isometry3d at_origin = placement_at_entry(v, Eigen::Isometry3d::Identity());
  for (std::size_t i = 0; i < resampled.size(); i += 10)
    EXPECT_NEAR((at_origin * resampled.points()[i] - aligned.points()[i]).norm(), 0.0, 1e-9) << i;
}

TEST(VesselCenterline, ParsesHeaderCommentsAndRadius) {
  const std::string csv = "x,y,z,radius\n# a comment\n0,0,0,2.0\n\n0,0,1,2.5\n0,0,2,3.0\n0,0,3,3.0\n";
  const auto branches = parse_centerline_csv(csv);
  ASSERT_EQ(branches.size(), 1u);
  EXPECT_EQ(branches[0].points.size(), 4u);
  const auto vessel = VesselCenterline::from_csv(csv, 0.5);
  EXPECT_EQ(vessel.size(), 7u);
  EXPECT_DOUBLE_EQ(vessel.length(), 3.0);
  ASSERT_TRUE(vessel.has_radius());
  EXPECT_NEAR(vessel.radii()[1], 2.25, 1e-12);  // linear between samples
  EXPECT_NEAR(vessel.points()[3].z(), 1.5, 1e-12);
}

TEST(VesselCenterline, ResamplesAtEqualArcLengthAlongBends) {
  // Quarter circle of radius 10 mm, densely sampled: resampled spacing is ds along the curve.
  CenterlinePolyline arc;
  for (int i = 0; i <= 2000; ++i) {
    const double a = 0.5 * kPi * i / 2000.0;
    arc.points.emplace_back(10.0 * (1.0 - std::cos(a)), 0.0, 10.0 * std::sin(a));
  }
  const auto vessel = VesselCenterline::from_polyline(arc, 0.5);
  EXPECT_EQ(vessel.size(), static_cast<std::size_t>(std::floor(5.0 * kPi / 0.5)) + 1);
  for (std::size_t i = 1; i < vessel.size(); ++i) {
    EXPECT_NEAR((vessel.points()[i] - vessel.points()[i - 1]).norm(), 0.5, 1e-3);
    // Tangent of the circle at arc length s is (sin(s/R), 0, cos(s/R)).
    const double a = vessel.arc_length(i) / 10.0;
    EXPECT_NEAR(vessel.tangents()[i].x(), std::sin(a), 2e-3);
    EXPECT_NEAR(vessel.tangents()[i].z(), std::cos(a), 2e-3);
  }
}

TEST(VesselCenterline, YawPitchFollowEquation43AndRebuildTheTangent) {
  CenterlinePolyline line;
  const Eigen::Vector3d direction = Eigen::Vector3d(-1.0, -2.0, 0.5).normalized();
  for (int i = 0; i < 20; ++i) line.points.push_back(direction * i);
  const auto vessel = VesselCenterline::from_polyline(line, 1.0);
  // α = atan2(y, x) of the horizontal projection (third quadrant, so the two-argument form matters).
  EXPECT_NEAR(vessel.yaw()[5], std::atan2(-2.0, -1.0), 1e-12);
  EXPECT_NEAR(vessel.pitch()[5], std::atan2(std::hypot(1.0, 2.0), 0.5), 1e-12);
  EXPECT_TRUE((vessel.local_frame(5).col(2) - direction).norm() < 1e-12);
}

TEST(VesselCenterline, SplitsBranchesAtJumpsAndSelectsNearest) {
  std::string csv;
  for (int i = 0; i < 10; ++i) csv += "0,0," + std::to_string(i) + "\n";
  for (int i = 0; i < 10; ++i) csv += "50," + std::to_string(i) + ",0\n";  // jump of ~50 mm
  const auto branches = parse_centerline_csv(csv);
  ASSERT_EQ(branches.size(), 2u);
  EXPECT_EQ(branches[1].points.size(), 10u);
  EXPECT_EQ(nearest_branch(branches, Eigen::Vector3d(50.0, 12.0, 0.0)), 1u);
  // Nearest end is the last point of branch 1, so the chosen vessel starts there.
  const auto vessel = VesselCenterline::from_csv_nearest(csv, 0.5, Eigen::Vector3d(50.0, 12.0, 0.0));
  EXPECT_NEAR((vessel.points().front() - Eigen::Vector3d(50.0, 9.0, 0.0)).norm(), 0.0, 1e-12);
  EXPECT_THROW(VesselCenterline::from_csv(csv, 0.5, 2), VesselInputError);
}

TEST(VesselCenterline, RejectsBadInputWithTypedErrors) {
  EXPECT_THROW(VesselCenterline::from_csv("", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("# only comments\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,nan\n0,0,2\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,inf\n0,0,2\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,1\n0,0,abc\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,1,2\n0,0,2\n", 0.5), VesselInputError);
  // Degenerate: repeated points leave fewer than 3 distinct points.
  EXPECT_THROW(VesselCenterline::from_csv("1,1,1\n1,1,1\n1,1,1\n1,1,1\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,5\n", 0.5), VesselInputError);
  // Too short for ds: 3 points but only 2 samples at ds = 1.5 over 2 mm.
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,1\n0,0,2\n", 1.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,1\n0,0,2\n", 0.0), VesselInputError);
  EXPECT_NO_THROW(VesselCenterline::from_csv("0,0,0\n0,0,1\n0,0,2\n", 1.0));
  // A path that doubles back (0 → 3 → 0 along z) has no tangent at the turn.
  try {
    VesselCenterline::from_csv("0,0,0\n0,0,1\n0,0,2\n0,0,3\n0,0,2\n0,0,1\n0,0,0\n", 0.5);
    FAIL() << "reversal accepted";
  } catch (const VesselInputError& e) {
    EXPECT_NE(std::string(e.what()).find("turns back"), std::string::npos);
  }
  // Absurdly long (1e6 mm) or too many samples for ds.
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,5e5\n0,0,1e6\n", 0.5), VesselInputError);
  EXPECT_THROW(VesselCenterline::from_csv("0,0,0\n0,0,500\n0,0,1000\n", 1e-4), VesselInputError);
  // Unit mismatch: a 150 mm path written in metres is 0.15 long.
  const auto ica = make_synthetic_ica(7);
  EXPECT_NO_THROW(VesselCenterline::from_csv(csv_of(ica), 0.5));
  try {
    VesselCenterline::from_csv(csv_of(ica, 1e-3), 0.5);
    FAIL() << "metres accepted";
  } catch (const VesselInputError& e) {
    EXPECT_NE(std::string(e.what()).find("metres"), std::string::npos);
  }
}

TEST(VesselCenterline, AlignedToInsertionStartsAtOriginAlongZ) {
  auto line = make_synthetic_ica(3);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(1.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  for (auto& p : line.points) p = R * p + Eigen::Vector3d(10, -4, 7);
  const auto vessel = VesselCenterline::from_polyline(line, 0.5);
  const auto aligned = vessel.aligned_to_insertion();
  EXPECT_LT(aligned.points().front().norm(), 1e-12);
  EXPECT_LT((aligned.tangents().front() - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
  // Rigid: spacing preserved.
  EXPECT_NEAR((aligned.points()[100] - aligned.points()[0]).norm(),
              (vessel.points()[100] - vessel.points()[0]).norm(), 1e-9);
}

TEST(SyntheticIca, DeterministicLengthCurvatureAndRadius) {
  const auto a = make_synthetic_ica(42), b = make_synthetic_ica(42), c = make_synthetic_ica(43);
  ASSERT_EQ(a.points.size(), b.points.size());
  for (std::size_t i = 0; i < a.points.size(); ++i) ASSERT_EQ(a.points[i], b.points[i]);
  EXPECT_NE(a.points.back(), c.points.back());
  const auto vessel = VesselCenterline::from_polyline(a, 0.5);
  EXPECT_NEAR(vessel.length(), 150.0, 0.5);
  for (double r : vessel.radii()) {
    EXPECT_GE(r, 2.0 - 1e-9);
    EXPECT_LE(r, 3.0 + 1e-9);
  }
  // Curvature from turning angle per ds: ≤ 1/5 mm⁻¹, and the path really bends (siphon-like).
  double max_curvature = 0.0, total_turn = 0.0;
  for (std::size_t i = 2; i + 2 < vessel.size(); ++i) {
    const double turn = std::acos(std::clamp(vessel.tangents()[i].dot(vessel.tangents()[i + 1]), -1.0, 1.0));
    max_curvature = std::max(max_curvature, turn / 0.5);
    total_turn += turn;
  }
  EXPECT_LE(max_curvature, 1.0 / 5.0 + 0.01);
  EXPECT_GT(total_turn, 2.0 * kPi);
}

}  // namespace
}  // namespace tendril::teleop
