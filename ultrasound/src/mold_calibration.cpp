// The catheter's mold calibration with a SIMULATED mold (Heunis et al. 2021, §2.2–2.3); see the header.
#include "tendril/ultrasound/mold_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>

#include "tendril/ultrasound/bmode_image.hpp"             // UltrasoundSetupError
#include "tendril/ultrasound/reconstruction_session.hpp"  // is_rigid

namespace tendril::ultrasound {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A channel from `start` heading +z, bending with κ(s) = amplitude·sin(π s / length) in the plane at
// `plane` rad about z (towards (cos, sin, 0)), every 0.1 mm: curvature-continuous, as a milled channel.
std::vector<Eigen::Vector3d> channel(const Eigen::Vector3d& start, double amplitude, double plane,
                                     double length) {
  std::vector<Eigen::Vector3d> points;
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p = start;
  const Eigen::Vector3d axis(-std::sin(plane), std::cos(plane), 0.0);
  const double ds = 0.05;
  const int steps = static_cast<int>(length / ds);
  for (int k = 0; k <= steps; ++k) {
    if (k % 2 == 0) points.push_back(p);
    const double angle = amplitude * std::sin(kPi * k * ds / length) * ds;
    r = r * Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    p += r.col(2) * ds;
  }
  return points;
}

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

class Tracker {
 public:
  Tracker(const SimulatedMold& mold) : mold_(mold), engine_(mold.seed * 7919 + 3) {}
  // One static recording of a rigid body at `truth`.
  Eigen::Isometry3d record(const Eigen::Isometry3d& truth) {
    std::normal_distribution<double> gauss(0.0, 1.0);
    Eigen::Vector3d direction(gauss(engine_), gauss(engine_), gauss(engine_));
    if (direction.norm() < 1e-12) direction = Eigen::Vector3d::UnitX();
    const double magnitude = std::max(0.0, mold_.tracker_mm + mold_.tracker_sd_mm * gauss(engine_));
    const double a = mold_.tracker_angle_sd_rad;
    const Eigen::Vector3d w(a * gauss(engine_), a * gauss(engine_), a * gauss(engine_));
    Eigen::Isometry3d error = Eigen::Isometry3d::Identity();
    if (w.norm() > 0.0) error.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
    error.translation() = magnitude * direction.normalized();
    return truth * error;
  }

 private:
  const SimulatedMold& mold_;
  std::mt19937_64 engine_;
};

FbgFrame averaged(SimulatedFbgInterrogator& interrogator, const FiberTruth& truth, int frames,
                  std::uint64_t& sequence) {
  FbgFrame sum = interrogator.measure(truth, 0.0, ++sequence);
  for (int k = 1; k < frames; ++k) {
    const FbgFrame f = interrogator.measure(truth, 0.0, ++sequence);
    for (std::size_t i = 0; i < sum.wavelengths.size(); ++i) sum.wavelengths[i] += f.wavelengths[i];
  }
  for (double& w : sum.wavelengths) w /= frames;
  return sum;
}

}  // namespace

MoldDesign MoldDesign::standard(const MulticoreFiber& fiber) {
  const double length = fiber.length() + 1.0;
  MoldDesign d;
  d.channels[0] = channel({-20.0, 0.0, 0.0}, 0.0, 0.0, length);
  d.channels[1] = channel({0.0, 0.0, 0.0}, 0.012, 0.3, length);
  d.channels[2] = channel({20.0, 0.0, 0.0}, 0.015, 2.0, length);
  d.design_in_marker.translation() = Eigen::Vector3d(0.0, -40.0, -10.0);
  return d;
}

void MoldDesign::validate(const MulticoreFiber& fiber) const {
  if (!is_rigid(design_in_marker)) throw UltrasoundSetupError("mold: the design offset H_L^M is not rigid");
  for (std::size_t c = 0; c < 3; ++c) {
    try {
      (void)fiber_truth(fiber, channels[c]);
    } catch (const std::invalid_argument& e) {
      throw UltrasoundSetupError("mold: channel " +
                                 std::string(c == 0   ? "I"
                                             : c == 1 ? "II"
                                                      : "III") +
                                 " cannot hold the fibre: " + e.what());
    }
  }
}

MoldCalibrationResult run_mold_calibration(const MulticoreFiber& fiber, const MoldDesign& design,
                                           const SimulatedMold& mold) {
  fiber.validate();
  design.validate(fiber);
  if (!is_rigid(mold.mold_in_world) || !is_rigid(mold.simulated_true_fiber_in_base))
    throw UltrasoundSetupError("mold calibration: the simulated mold pose or fibre-in-base is not rigid");
  if (mold.frames < 1 || mold.frames > 10000)
    throw UltrasoundSetupError("mold calibration: 1..10000 interrogator frames per channel, got " +
                               std::to_string(mold.frames));
  for (const double v : {mold.tracker_mm, mold.tracker_sd_mm, mold.tracker_angle_sd_rad, mold.fbg_noise_pm}) {
    if (!std::isfinite(v) || v < 0.0)
      throw UltrasoundSetupError("mold calibration: a simulated error is negative or not finite");
  }
  SimulatedFbgInterrogator interrogator(fiber, mold.fbg_noise_pm, mold.seed);
  Tracker tracker(mold);
  std::uint64_t sequence = 0;
  std::array<FiberTruth, 3> truths;
  for (std::size_t c = 0; c < 3; ++c) truths[c] = fiber_truth(fiber, design.channels[c]);
  // Where the catheter base truly is with the fibre in channel c: the fibre's {F} at the channel's
  // entry, the base at (H_F^C)⁻¹ from it.
  const auto base_in_world = [&](std::size_t c) {
    return mold.mold_in_world * design.design_in_marker * truths[c].fiber_pose *
           mold.simulated_true_fiber_in_base.inverse();
  };
  // Channel I: the straight reference.
  const FbgFrame reference = averaged(interrogator, truths[0], mold.frames, sequence);
  FbgShapeReconstructor reconstructor(fiber, reference);
  // Channel II: the fit.
  const Eigen::Isometry3d mold_ii = tracker.record(mold.mold_in_world);
  const Eigen::Isometry3d base_ii = tracker.record(base_in_world(1));
  const FbgShape shape_ii =
      reconstructor.reconstruct(averaged(interrogator, truths[1], mold.frames, sequence));
  if (shape_ii.status != FbgShapeStatus::ok)
    throw UltrasoundSetupError(std::string("mold calibration: channel II's FBG frame was refused (") +
                               to_string(shape_ii.status) + ")");
  const Eigen::Isometry3d design_in_base = base_ii.inverse() * mold_ii * design.design_in_marker;
  std::vector<Eigen::Vector3d> dense;
  dense.reserve(design.channels[1].size());
  for (const auto& p : design.channels[1]) dense.push_back(design_in_base * p);
  MoldCalibrationResult result;
  result.fit = calibrate_fiber_in_base(shape_ii.points,
                                       sample_at_arc_lengths(dense, fiber.grating_spacing, fiber.gratings));
  // Channel III: Eq. 2 with the fit against the channel in {G}.
  const Eigen::Isometry3d mold_iii = tracker.record(mold.mold_in_world);
  const Eigen::Isometry3d base_iii = tracker.record(base_in_world(2));
  const FbgShape& shape_iii =
      reconstructor.reconstruct(averaged(interrogator, truths[2], mold.frames, sequence));
  if (shape_iii.status != FbgShapeStatus::ok)
    throw UltrasoundSetupError(std::string("mold calibration: channel III's FBG frame was refused (") +
                               to_string(shape_iii.status) + ")");
  std::vector<Eigen::Vector3d> global, channel_iii;
  fbg_to_global(base_iii, result.fit.fiber_in_base, shape_iii.points, global);
  for (const auto& p : design.channels[2]) channel_iii.push_back(mold_iii * design.design_in_marker * p);
  result.channel_iii = validate_on_channel(global, channel_iii);
  result.valid =
      result.channel_iii.mean <= kMoldValidationMeanMm && result.channel_iii.max <= kMoldValidationMaxMm;
  for (const auto& p : truths[1].points)
    result.simulated_error_mm =
        std::max(result.simulated_error_mm,
                 (result.fit.fiber_in_base * p - mold.simulated_true_fiber_in_base * p).norm());
  result.simulated_error_deg = Eigen::AngleAxisd((result.fit.fiber_in_base.linear().transpose() *
                                                  mold.simulated_true_fiber_in_base.linear()))
                                   .angle() *
                               180.0 / kPi;
  result.summary = "H_F^C fitted on channel II (rms " + number(result.fit.rms) + " mm over " +
                   std::to_string(fiber.gratings) + " gratings); channel III " +
                   number(result.channel_iii.mean) + " ± " + number(result.channel_iii.standard_deviation) +
                   " mm, max " + number(result.channel_iii.max) + " mm (accepted up to " +
                   number(kMoldValidationMeanMm) + " mean and " + number(kMoldValidationMaxMm) +
                   " max): " + (result.valid ? "valid" : "NOT valid, the previous calibration stays in use");
  return result;
}

}  // namespace tendril::ultrasound
