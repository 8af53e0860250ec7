// Image-to-probe calibration (Heunis et al. 2021, §2.3) with the SIMULATED N-wire phantom: echo
// detection to sub-pixel, the least-squares solve against a known truth with noise, its refusals, and
// the whole routine validated on images it did not fit.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "tendril/ultrasound/probe_calibration.hpp"

namespace {

using namespace tendril::ultrasound;
using Eigen::Isometry3d;
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kDegree = 3.14159265358979323846 / 180.0;

// The SIMULATED scanner's truth: 0.8 mm and 1° off the nominal plane, and its scales 1.6 % off (a
// speed-of-sound mismatch stretches depth; the lateral pitch differs by the array's tolerance).
ImageCalibration true_calibration() {
  ImageCalibration c;
  c.image_in_probe = Isometry3d::Identity();
  c.image_in_probe.linear() =
      Eigen::AngleAxisd(1.0 * kDegree, Vector3d(1.0, 0.4, -0.3).normalized()).toRotationMatrix();
  c.image_in_probe.translation() = Vector3d(0.0, 0.0, 0.5) + 0.8 * Vector3d(0.5, -0.7, 0.5).normalized();
  c.s_u = 0.127;
  c.s_v = 0.123;
  return c;
}

// Largest distance between two calibrations' points over the image (a grid of pixels).
double largest_difference(const ImageCalibration& a, const ImageCalibration& b, const BModeGeometry& g) {
  double worst = 0.0;
  for (int c = 0; c < g.columns; c += 16)
    for (int r = 0; r < g.rows; r += 16)
      worst = std::max(worst, (a.in_probe(g, {c, r}) - b.in_probe(g, {c, r})).norm());
  return worst;
}

TEST(NWirePhantom, EchoesAreFoundToASubPixelAtTheTrueCrossings) {
  const BModeGeometry g;
  const SimulatedNWireScanner scanner(NWirePhantom{}, g, true_calibration());
  const Isometry3d pose = n_wire_calibration_poses(Isometry3d::Identity(), 5)[2];
  const std::vector<NWireCrossing> truth = scanner.crossings(pose);
  ASSERT_EQ(truth.size(), 3U);  // every layer in view
  const std::vector<EchoSpot> spots = detect_echo_spots(scanner.render(pose, 11));
  ASSERT_EQ(spots.size(), 9U);  // three wires per layer, no speckle peak taken for one
  double worst = 0.0;
  for (const auto& crossing : truth)
    for (const Vector2d& yz : crossing.in_image) {
      const Vector2d pixel(yz.x() / scanner.truth().s_u + g.centre_column(), yz.y() / scanner.truth().s_v);
      double nearest = 1e9;
      for (const auto& s : spots) nearest = std::min(nearest, (s.pixel - pixel).norm());
      worst = std::max(worst, nearest);
    }
  std::printf("echo detection: worst centroid %.3f px from the true crossing\n", worst);
  EXPECT_LT(worst, 0.5);  // sub-pixel: 0.06 mm at 0.125 mm per pixel

  // An empty bath has no echoes; a bad image is refused.
  const SimulatedNWireScanner far(NWirePhantom{}, g, true_calibration());
  Isometry3d away = pose;
  away.translation().x() += 100.0;  // off the wires' ends
  EXPECT_TRUE(detect_echo_spots(far.render(away, 3)).empty());
  BModeImage broken = scanner.render(pose, 1);
  broken.pixels.pop_back();
  EXPECT_THROW(detect_echo_spots(broken), UltrasoundSetupError);
}

TEST(ImageCalibrationSolve, RecoversTheTransformAndScalesFromNoisyFiducials) {
  const BModeGeometry g;
  const ImageCalibration truth = true_calibration();
  std::mt19937 engine(3);
  std::uniform_real_distribution<double> column(10.0, g.columns - 10.0), row(60.0, g.rows - 40.0);
  std::normal_distribution<double> noise(0.0, 0.15 / std::sqrt(3.0));  // 0.15 mm per point
  std::vector<PixelCorrespondence> points;
  for (int k = 0; k < 60; ++k) {
    PixelCorrespondence p;
    p.pixel = {column(engine), row(engine)};
    p.in_probe = truth.in_probe(g, p.pixel) + Vector3d(noise(engine), noise(engine), noise(engine));
    p.image = k / 3;
    points.push_back(p);
  }
  const ImageCalibrationFit fit = solve_image_calibration(points, g);
  const Isometry3d error = fit.calibration.image_in_probe.inverse() * truth.image_in_probe;
  const double angle = Eigen::AngleAxisd(error.linear()).angle() / kDegree;
  std::printf(
      "solve: rms %.3f mm, H_I^U off %.3f mm / %.3f deg, s_u %.5f s_v %.5f (true 0.127, 0.123), %d "
      "iterations\n",
      fit.rms_mm, error.translation().norm(), angle, fit.calibration.s_u, fit.calibration.s_v,
      fit.iterations);
  EXPECT_LT(largest_difference(fit.calibration, truth, g), 0.1);
  EXPECT_LT(angle, 0.2);
  EXPECT_NEAR(fit.calibration.s_u, 0.127, 0.001);
  EXPECT_NEAR(fit.calibration.s_v, 0.123, 0.001);
  EXPECT_NEAR(fit.rms_mm, 0.15, 0.05);
  EXPECT_EQ(fit.images, 20);

  // Noise-free, the solve is exact.
  std::vector<PixelCorrespondence> exact = points;
  for (auto& p : exact) p.in_probe = truth.in_probe(g, p.pixel);
  EXPECT_LT(largest_difference(solve_image_calibration(exact, g).calibration, truth, g), 1e-6);
}

TEST(ImageCalibrationSolve, RefusesDegenerateDataWithAReason) {
  const BModeGeometry g;
  const ImageCalibration truth = true_calibration();
  std::vector<PixelCorrespondence> line;
  for (int k = 0; k < 12; ++k) {
    PixelCorrespondence p;
    p.pixel = {40.0 + 20.0 * k, 100.0 + 20.0 * k};  // one line across the image
    p.in_probe = truth.in_probe(g, p.pixel);
    p.image = k % 4;
    line.push_back(p);
  }
  try {
    (void)solve_image_calibration(line, g);
    ADD_FAILURE() << "collinear fiducials were accepted";
  } catch (const ImageCalibrationError& e) {
    EXPECT_NE(std::string(e.what()).find("one line"), std::string::npos) << e.what();
  }
  std::vector<PixelCorrespondence> few(line.begin(), line.begin() + 4);
  EXPECT_THROW((void)solve_image_calibration(few, g), ImageCalibrationError);
  std::vector<PixelCorrespondence> one_image = line;
  for (auto& p : one_image) p.image = 0;
  EXPECT_THROW((void)solve_image_calibration(one_image, g), ImageCalibrationError);
  std::vector<PixelCorrespondence> bad = line;
  bad[3].in_probe.x() = std::nan("");
  EXPECT_THROW((void)solve_image_calibration(bad, g), ImageCalibrationError);
}

// Image-to-probe calibration end to end: 24 poses over the phantom, each with the robot's positioning error
// (Heunis et al. 2021, §4.3: 0.3 ± 0.1 mm, 0.02° per axis) between where the arm says the probe is and where
// it is; fit on 18 images, validate on the other 6.
TEST(NWireCalibration, RecoversTheTrueImagePlaneAndValidatesOnHeldOutImages) {
  const BModeGeometry g;
  const ImageCalibration truth = true_calibration(), nominal = ImageCalibration::nominal(g);
  const SimulatedNWireScanner scanner(NWirePhantom{}, g, truth);
  Isometry3d phantom = Isometry3d::Identity();
  phantom.linear() = Eigen::AngleAxisd(0.3, Vector3d::UnitZ()).toRotationMatrix() *
                     Eigen::AngleAxisd(3.14159265358979, Vector3d::UnitX()).toRotationMatrix();
  phantom.translation() = Vector3d(-450.0, 120.0, 160.0);
  std::mt19937 engine(9);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::vector<CalibrationShot> shots;
  for (const Isometry3d& pose : n_wire_calibration_poses(phantom, 24)) {
    Vector3d direction(gauss(engine), gauss(engine), gauss(engine));
    Isometry3d error = Isometry3d::Identity();
    error.translation() = std::max(0.0, 0.3 + 0.1 * gauss(engine)) * direction.normalized();
    error.linear() = (Eigen::AngleAxisd(0.02 * kDegree * gauss(engine), Vector3d::UnitX()) *
                      Eigen::AngleAxisd(0.02 * kDegree * gauss(engine), Vector3d::UnitY()) *
                      Eigen::AngleAxisd(0.02 * kDegree * gauss(engine), Vector3d::UnitZ()))
                         .toRotationMatrix();
    shots.push_back({pose, pose * error});
  }
  const ImageCalibrationRun run = run_n_wire_calibration(scanner, phantom, shots, nominal, 5);
  const Isometry3d error = run.fit.calibration.image_in_probe.inverse() * truth.image_in_probe;
  const double angle = Eigen::AngleAxisd(error.linear()).angle() / kDegree;
  const double nominal_off = largest_difference(nominal, truth, g);
  const double calibrated_off = largest_difference(run.fit.calibration, truth, g);
  std::printf(
      "N-wire routine: %d images (%d used, %d held out), %d fiducials in the fit, rms %.3f mm; "
      "held-out point reconstruction %.3f mm mean, %.3f max; H_I^U off %.3f mm / %.3f deg, s_u %.5f, "
      "s_v %.5f; over the image the nominal is up to %.3f mm off, the calibrated %.3f mm\n",
      run.images, run.images_used, run.images_validation, run.fit.points, run.fit.rms_mm,
      run.validation.mean_mm, run.validation.max_mm, error.translation().norm(), angle,
      run.fit.calibration.s_u, run.fit.calibration.s_v, nominal_off, calibrated_off);
  for (const auto& note : run.notes) std::printf("  %s\n", note.c_str());
  EXPECT_EQ(run.images, 24);
  EXPECT_GE(run.images_used, 22);
  EXPECT_GE(run.validation.points, 12);
  EXPECT_LT(run.validation.mean_mm,
            0.5);  // Image-to-probe calibration: a phantom point reprojects to < 0.5 mm
  EXPECT_LT(run.validation.max_mm, 1.0);
  EXPECT_GT(nominal_off, 1.0);     // the truth is really off the nominal
  EXPECT_LT(calibrated_off, 0.5);  // and the calibration finds it
  EXPECT_NEAR(run.fit.calibration.s_u, truth.s_u, 0.002);
  EXPECT_NEAR(run.fit.calibration.s_v, truth.s_v, 0.002);

  // The probe held away from the phantom: no fiducials, refused with a sentence.
  std::vector<CalibrationShot> away = shots;
  for (auto& s : away) {
    s.measured.translation().z() += 300.0;
    s.simulated_true.translation().z() += 300.0;
  }
  EXPECT_THROW((void)run_n_wire_calibration(scanner, phantom, away, nominal, 5), ImageCalibrationError);
}

}  // namespace
