// The catheter's mold calibration as a routine (Heunis et al. 2021, §2.2–2.3) on the SIMULATED mold: channel
// I the reference, channel II the fit of H_F^C, channel III the validation against the article's 0.82 mm mean
// and 1.52 mm max, with the tracker's error per recording and the interrogator's noise.
#include <gtest/gtest.h>

#include <cstdio>

#include "tendril/ultrasound/mold_calibration.hpp"

namespace {

using namespace tendril::ultrasound;
using Eigen::Isometry3d;
using Eigen::Vector3d;

SimulatedMold simulated_mold(std::uint64_t seed) {
  SimulatedMold mold;
  mold.mold_in_world.linear() =
      Eigen::AngleAxisd(-0.7, Vector3d(0.2, 1.0, 0.1).normalized()).toRotationMatrix();
  mold.mold_in_world.translation() = Vector3d(-300.0, 250.0, 80.0);
  mold.simulated_true_fiber_in_base.linear() =
      Eigen::AngleAxisd(0.4, Vector3d(0.3, 1.0, 0.2).normalized()).toRotationMatrix();
  mold.simulated_true_fiber_in_base.translation() = Vector3d(2.0, -3.0, 15.0);
  mold.seed = seed;
  return mold;
}

TEST(MoldCalibrationRoutine, FitsOnChannelTwoAndValidatesOnChannelThree) {
  const MulticoreFiber fiber;
  const MoldDesign design = MoldDesign::standard(fiber);
  double worst_mean = 0.0, worst_max = 0.0, worst_error = 0.0;
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    const MoldCalibrationResult r = run_mold_calibration(fiber, design, simulated_mold(seed));
    std::printf("mold seed %llu: %s; H_F^C off %.3f mm at the worst grating, %.3f deg\n",
                static_cast<unsigned long long>(seed), r.summary.c_str(), r.simulated_error_mm,
                r.simulated_error_deg);
    EXPECT_TRUE(r.valid) << r.summary;
    worst_mean = std::max(worst_mean, r.channel_iii.mean);
    worst_max = std::max(worst_max, r.channel_iii.max);
    worst_error = std::max(worst_error, r.simulated_error_mm);
  }
  EXPECT_LE(worst_mean, kMoldValidationMeanMm);  // the article's figures (§4.2)
  EXPECT_LE(worst_max, kMoldValidationMaxMm);
  EXPECT_LT(worst_error, 1.5);  // two tracked poses of 0.3 mm each, turned over the fibre's 270 mm

  // Without tracker or interrogator error the routine recovers the truth.
  SimulatedMold exact = simulated_mold(1);
  exact.tracker_mm = exact.tracker_sd_mm = exact.tracker_angle_sd_rad = exact.fbg_noise_pm = 0.0;
  const MoldCalibrationResult r = run_mold_calibration(fiber, design, exact);
  EXPECT_LT(r.simulated_error_mm, 0.05);
  EXPECT_LT(r.channel_iii.mean, 0.05);
}

TEST(MoldCalibrationRoutine, AWrongMoldOrALooseTrackerIsReported) {
  const MulticoreFiber fiber;
  MoldDesign design = MoldDesign::standard(fiber);
  // A tracker 3 mm off per recording: the fit still runs, but channel III fails and says so.
  SimulatedMold loose = simulated_mold(2);
  loose.tracker_mm = 3.0;
  const MoldCalibrationResult r = run_mold_calibration(fiber, design, loose);
  EXPECT_FALSE(r.valid);
  EXPECT_NE(r.summary.find("NOT valid"), std::string::npos) << r.summary;
  // A straight channel II leaves the roll free: the fit refuses it.
  design.channels[1] = design.channels[0];
  EXPECT_THROW((void)run_mold_calibration(fiber, design, simulated_mold(1)), std::invalid_argument);
  // A channel shorter than the fibre cannot hold it.
  MoldDesign short_design = MoldDesign::standard(fiber);
  short_design.channels[2].resize(100);
  EXPECT_THROW((void)run_mold_calibration(fiber, short_design, simulated_mold(1)), UltrasoundSetupError);
}

}  // namespace
