// The us_arm's image-to-probe ("us", Heunis et al. 2021, §2.3) and catheter mold ("catheter", §2.2–2.3)
// calibrations as routines of the robot's CalibrationRunner (calibration_runner.hpp): POST …/calibrate
// {"kind": "us" | "catheter"} runs them, each result is saved as a new version in the robot's
// CalibrationStore and, when valid, becomes the one the ultrasound topics' reconstruction maps with
// (UltrasoundTopics reads image_in_use() / fiber_in_use() at each worker step).
//
// "us": the SIMULATED N-wire phantom (ultrasound/probe_calibration.hpp) at a fixed pose in the arm's
// base frame; the probe held over it at 24 poses; at each the SIMULATED scanner images through its TRUE
// H_I^U and pixel scales (0.8 mm and 1° off the nominal plane, s_u 0.127 and s_v 0.123 mm against the
// nominal 0.125 — our SIMULATED error, chosen about a speed-of-sound mismatch and a mounting tolerance)
// at the true probe pose (where the arm says it is ⊕ its positioning error, 0.3 ± 0.1 mm, Heunis et al. 2021,
// §4.3); echoes detected, each layer's M placed by the N-wire ratio, least squares over 18 images, the point
// reconstruction error on the other 6 the validation (valid below 0.5 mm). The arm does not
// move there yet: the poses are where it would hold the probe (a routine of the robot's motion, like
// the robot calibration's, is what is left).
// "catheter": the SIMULATED mold (ultrasound/mold_calibration.hpp): channel I the reference, channel II
// the fit, channel III the validation (valid within the article's 0.82 mm mean and 1.52 mm max); no arm
// motion. The fibre's true H_F^C is the simulation's; the reconstruction's catheter is imaged through it
// and mapped through the calibrated one.
//
// Threads: the routines run on a worker thread of this object (the "us" one takes seconds in a
// sanitized build), never on the control thread; start refusals come back on the caller's (network)
// thread.
#pragma once

#include <Eigen/Geometry>
#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "serial_arm/calibration_runner.hpp"
#include "serial_arm/ultrasound_topics.hpp"
#include "tendril/ultrasound/mold_calibration.hpp"
#include "tendril/ultrasound/probe_calibration.hpp"

namespace tendril::server {

struct UltrasoundCalibrationSimulation {
  ultrasound::BModeGeometry geometry{};     // the scanner's pixels (the session's)
  ultrasound::ImageCalibration true_image;  // where the SIMULATED scanner truly images
  ultrasound::NWirePhantom phantom{};       // its wires
  Eigen::Isometry3d phantom_in_base = Eigen::Isometry3d::Identity();  // {N} in the arm's base frame
  int poses = 24;
  double robot_error_mm = 0.3, robot_error_sd_mm = 0.1;  // Heunis et al. 2021, §4.3, per pose
  double robot_angle_sd_rad = 0.02 * 3.14159265358979323846 / 180.0;
  ultrasound::SimulatedMold mold;  // its pose, the fibre's true H_F^C, the tracker and interrogator noise
  std::uint64_t seed = 17;
  // The values above for the us_arm: the truth 0.8 mm / 1° / 1.6 % off the nominal image, the phantom
  // beside the limb (300 mm from it along the base's y), the fibre 0.9 mm and 1° off its design place.
  static UltrasoundCalibrationSimulation standard();
};

class UltrasoundCalibrations {
 public:
  // What the routines need of the robot: whether the sweep holds the probe (a sentence why "us" cannot
  // run now, else nullopt). Any thread but the control thread.
  using ProbeBusy = std::function<std::optional<std::string>()>;
  // Registers "us" (required by the sweep) and "catheter" with `runner` (and so with its store), for
  // the robot `robot`.
  UltrasoundCalibrations(std::string robot, CalibrationRunner& runner,
                         UltrasoundCalibrationSimulation simulation, ProbeBusy probe_busy = {});
  ~UltrasoundCalibrations();  // stops a running routine and joins the worker
  UltrasoundCalibrations(const UltrasoundCalibrations&) = delete;
  UltrasoundCalibrations& operator=(const UltrasoundCalibrations&) = delete;

  const UltrasoundCalibrationSimulation& simulation() const noexcept { return simulation_; }
  // The valid versions in use (the store's newest valid), nullopt before the first: what the
  // reconstruction maps with. Any thread but the control thread (the store locks).
  std::optional<std::pair<int, ultrasound::ImageCalibration>> image_in_use() const;
  std::optional<std::pair<int, Eigen::Isometry3d>> fiber_in_use() const;

  // The routines' bodies (worker thread; public for tests that run them synchronously).
  void run_image_calibration(std::uint64_t run);
  void run_mold_calibration(std::uint64_t run);

 private:
  std::optional<std::string> start(const OperatingStateView& state, bool image);

  std::string robot_;
  CalibrationRunner& runner_;
  UltrasoundCalibrationSimulation simulation_;
  ProbeBusy probe_busy_;
  std::mutex worker_mutex_;
  std::thread worker_;
  std::uint64_t runs_ = 0;
  std::atomic<bool> stopping_{false};
};

// Hooks the reconstruction up to the calibrations: the session's SIMULATED scanner and fibre get the
// true image plane and H_F^C, and the topics' worker reads the versions in use (`calibrations` must
// outlive the topics).
void use_ultrasound_calibrations(const UltrasoundCalibrations& calibrations,
                                 ultrasound::ReconstructionSessionConfig& session,
                                 UltrasoundTopicsSettings& settings);

}  // namespace tendril::server
