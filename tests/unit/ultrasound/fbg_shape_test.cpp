// FBG catheter shape (Heunis et al. 2021, §2.2 and §3.3) and contacts (§3.3): the frame
// codec, reconstruction from a SIMULATED interrogator, Eq. 2, curvature warnings, wall contacts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <random>
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

// Shape from strain: a constant-curvature arc R = 100 mm, 270 mm, noise-free → max error < 0.05 mm; a 3-D
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

// Shape from strain with 1 µε-equivalent wavelength noise (1.2 pm): mean ≤ 0.82 mm, max ≤ 1.52 mm over 200
// frames.
TEST(FbgShapeReconstructor, StaysInsideTheArticlesEnvelopeWithOneMicrostrainOfNoise) {
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

// Eq. 2 transform: Eq. 2 round-trips a known shape and base pose to 1e-9.
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

// A planar curve with smoothly varying curvature κ(s) = amplitude·sin(π s / length), bending in the
// plane at `plane` rad about z, every 0.1 mm.
std::vector<Vector3d> mold_channel(double amplitude, double plane, double length = 271.0) {
  std::vector<Vector3d> points;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Vector3d p = Vector3d::Zero();
  const Vector3d axis(-std::sin(plane), std::cos(plane), 0.0);  // bends towards (cos, sin, 0)
  const double ds = 0.05;
  for (int k = 0; k <= static_cast<int>(length / ds); ++k) {
    if (k % 2 == 0) points.push_back(p);
    const double angle = amplitude * std::sin(3.14159265358979 * k * ds / length) * ds;
    R = R * Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    p += R.col(2) * ds;
  }
  return points;
}

// Mold calibration: H_F^C from a curved channel II with 0.3 mm noise on its points, then Eq. 2
// validated on channel III (another bend plane): the article's 0.82 ± 0.21 mm, max 1.52 mm envelope.
TEST(MoldCalibration, RecoversTheFibreInTheBaseAndValidatesOnAnotherChannel) {
  const MulticoreFiber fiber;
  SimulatedFbgInterrogator interrogator(fiber, 1.2, 5);
  FbgShapeReconstructor reconstructor(fiber, interrogator.reference());
  Eigen::Isometry3d fiber_in_base = Eigen::Isometry3d::Identity();
  fiber_in_base.linear() = Eigen::AngleAxisd(0.4, Vector3d(0.3, 1.0, 0.2).normalized()).toRotationMatrix();
  fiber_in_base.translation() = Vector3d(2.0, -3.0, 15.0);
  // Channel II: its design centerline in {C}, sampled at the gratings, each sample with 0.3 mm of noise.
  const std::vector<Vector3d> channel2_line = mold_channel(0.012, 0.3);
  const FiberTruth channel2 = fiber_truth(fiber, channel2_line);
  std::vector<Vector3d> channel2_dense;
  for (const auto& p : channel2_line)
    channel2_dense.push_back(fiber_in_base * (channel2.fiber_pose.inverse() * p));
  std::vector<Vector3d> channel2_in_base =
      sample_at_arc_lengths(channel2_dense, fiber.grating_spacing, fiber.gratings);
  std::mt19937 engine(4);
  std::normal_distribution<double> noise(0.0, 0.3 / std::sqrt(3.0));
  for (auto& p : channel2_in_base) p += Vector3d(noise(engine), noise(engine), noise(engine));
  // The catheter rests in the mold: 50 interrogator frames are averaged (1 µε each), as a static
  // recording allows; a single frame's noise tilts the fit by ~0.2°.
  FbgFrame averaged = interrogator.measure(channel2, 0.0, 0);
  for (int k = 1; k < 50; ++k) {
    const FbgFrame frame = interrogator.measure(channel2, 0.0, static_cast<std::uint64_t>(k));
    for (std::size_t i = 0; i < averaged.wavelengths.size(); ++i)
      averaged.wavelengths[i] += frame.wavelengths[i];
  }
  for (double& w : averaged.wavelengths) w /= 50.0;
  const FbgShape& shape2 = reconstructor.reconstruct(averaged);
  ASSERT_EQ(shape2.status, FbgShapeStatus::ok);
  const FiberCalibration calibration = calibrate_fiber_in_base(shape2.points, channel2_in_base);
  const Eigen::Isometry3d error = calibration.fiber_in_base.inverse() * fiber_in_base;
  const double angle = Eigen::AngleAxisd(error.linear()).angle() * 180.0 / 3.14159265358979;
  // The error where it matters: at the gratings (a rotation error moves the far ones most).
  double worst_point = 0.0;
  for (const auto& p : channel2.points)
    worst_point = std::max(worst_point, (calibration.fiber_in_base * p - fiber_in_base * p).norm());
  // Channel III in {G}: the catheter base tracked at H_C^G, the channel bending in another plane.
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  base.linear() = Eigen::AngleAxisd(-0.8, Vector3d(1.0, 0.0, 1.0).normalized()).toRotationMatrix();
  base.translation() = Vector3d(300.0, 50.0, -20.0);
  const std::vector<Vector3d> channel3 = mold_channel(0.015, 2.0);
  const FiberTruth truth3 = fiber_truth(fiber, channel3);
  std::vector<Vector3d> channel3_in_global;
  for (const auto& p : channel3)
    channel3_in_global.push_back(base * fiber_in_base * truth3.fiber_pose.inverse() * p);
  std::vector<Vector3d> global;
  fbg_to_global(base, calibration.fiber_in_base,
                reconstructor.reconstruct(interrogator.measure(truth3, 0.0, 2)).points, global);
  const ChannelValidation v = validate_on_channel(global, channel3_in_global);
  std::printf(
      "mold calibration: rms %.3f mm, H_F^C off by %.3f mm / %.3f deg (%.3f mm at the worst grating); "
      "channel III %.3f +- %.3f mm, max %.3f mm\n",
      calibration.rms, error.translation().norm(), angle, worst_point, v.mean, v.standard_deviation, v.max);
  EXPECT_LT(error.translation().norm(), 0.2);  // mold calibration
  EXPECT_LT(angle, 0.2);
  EXPECT_LE(v.mean, 0.82);
  EXPECT_LE(v.max, 1.52);
  // A straight channel leaves the roll free: refused.
  std::vector<Vector3d> straight;
  for (int g = 0; g < 32; ++g) straight.emplace_back(0.0, 0.0, fiber.grating_spacing * g);
  EXPECT_THROW(calibrate_fiber_in_base(shape2.points, straight), std::invalid_argument);
  EXPECT_THROW(calibrate_fiber_in_base(shape2.points, {Vector3d::Zero(), Vector3d::UnitZ()}),
               std::invalid_argument);
  EXPECT_THROW(sample_at_arc_lengths(straight, fiber.grating_spacing, 40),
               std::invalid_argument);  // too short
}

// Contact flagging: a straight catheter, tilted in a 10 mm tube (a mesh of 120 sides), is flagged exactly
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
