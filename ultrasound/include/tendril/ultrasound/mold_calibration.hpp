// The catheter's mold calibration of H_F^C (Heunis et al. 2021, §2.2–2.3) as a routine, with a SIMULATED
// mold: the fibre-Bragg-grating (FBG) catheter laid in turn into three channels of a mold whose centerlines
// are known in its design frame {L}; the mold's marker body {M} and the catheter base {C} tracked in {G}.
//   * channel I (straight): the interrogator's reference frame, zero strain ↔ straight (averaged frames);
//   * channel II (curved): the channel's design points mapped into {C} through the tracked H_M^G, the
//     design offset H_L^M and the tracked H_C^G, sampled at the gratings' arc lengths (grating 1 at the
//     channel's entry, where the base's known offset puts it), and fitted to the reconstructed shape
//     Φ_F by Kabsch (calibrate_fiber_in_base, fbg_shape.hpp) → H_F^C;
//   * channel III (curved in another plane): Eq. 2 with the new H_F^C and a fresh tracked H_C^G, each
//     grating's distance to the channel's centerline in {G}: mean, sd and max. The calibration is valid
//     when they are within the article's reported figures (mean ≤ 0.82 mm, max ≤ 1.52 mm, §4.2) [our
//     acceptance rule; the article gives the figures, not a rule].
// The simulation's truth: the fibre sits in the catheter base at `simulated_true_fiber_in_base`, which the
// routine does not see; it sees tracked poses (the tracker's error per static recording, Heunis et al. 2021,
// §4.3, and our 0.3 mm) and interrogator frames with their noise.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "tendril/ultrasound/bmode_image.hpp"  // UltrasoundSetupError
#include "tendril/ultrasound/fbg_shape.hpp"

namespace tendril::ultrasound {

struct MoldDesign {
  // Dense centerlines (≤ 1 mm segments, longer than the fibre) in {L}; index 0, 1, 2 = channels I, II, III.
  std::array<std::vector<Eigen::Vector3d>, 3> channels;
  Eigen::Isometry3d design_in_marker = Eigen::Isometry3d::Identity();  // H_L^M (the mold's drawing)
  // Three channels 20 mm apart in a 300 mm block: I straight, II bending in the block's plane, III
  // out of it (curvature up to 0.012 and 0.015 mm⁻¹, under the fibre's 1/50 mm⁻¹ limit).
  static MoldDesign standard(const MulticoreFiber& fiber);
  // Throws UltrasoundSetupError for a channel shorter than the fibre, segments over 1 mm, or a
  // non-rigid H_L^M.
  void validate(const MulticoreFiber& fiber) const;
};

struct SimulatedMold {
  Eigen::Isometry3d mold_in_world = Eigen::Isometry3d::Identity();                 // true H_M^G
  Eigen::Isometry3d simulated_true_fiber_in_base = Eigen::Isometry3d::Identity();  // true H_F^C
  // Tracker error of one static recording of a rigid body: a translation of N(mean, sd) mm in a random
  // direction and a rotation of angle_sd per axis. 0.3 mm is the article's "0.3 mm-equivalent" tracker
  // noise (our choice); the per-marker 0.56 mm of §4.3 is averaged by a rigid body's markers.
  double tracker_mm = 0.3, tracker_sd_mm = 0.08;
  double tracker_angle_sd_rad = 0.02 * 3.14159265358979323846 / 180.0;
  double fbg_noise_pm = 1.2;  // per frame (≈ 1 µε)
  int frames = 50;            // interrogator frames averaged per channel (the catheter lies still)
  std::uint64_t seed = 1;
};

struct MoldCalibrationResult {
  FiberCalibration fit;             // H_F^C and the channel-II residuals (rms, max at the gratings)
  ChannelValidation channel_iii;    // Eq. 2 against channel III's centerline in {G}
  bool valid = false;               // channel III within 0.82 mm mean and 1.52 mm max
  double simulated_error_mm = 0.0;  // SIMULATED: the fit's H_F^C vs the truth at the worst grating
  double simulated_error_deg = 0.0;
  std::string summary;  // a sentence for a person
};

inline constexpr double kMoldValidationMeanMm = 0.82;  // Heunis et al. 2021, §4.2
inline constexpr double kMoldValidationMaxMm = 1.52;

// Runs the three channels on the SIMULATED mold. Throws UltrasoundSetupError for a design or setup that
// cannot be simulated and std::invalid_argument (from the fit) when channel II cannot fix H_F^C.
MoldCalibrationResult run_mold_calibration(const MulticoreFiber& fiber, const MoldDesign& design,
                                           const SimulatedMold& mold);

}  // namespace tendril::ultrasound
