// One ultrasound reconstruction session (Heunis et al. 2021, issue 17); see the header.
#include "tendril/ultrasound/reconstruction_session.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <utility>

namespace tendril::ultrasound {

namespace {

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

SessionOutcome refuse(SessionStatus status, std::string message) {
  SessionOutcome o;
  o.status = status;
  o.message = std::move(message);
  return o;
}

}  // namespace

const char* to_string(SessionStatus status) noexcept {
  switch (status) {
    case SessionStatus::ok:
      return "ok";
    case SessionStatus::no_contact:
      return "no_contact";
    case SessionStatus::invalid_pose:
      return "invalid_pose";
    case SessionStatus::invalid_image:
      return "invalid_image";
    case SessionStatus::no_vessel:
      return "no_vessel";
  }
  return "unknown";
}

bool is_rigid(const Eigen::Isometry3d& pose) noexcept {
  if (!pose.matrix().allFinite()) return false;
  const Eigen::Matrix3d r = pose.linear();
  return (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-6 &&
         std::abs(r.determinant() - 1.0) < 1e-6;
}

namespace {
// The B-mode simulation's parameters with the scanner's true pixel scales.
SimulatedBModeParameters true_scanner(const ReconstructionSessionConfig& config) {
  SimulatedBModeParameters p = config.bmode;
  if (config.simulated_true_image) {
    p.lateral_scale = config.simulated_true_image->s_u / config.geometry.pixel_size;
    p.axial_scale = config.simulated_true_image->s_v / config.geometry.pixel_size;
  }
  return p;
}
}  // namespace

UltrasoundReconstructionSession::UltrasoundReconstructionSession(ReconstructionSessionConfig config)
    : config_(std::move(config)),
      scanner_(config_.artery, config_.geometry, true_scanner(config_)),
      segmenter_(config_.geometry, config_.ekf),
      engine_(config_.errors.seed) {
  if (!is_rigid(config_.image_in_probe))
    throw UltrasoundSetupError("ultrasound session: the image-to-probe transform H_I^U is not rigid");
  if (!is_rigid(config_.fiber_in_base) ||
      (config_.simulated_true_fiber_in_base && !is_rigid(*config_.simulated_true_fiber_in_base)))
    throw UltrasoundSetupError("ultrasound session: the fibre-to-catheter-base transform H_F^C is not rigid");
  if (config_.simulated_true_image) config_.simulated_true_image->validate();
  image_calibration().validate();
  const auto& e = config_.errors;
  for (double v : {e.robot_mm, e.robot_sd_mm, e.tracker_mm, e.tracker_sd_mm, e.angle_sd_rad}) {
    if (!std::isfinite(v) || v < 0.0)
      throw UltrasoundSetupError(
          "ultrasound session: a simulated measurement error is negative or not finite (" + number(v) + ")");
  }
  if (!config_.catheter_path.empty()) {
    if (!std::isfinite(config_.fbg_noise_pm) || config_.fbg_noise_pm < 0.0)
      throw UltrasoundSetupError("ultrasound session: the FBG noise must be ≥ 0 pm, got " +
                                 number(config_.fbg_noise_pm));
    try {
      config_.fiber.validate();
      catheter_truth_ = fiber_truth(config_.fiber, config_.catheter_path);
    } catch (const std::invalid_argument& error) {
      throw UltrasoundSetupError(std::string("ultrasound session: the catheter cannot be simulated: ") +
                                 error.what());
    }
    interrogator_ = std::make_unique<SimulatedFbgInterrogator>(config_.fiber, config_.fbg_noise_pm,
                                                               config_.errors.seed + 7);
    reconstructor_ = std::make_unique<FbgShapeReconstructor>(config_.fiber, interrogator_->reference());
  }
}

void UltrasoundReconstructionSession::set_plan(SweepPlan plan) {
  check_plan(plan);
  plan_ = std::move(plan);
  for (auto& s : slices_) {
    const auto i = static_cast<std::size_t>(s.via_point);
    s.centroid_error = i < plan_.centroids.size() ? (s.slice.centroid - plan_.centroids[i]).norm() : -1.0;
  }
  ++revision_;
}

void UltrasoundReconstructionSession::check_plan(const SweepPlan& plan) {
  auto finite = [](const std::vector<Eigen::Vector3d>& points) {
    return std::all_of(points.begin(), points.end(), [](const Eigen::Vector3d& p) { return p.allFinite(); });
  };
  if (!finite(plan.surface) || !finite(plan.centroids))
    throw PlanningInputError(
        "ultrasound session: the plan has a surface point or centroid that is not finite");
  for (const auto& v : plan.via_points) {
    if (!v.surface_point.allFinite() || !is_rigid(v.pose()))
      throw PlanningInputError(
          "ultrasound session: the plan has a via-point pose that is not finite or not rigid");
  }
  if (!plan.via_points.empty() && plan.via_points.size() != plan.centroids.size())
    throw PlanningInputError("ultrasound session: the plan has " + std::to_string(plan.via_points.size()) +
                             " via-points for " + std::to_string(plan.centroids.size()) +
                             " centroids (one each expected)");
}

Eigen::Isometry3d UltrasoundReconstructionSession::perturbed(const Eigen::Isometry3d& pose, double mean,
                                                             double sd) {
  // A random rigid error: a translation of magnitude N(mean, sd) in a random direction and a rotation
  // of angle_sd per axis (the digital twin's error model).
  std::normal_distribution<double> gauss(0.0, 1.0);
  Eigen::Vector3d direction(gauss(engine_), gauss(engine_), gauss(engine_));
  if (direction.norm() < 1e-12) direction = Eigen::Vector3d::UnitX();
  direction.normalize();
  const double magnitude = std::max(0.0, mean + sd * gauss(engine_));
  const double a = config_.errors.angle_sd_rad;
  const Eigen::Vector3d w(a * gauss(engine_), a * gauss(engine_), a * gauss(engine_));
  Eigen::Isometry3d error = Eigen::Isometry3d::Identity();
  if (w.norm() > 0.0) error.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix();
  error.translation() = magnitude * direction;
  return pose * error;
}

namespace {
bool sample_is_valid(const ProbeSample& s) noexcept {
  return is_rigid(s.world_T_probe) && is_rigid(s.world_T_limb) &&
         (!s.world_T_limb_true || is_rigid(*s.world_T_limb_true)) && std::isfinite(s.t);
}
}  // namespace

SessionOutcome UltrasoundReconstructionSession::process(const ProbeSample& sample) {
  if (!sample_is_valid(sample))
    return refuse(SessionStatus::invalid_pose,
                  "the probe sample was refused: its probe or limb pose (or time) is not finite, or a "
                  "rotation is not orthonormal; nothing reconstructed was changed");
  if (!sample.in_contact)
    return refuse(SessionStatus::no_contact, "the probe is not in contact with the skin: no image");
  Eigen::Isometry3d probe_true = sample.world_T_probe, limb_measured = sample.world_T_limb;
  if (config_.errors.enabled) {
    probe_true = perturbed(sample.world_T_probe, config_.errors.robot_mm, config_.errors.robot_sd_mm);
    limb_measured = perturbed(sample.world_T_limb, config_.errors.tracker_mm, config_.errors.tracker_sd_mm);
  }
  const Eigen::Isometry3d& true_image_in_probe =
      config_.simulated_true_image ? config_.simulated_true_image->image_in_probe : config_.image_in_probe;
  const Eigen::Isometry3d image_true =
      sample.world_T_limb_true.value_or(sample.world_T_limb).inverse() * probe_true * true_image_in_probe;
  const Eigen::Isometry3d image_measured =
      limb_measured.inverse() * sample.world_T_probe * config_.image_in_probe;
  const BModeImage image = scanner_.render(image_true, config_.errors.seed * 1'000'003ULL + image_count_++);
  return segment_and_store(sample, image, image_measured, image_true);
}

SessionOutcome UltrasoundReconstructionSession::process(const ProbeSample& sample, const BModeImage& image) {
  if (!sample_is_valid(sample))
    return refuse(SessionStatus::invalid_pose,
                  "the probe sample was refused: its probe or limb pose (or time) is not finite, or a "
                  "rotation is not orthonormal; nothing reconstructed was changed");
  const BModeGeometry& g = config_.geometry;
  if (image.pixels.empty())
    return refuse(SessionStatus::invalid_image, "the ultrasound image was refused: it has no pixels");
  if (image.geometry.columns != g.columns || image.geometry.rows != g.rows ||
      image.geometry.pixel_size != g.pixel_size || image.pixels.size() != g.pixel_count())
    return refuse(SessionStatus::invalid_image,
                  "the ultrasound image was refused: it is " + std::to_string(image.geometry.columns) +
                      " × " + std::to_string(image.geometry.rows) + " pixels of " +
                      number(image.geometry.pixel_size) + " mm with " + std::to_string(image.pixels.size()) +
                      " values, the session expects " + std::to_string(g.columns) + " × " +
                      std::to_string(g.rows) + " of " + number(g.pixel_size) + " mm");
  if (!std::all_of(image.pixels.begin(), image.pixels.end(), [](float v) { return std::isfinite(v); }))
    return refuse(SessionStatus::invalid_image, "the ultrasound image was refused: a pixel is not finite");
  if (!sample.in_contact)
    return refuse(SessionStatus::no_contact, "the probe is not in contact with the skin: no image");
  // An image from outside comes with measured poses: mapped as given.
  const Eigen::Isometry3d image_pose =
      sample.world_T_limb.inverse() * sample.world_T_probe * config_.image_in_probe;
  return segment_and_store(sample, image, image_pose, image_pose);
}

Eigen::Vector2d UltrasoundReconstructionSession::seed_for(const ProbeSample& sample,
                                                          const Eigen::Isometry3d& tissue_T_image) const {
  const BModeGeometry& g = config_.geometry;
  auto inside = [&](const Eigen::Vector2d& yz) {
    return std::abs(yz.x()) < 0.5 * g.width() && yz.y() > 0.0 && yz.y() < g.depth();
  };
  // The EKF starts from the planned centroid of this via-point projected into the image through the measured
  // chain.
  const auto i = static_cast<std::size_t>(sample.via_point);
  if (sample.via_point >= 0 && i < plan_.centroids.size()) {
    const Eigen::Vector3d p = tissue_T_image.inverse() * plan_.centroids[i];
    // Calibrated {I} → the segmenter's millimetres of the geometry's pixel size.
    Eigen::Vector2d yz(p.y() / scale_u(), p.z() / scale_v());
    if (inside(yz)) return yz;
  }
  // Between via-points (or without a plan): follow the last contour's centre; else the image's middle.
  if (frame_ && frame_->segmentation.valid && inside(frame_->segmentation.centre))
    return frame_->segmentation.centre;
  return {0.0, 0.5 * g.depth()};
}

SessionOutcome UltrasoundReconstructionSession::segment_and_store(
    const ProbeSample& sample, const BModeImage& image, const Eigen::Isometry3d& tissue_T_image,
    const Eigen::Isometry3d& tissue_T_image_true) {
  const Eigen::Vector2d seed = seed_for(sample, tissue_T_image);
  const SliceSegmentation& result = segmenter_.segment(image, seed);
  SessionFrame frame;
  frame.t = sample.t;
  frame.image = image;
  frame.segmentation = result;
  frame.tissue_T_image = tissue_T_image;
  frame.world_T_image = sample.world_T_limb * tissue_T_image;
  frame.simulated_true_tissue_T_image = tissue_T_image_true;
  frame.via_point = sample.via_point;
  frame_ = std::move(frame);
  if (!result.valid) return refuse(SessionStatus::no_vessel, "no artery boundary was found in this slice");
  SessionOutcome outcome;
  if (!sample.acquiring || sample.via_point < 0) return outcome;
  const auto at = std::lower_bound(slices_.begin(), slices_.end(), sample.via_point,
                                   [](const StoredSlice& s, int v) { return s.via_point < v; });
  if (at != slices_.end() && at->via_point == sample.via_point) return outcome;  // one slice per via-point
  StoredSlice stored;
  stored.via_point = sample.via_point;
  stored.t = sample.t;
  stored.slice = map_slice(calibrated(result), tissue_T_image);  // Eq. 5 with the calibrated s_u, s_v
  stored.tissue_T_image = tissue_T_image;
  segmenter_.lumen_mask(result, stored.mask);
  const auto i = static_cast<std::size_t>(sample.via_point);
  if (i < plan_.centroids.size()) stored.centroid_error = (stored.slice.centroid - plan_.centroids[i]).norm();
  slices_.insert(at, std::move(stored));
  if (slices_.size() >= 2) {
    std::vector<ReconstructedSlice> contours;
    contours.reserve(slices_.size());
    for (const auto& s : slices_) contours.push_back(s.slice);
    mesh_ = loft_artery_mesh(contours);
  }
  ++revision_;
  outcome.stored_slice = true;
  if (!result.converged)
    outcome.message = "slice stored, but the contour's centre still moved " + number(result.final_shift) +
                      " mm in the last star iteration";
  return outcome;
}

SessionOutcome UltrasoundReconstructionSession::update_catheter(const ProbeSample& sample) {
  if (!is_rigid(sample.world_T_limb) || (sample.world_T_limb_true && !is_rigid(*sample.world_T_limb_true)) ||
      !std::isfinite(sample.t))
    return refuse(SessionStatus::invalid_pose,
                  "the catheter update was refused: the limb pose (or time) is not finite or not rigid; "
                  "the last catheter shape stays");
  if (!interrogator_) return {};
  // The catheter lies in the artery, so its base moves with the limb: H_C^G = H_P^G · H_F^P · (H_F^C)⁻¹;
  // the tracker sees the base and the limb with its error.
  const Eigen::Isometry3d limb_true = sample.world_T_limb_true.value_or(sample.world_T_limb);
  const Eigen::Isometry3d base_true =
      limb_true * catheter_truth_.fiber_pose *
      config_.simulated_true_fiber_in_base.value_or(config_.fiber_in_base).inverse();
  Eigen::Isometry3d base_measured = base_true, limb_measured = sample.world_T_limb;
  if (config_.errors.enabled) {
    base_measured = perturbed(base_true, config_.errors.tracker_mm, config_.errors.tracker_sd_mm);
    limb_measured = perturbed(sample.world_T_limb, config_.errors.tracker_mm, config_.errors.tracker_sd_mm);
  }
  const FbgShape& shape =
      reconstructor_->reconstruct(interrogator_->measure(catheter_truth_, 0.0, ++fbg_sequence_));
  if (shape.status != FbgShapeStatus::ok)
    return refuse(SessionStatus::invalid_image, std::string("the FBG frame was refused (") +
                                                    to_string(shape.status) +
                                                    "); the last catheter shape stays");
  CatheterState c;
  c.valid = true;
  c.t = sample.t;
  fbg_to_global(base_measured, config_.fiber_in_base, shape.points, c.world);  // Eq. 2
  const Eigen::Isometry3d world_to_tissue = limb_measured.inverse();
  c.tissue.reserve(c.world.size());
  for (const auto& p : c.world) c.tissue.push_back(world_to_tissue * p);
  c.simulated_true_world.reserve(catheter_truth_.points.size());
  for (const auto& p : catheter_truth_.points)
    c.simulated_true_world.push_back(limb_true * (catheter_truth_.fiber_pose * p));
  if (mesh_.triangles.empty()) {
    c.wall_distance.assign(c.tissue.size(), std::numeric_limits<double>::infinity());
  } else {
    find_contacts(mesh_, c.tissue, config_.contact, c.contacts, c.wall_distance);
  }
  for (std::size_t g = 0; g < shape.over_limit.size(); ++g)
    if (shape.over_limit[g]) c.over_curvature.push_back(static_cast<int>(g));
  c.max_curvature = shape.max_curvature;
  c.world_T_fbg = base_measured * config_.fiber_in_base;
  catheter_ = std::move(c);
  return {};
}

double UltrasoundReconstructionSession::scale_u() const noexcept {
  return config_.image_scale_u > 0.0 ? config_.image_scale_u / config_.geometry.pixel_size : 1.0;
}
double UltrasoundReconstructionSession::scale_v() const noexcept {
  return config_.image_scale_v > 0.0 ? config_.image_scale_v / config_.geometry.pixel_size : 1.0;
}

SliceSegmentation UltrasoundReconstructionSession::calibrated(const SliceSegmentation& segmentation) const {
  // The segmenter measures in the geometry's pixel size; the calibration says what a pixel really is.
  SliceSegmentation out = segmentation;
  const Eigen::Vector2d scale(scale_u(), scale_v());
  out.centre = out.centre.cwiseProduct(scale);
  for (auto& p : out.contour) p = p.cwiseProduct(scale);
  return out;
}

void UltrasoundReconstructionSession::set_image_calibration(const ImageCalibration& calibration) {
  calibration.validate();
  config_.image_in_probe = calibration.image_in_probe;
  config_.image_scale_u = calibration.s_u;
  config_.image_scale_v = calibration.s_v;
}

ImageCalibration UltrasoundReconstructionSession::image_calibration() const noexcept {
  ImageCalibration c;
  c.image_in_probe = config_.image_in_probe;
  c.s_u = config_.image_scale_u > 0.0 ? config_.image_scale_u : config_.geometry.pixel_size;
  c.s_v = config_.image_scale_v > 0.0 ? config_.image_scale_v : config_.geometry.pixel_size;
  return c;
}

void UltrasoundReconstructionSession::set_fiber_in_base(const Eigen::Isometry3d& fiber_in_base) {
  if (!is_rigid(fiber_in_base))
    throw UltrasoundSetupError("ultrasound session: the fibre-to-catheter-base transform H_F^C is not rigid");
  config_.fiber_in_base = fiber_in_base;
}

void UltrasoundReconstructionSession::reset() {
  slices_.clear();
  mesh_ = {};
  catheter_ = {};
  frame_.reset();
  ++revision_;
}

}  // namespace tendril::ultrasound
