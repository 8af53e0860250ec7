// FBG catheter shape (seed 002 §9, REQ-FBG-1/2, REQ-SAFE-3) and contacts (§10, REQ-CON-1): the frame
// codec, reconstruction from a SIMULATED interrogator, Eq. 2, curvature warnings, wall contacts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/ultrasound/artery_model.hpp"
#include "tendril/ultrasound/fbg_shape.hpp"

namespace {

using namespace tendril::ultrasound;
using Eigen::Vector3d;

// A planar constant-curvature arc of radius R from the origin along +z, bending towards +x, dense.
std::vector<Vector3d> arc(double radius, double length, double spacing = 0.1) {
  std::vector<Vector3d> points;
  for (double s = 0.0; s <= length + 1e-9; s += spacing) {
    const double a = s / radius;
    points.emplace_back(radius * (1.0 - std::cos(a)), 0.0, radius * std::sin(a));
  }
  return points;
}

// A 3-D S-curve: two opposite bends in different planes, every 0.1 mm.
std::vector<Vector3d> s_curve(double length) {
  std::vector<Vector3d> points;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Vector3d p = Vector3d::Zero();
  const double ds = 0.05;
  const int steps = static_cast<int>(length / ds);
  for (int k = 0; k <= steps; ++k) {
    if (k % 2 == 0) points.push_back(p);
    const double s = k * ds;
    const double kx = 0.012 * std::sin(2.0 * 3.14159265358979 * s / length);
    const double ky = 0.008 * std::cos(3.14159265358979 * s / length);
    const Vector3d w(kx * ds, ky * ds, 0.0);
    if (w.norm() > 0.0) R = R * Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    p += R.col(2) * ds;
  }
  return points;
}

struct Errors {
  double mean;
  double max;
};

Errors shape_errors(const std::vector<Vector3d>& a, const std::vector<Vector3d>& b) {
  double sum = 0.0, worst = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double e = (a[i] - b[i]).norm();
    sum += e;
    worst = std::max(worst, e);
  }
  return {sum / static_cast<double>(a.size()), worst};
}

TEST(FbgFrame, RoundTripsAndRejectsMalformedFrames) {
  FbgFrame frame;
  frame.sequence = 42;
  frame.gratings = 2;
  frame.cores = 4;
  frame.wavelengths = {1510.0, 1510.0001, 1509.9999, 1510.00002, 1511.25, 1511.3, 1511.2, 1511.25};
  const FbgFrame back = parse_fbg_frame(format_fbg_frame(frame));
  EXPECT_EQ(back.sequence, 42u);
  EXPECT_EQ(back.gratings, 2);
  EXPECT_EQ(back.cores, 4);
  EXPECT_EQ(back.wavelengths, frame.wavelengths);
  EXPECT_EQ(parse_fbg_frame("FBG 1 1 1 1550\r\n").wavelengths.size(), 1u);
  for (const char* bad :
       {"", "FBG", "XYZ 1 1 1 1550", "FBG 1 1 1", "FBG 1 1 1 1550 1551", "FBG 1 0 1", "FBG 1 2000 1 1550",
        "FBG 1 1 17 1550", "FBG 1 1 1 nan", "FBG 1 1 1 -3", "FBG 1 1 1 1e9", "FBG -1 1 1 1550",
        "FBG 1 1 1 1550x", "FBG 1 1 1  1550", "FBG 1 1 2 1550"}) {
    EXPECT_THROW(parse_fbg_frame(bad), FbgFrameError) << bad;
  }
}

// REQ-FBG-2: a constant-curvature arc R = 100 mm, 270 mm, noise-free → max error < 0.05 mm; a 3-D
// S-curve too; and with temperature (common mode) it does not matter.
TEST(FbgShapeReconstructor, ReconstructsArcsAndSCurvesNoiseFree) {
  const MulticoreFiber fiber;
  SimulatedFbgInterrogator interrogator(fiber, 0.0);
  FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
  for (const auto& polyline : {arc(100.0, 271.0), arc(60.0, 271.0), s_curve(271.0)}) {
    const FiberTruth truth = fiber_truth(fiber, polyline);
    const FbgShape& shape = reconstructor.reconstruct(interrogator.measure(truth, 12.0, 1));
    ASSERT_EQ(shape.status, FbgShapeStatus::ok);
    const Errors e = shape_errors(shape.points, truth.points);
    std::printf("noise-free: mean %.4f mm, max %.4f mm, max curvature %.4f 1/mm\n", e.mean, e.max,
                shape.max_curvature);
    EXPECT_LT(e.max, 0.05);
    EXPECT_FALSE(shape.curvature_warning);
  }
  // The arc's curvature is 1/R at every grating, bending towards +x of {F}.
  const FbgShape& shape = reconstructor.reconstruct(interrogator.measure(arc(100.0, 271.0), 0.0, 2));
  for (const auto& k : shape.curvature) EXPECT_NEAR(k.norm(), 0.01, 1e-5);
}

// REQ-FBG-2 with 1 µε-equivalent wavelength noise (1.2 pm): mean ≤ 0.82 mm, max ≤ 1.52 mm over 200 frames.
TEST(FbgShapeReconstructor, StaysInsideTheSeedsEnvelopeWithOneMicrostrainOfNoise) {
  const MulticoreFiber fiber;
  SimulatedFbgInterrogator interrogator(fiber, 1.2, 7);
  FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
  const FiberTruth truth = fiber_truth(fiber, s_curve(271.0));
  double sum = 0.0, worst = 0.0;
  for (int k = 0; k < 200; ++k) {
    const FbgShape& shape =
        reconstructor.reconstruct(interrogator.measure(truth, 0.5 * k, static_cast<std::uint64_t>(k)));
    ASSERT_EQ(shape.status, FbgShapeStatus::ok);
    const Errors e = shape_errors(shape.points, truth.points);
    sum += e.mean;
    worst = std::max(worst, e.max);
  }
  std::printf("1 ue noise: mean %.3f mm, max %.3f mm\n", sum / 200.0, worst);
  EXPECT_LE(sum / 200.0, 0.82);
  EXPECT_LE(worst, 1.52);
}

TEST(FbgShapeReconstructor, WarnsAboveTheBendLimitAndRejectsBadFramesWithoutAllocating) {
  const MulticoreFiber fiber;
  SimulatedFbgInterrogator interrogator(fiber, 0.0);
  FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
  const FbgFrame tight = interrogator.measure(arc(40.0, 271.0), 0.0, 1);  // R = 40 mm < 50 mm
  const FbgFrame gentle = interrogator.measure(arc(55.0, 271.0), 0.0, 2);
  FbgFrame short_frame = gentle;
  short_frame.gratings = 31;
  short_frame.wavelengths.resize(31 * 4);
  FbgFrame nan_frame = gentle;
  nan_frame.wavelengths[5] = std::nan("");
  reconstructor.reconstruct(gentle);
  const long before = tendril::testing::allocation_count.load();
  EXPECT_TRUE(reconstructor.reconstruct(tight).curvature_warning);
  EXPECT_EQ(std::count(reconstructor.reconstruct(tight).over_limit.begin(),
                       reconstructor.reconstruct(tight).over_limit.end(), 1),
            32);
  EXPECT_FALSE(reconstructor.reconstruct(gentle).curvature_warning);
  EXPECT_EQ(reconstructor.reconstruct(short_frame).status, FbgShapeStatus::wrong_dimensions);
  EXPECT_EQ(reconstructor.reconstruct(nan_frame).status, FbgShapeStatus::not_finite);
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_THROW(FbgShapeReconstructor(fiber, short_frame), std::invalid_argument);
  EXPECT_THROW(fiber_truth(fiber, arc(100.0, 200.0)), std::invalid_argument);  // shorter than the fibre
}

// REQ-FBG-1: Eq. 2 round-trips a known shape and base pose to 1e-9.
TEST(FbgToGlobal, IsEquationTwo) {
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity(), fiber_in_base = Eigen::Isometry3d::Identity();
  base.linear() = Eigen::AngleAxisd(0.7, Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  base.translation() = Vector3d(100.0, -20.0, 35.0);
  fiber_in_base.linear() = Eigen::AngleAxisd(-0.3, Vector3d::UnitY()).toRotationMatrix();
  fiber_in_base.translation() = Vector3d(0.0, 0.0, 12.0);
  const auto shape = fiber_truth(MulticoreFiber{}, s_curve(271.0)).points;
  std::vector<Vector3d> global;
  fbg_to_global(base, fiber_in_base, shape, global);
  ASSERT_EQ(global.size(), shape.size());
  for (std::size_t i = 0; i < shape.size(); ++i) {
    EXPECT_LT((global[i] - base * (fiber_in_base * shape[i])).norm(), 1e-9);
    EXPECT_LT(((base * fiber_in_base).inverse() * global[i] - shape[i]).norm(), 1e-9);
  }
}

// REQ-CON-1: a straight catheter, tilted in a 10 mm tube (a mesh of 120 sides), is flagged exactly
// at the sensors within 0.25 mm of touching the wall (axis closer than 1.25 mm to it); none centred.
TEST(CatheterContacts, AreFlaggedExactlyUnderOnePointTwoFiveMillimetres) {
  tendril::teleop::CenterlinePolyline tube;
  for (double x = -20.0; x <= 300.0; x += 5.0) {
    tube.points.emplace_back(x, 0.0, 0.0);
    tube.radii.push_back(5.0);
  }
  const auto mesh = tendril::teleop::make_tube_mesh(tube, 5.0, 120);
  std::vector<Vector3d> centred, tilted;
  std::vector<double> offsets;
  for (int g = 0; g < 32; ++g) {
    const double x = 270.0 / 31.0 * g;
    centred.emplace_back(x, 0.0, 0.0);
    const double offset = 2.0 + 2.2 * x / 270.0;  // 2 → 4.2 mm off the axis: wall distance 3 → 0.8
    offsets.push_back(offset);
    tilted.emplace_back(x, offset * std::cos(0.4), offset * std::sin(0.4));
  }
  std::vector<CatheterContact> contacts;
  std::vector<double> distances;
  find_contacts(mesh, centred, {}, contacts, distances);
  EXPECT_TRUE(contacts.empty());
  for (const double d : distances) EXPECT_NEAR(d, 5.0, 0.01);
  find_contacts(mesh, tilted, {}, contacts, distances);
  std::vector<int> expected;
  for (int g = 0; g < 32; ++g) {
    const double wall = 5.0 - offsets[static_cast<std::size_t>(g)];
    EXPECT_NEAR(distances[static_cast<std::size_t>(g)], wall, 0.01);
    ASSERT_GT(std::abs(wall - 1.25), 0.01) << "sensor " << g << " sits on the threshold";
    if (wall < 1.25) expected.push_back(g);
  }
  std::vector<int> flagged;
  for (const auto& c : contacts) flagged.push_back(c.sensor);
  EXPECT_EQ(flagged, expected);
  EXPECT_FALSE(expected.empty());
  EXPECT_LT(expected.size(), 32u);
}

}  // namespace
