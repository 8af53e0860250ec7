// The us_arm's "us" and "catheter" calibrations (Heunis et al. 2021, §2.2–2.3); see the header.
#include "serial_arm/ultrasound_calibrations.hpp"

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

namespace tendril::server {
namespace {

constexpr double kDegree = 3.14159265358979323846 / 180.0;

std::string mm(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", v);
  return buf;
}

}  // namespace

UltrasoundCalibrationSimulation UltrasoundCalibrationSimulation::standard() {
  UltrasoundCalibrationSimulation s;
  s.true_image = ultrasound::ImageCalibration::nominal(s.geometry);
  s.true_image.image_in_probe.linear() =
      Eigen::AngleAxisd(1.0 * kDegree, Eigen::Vector3d(1.0, 0.4, -0.3).normalized()).toRotationMatrix();
  s.true_image.image_in_probe.translation() =
      Eigen::Vector3d(0.0, 0.0, 0.5) + 0.8 * Eigen::Vector3d(0.5, -0.7, 0.5).normalized();
  s.true_image.s_u = 0.127;
  s.true_image.s_v = 0.123;
  // The phantom's top beside the limb, its z (depth) pointing down like the probe's on the skin.
  s.phantom_in_base.linear() =
      Eigen::AngleAxisd(3.14159265358979323846, Eigen::Vector3d::UnitX()).toRotationMatrix();
  s.phantom_in_base.translation() = Eigen::Vector3d(-610.0, 190.0, 200.0);
  s.mold.mold_in_world.translation() = Eigen::Vector3d(-400.0, 300.0, 120.0);
  // The fibre 1° and 0.9 mm off its design place in the base (the reconstruction's uncalibrated H_F^C is
  // the identity): about 5 mm at the tip of its 270 mm until calibrated.
  s.mold.simulated_true_fiber_in_base.linear() =
      Eigen::AngleAxisd(1.0 * kDegree, Eigen::Vector3d(1.0, 1.0, 0.0).normalized()).toRotationMatrix();
  s.mold.simulated_true_fiber_in_base.translation() = Eigen::Vector3d(0.6, -0.5, 0.5);
  s.mold.seed = 23;
  return s;
}

UltrasoundCalibrations::UltrasoundCalibrations(std::string robot, CalibrationRunner& runner,
                                               UltrasoundCalibrationSimulation simulation,
                                               ProbeBusy probe_busy)
    : robot_(std::move(robot)),
      runner_(runner),
      simulation_(std::move(simulation)),
      probe_busy_(std::move(probe_busy)) {
  simulation_.true_image.validate();
  simulation_.phantom.validate();
  runner_.add(
      {"us", "image-to-probe: H_I^U and the pixel scales s_u, s_v (Heunis et al. 2021, §2.3), N-wire phantom",
       "POST /api/v1/robots/" + robot_ + "/calibrate {\"kind\":\"us\"}", true},
      [this](const OperatingStateView& state) { return start(state, true); });
  runner_.add({"catheter",
               "catheter mold: H_F^C of the FBG fibre in the catheter base (Heunis et al. 2021, §2.2–2.3), "
               "validated on channel III",
               "POST /api/v1/robots/" + robot_ + "/calibrate {\"kind\":\"catheter\"}", false},
              [this](const OperatingStateView& state) { return start(state, false); });
}

UltrasoundCalibrations::~UltrasoundCalibrations() {
  stopping_.store(true);
  std::lock_guard lock(worker_mutex_);
  if (worker_.joinable()) worker_.join();
}

std::optional<std::string> UltrasoundCalibrations::start(const OperatingStateView& /*state*/, bool image) {
  if (image && probe_busy_) {
    if (auto why = probe_busy_()) return why;
  }
  std::lock_guard lock(worker_mutex_);
  if (worker_.joinable()) worker_.join();  // the previous routine has finished (the runner allows one)
  const std::uint64_t run = ++runs_;
  worker_ = std::thread([this, image, run] {
    if (image)
      run_image_calibration(run);
    else
      run_mold_calibration(run);
  });
  return std::nullopt;
}

void UltrasoundCalibrations::run_image_calibration(std::uint64_t run) {
  const auto& sim = simulation_;
  try {
    const ultrasound::SimulatedNWireScanner scanner(sim.phantom, sim.geometry, sim.true_image);
    // Where the arm would hold the probe (its forward kinematics) and where the probe truly is.
    std::mt19937_64 engine(sim.seed * 1009 + run);
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::vector<ultrasound::CalibrationShot> shots;
    for (const Eigen::Isometry3d& pose :
         ultrasound::n_wire_calibration_poses(sim.phantom_in_base, sim.poses)) {
      Eigen::Vector3d direction(gauss(engine), gauss(engine), gauss(engine));
      Eigen::Isometry3d error = Eigen::Isometry3d::Identity();
      error.translation() =
          std::max(0.0, sim.robot_error_mm + sim.robot_error_sd_mm * gauss(engine)) * direction.normalized();
      const Eigen::Vector3d w(sim.robot_angle_sd_rad * gauss(engine), sim.robot_angle_sd_rad * gauss(engine),
                              sim.robot_angle_sd_rad * gauss(engine));
      if (w.norm() > 0.0) error.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
      shots.push_back({pose, pose * error});
    }
    const ultrasound::ImageCalibration nominal = ultrasound::ImageCalibration::nominal(sim.geometry);
    const ultrasound::ImageCalibrationRun result = ultrasound::run_n_wire_calibration(
        scanner, sim.phantom_in_base, shots, nominal, sim.seed + run, [this](int done, int images) {
          runner_.progress(
              done, images + 1,
              "imaging the N-wire phantom: image " + std::to_string(done) + " of " + std::to_string(images));
          return !stopping_.load();
        });
    runner_.progress(sim.poses + 1, sim.poses + 1, "fitted; saving");
    const ultrasound::ImageCalibration& c = result.fit.calibration;
    const Eigen::Isometry3d off = c.image_in_probe.inverse() * sim.true_image.image_in_probe;
    CalibrationRecord record;
    record.kind = "us";
    record.robot = robot_;
    record.method =
        "N-wire phantom (3 layers, the middle echo placed by its ratio along the diagonal), linear least "
        "squares "
        "then Gauss–Newton over H_I^U, s_u, s_v; validated by the point reconstruction error on every 4th "
        "image (not fitted); SIMULATED scanner, phantom and probe poses";
    record.transforms["H_I^U"] = c.image_in_probe;
    record.values["s_u_mm_per_px"] = c.s_u;
    record.values["s_v_mm_per_px"] = c.s_v;
    record.residual_mm = result.validation.mean_mm;
    record.residuals = {{"fit_rms_mm", result.fit.rms_mm},
                        {"fit_max_mm", result.fit.max_mm},
                        {"validation_mean_mm", result.validation.mean_mm},
                        {"validation_max_mm", result.validation.max_mm},
                        {"validation_points", result.validation.points},
                        {"fiducials", result.fit.points},
                        {"images", result.images},
                        {"images_used", result.images_used},
                        {"images_validation", result.images_validation},
                        {"simulated_error_mm", off.translation().norm()},
                        {"simulated_error_deg", Eigen::AngleAxisd(off.linear()).angle() / kDegree},
                        {"notes", result.notes}};
    // Image-to-probe calibration: a phantom point reprojects to < 0.5 mm (here: points of images the fit did
    // not see).
    record.valid = result.validation.points > 0 && result.validation.mean_mm < 0.5;
    record.summary =
        "H_I^U and s_u " + mm(c.s_u) + ", s_v " + mm(c.s_v) + " mm/px from " +
        std::to_string(result.fit.points) + " fiducials in " + std::to_string(result.fit.images) +
        " images (rms " + mm(result.fit.rms_mm) + " mm); held-out points reconstruct to " +
        mm(result.validation.mean_mm) + " mm mean, " + mm(result.validation.max_mm) + " max (" +
        (record.valid ? "valid: under 0.5 mm" : "NOT valid: 0.5 mm or more; the previous one stays") + ")";
    const CalibrationRecord saved = runner_.store().save(record);
    runner_.finish(saved.valid, saved.version, saved.summary);
  } catch (const std::exception& error) {
    runner_.finish(false, 0, std::string("the image calibration failed: ") + error.what());
  }
}

void UltrasoundCalibrations::run_mold_calibration(std::uint64_t run) {
  try {
    runner_.progress(1, 2, "reading the FBG fibre in mold channels I, II and III");
    ultrasound::SimulatedMold mold = simulation_.mold;
    mold.seed += run;
    const ultrasound::MulticoreFiber fiber;
    const ultrasound::MoldCalibrationResult r =
        ultrasound::run_mold_calibration(fiber, ultrasound::MoldDesign::standard(fiber), mold);
    runner_.progress(2, 2, "fitted; saving");
    CalibrationRecord record;
    record.kind = "catheter";
    record.robot = robot_;
    record.method =
        "mold: channel I straight reference, channel II Kabsch fit of the FBG shape to the channel's design "
        "points in {C} (tracked H_M^G, H_C^G), channel III point-to-centerline validation (Eq. 2); SIMULATED "
        "mold, tracker and interrogator";
    record.transforms["H_F^C"] = r.fit.fiber_in_base;
    record.residual_mm = r.channel_iii.mean;
    record.residuals = {{"channel_ii_rms_mm", r.fit.rms},
                        {"channel_ii_max_mm", r.fit.max},
                        {"channel_iii_mean_mm", r.channel_iii.mean},
                        {"channel_iii_sd_mm", r.channel_iii.standard_deviation},
                        {"channel_iii_max_mm", r.channel_iii.max},
                        {"accept_mean_mm", ultrasound::kMoldValidationMeanMm},
                        {"accept_max_mm", ultrasound::kMoldValidationMaxMm},
                        {"simulated_error_mm", r.simulated_error_mm},
                        {"simulated_error_deg", r.simulated_error_deg}};
    record.valid = r.valid;
    record.summary = r.summary;
    const CalibrationRecord saved = runner_.store().save(record);
    runner_.finish(saved.valid, saved.version, saved.summary);
  } catch (const std::exception& error) {
    runner_.finish(false, 0, std::string("the mold calibration failed: ") + error.what());
  }
}

std::optional<std::pair<int, ultrasound::ImageCalibration>> UltrasoundCalibrations::image_in_use() const {
  const std::optional<CalibrationRecord> record = runner_.store().current("us");
  if (!record) return std::nullopt;
  const auto transform = record->transforms.find("H_I^U");
  const auto s_u = record->values.find("s_u_mm_per_px");
  const auto s_v = record->values.find("s_v_mm_per_px");
  if (transform == record->transforms.end() || s_u == record->values.end() || s_v == record->values.end())
    return std::nullopt;  // a file without them is not an image calibration
  ultrasound::ImageCalibration c;
  c.image_in_probe = transform->second;
  c.s_u = s_u->second;
  c.s_v = s_v->second;
  return std::make_pair(record->version, c);
}

std::optional<std::pair<int, Eigen::Isometry3d>> UltrasoundCalibrations::fiber_in_use() const {
  const std::optional<CalibrationRecord> record = runner_.store().current("catheter");
  if (!record) return std::nullopt;
  const auto transform = record->transforms.find("H_F^C");
  if (transform == record->transforms.end()) return std::nullopt;
  return std::make_pair(record->version, transform->second);
}

void use_ultrasound_calibrations(const UltrasoundCalibrations& calibrations,
                                 ultrasound::ReconstructionSessionConfig& session,
                                 UltrasoundTopicsSettings& settings) {
  session.simulated_true_image = calibrations.simulation().true_image;
  session.simulated_true_fiber_in_base = calibrations.simulation().mold.simulated_true_fiber_in_base;
  settings.image_calibration_reader = [&calibrations] { return calibrations.image_in_use(); };
  settings.fiber_calibration_reader = [&calibrations] { return calibrations.fiber_in_use(); };
}

}  // namespace tendril::server
