// The imaging half of the catheter's image_guided mode (image_guidance.hpp).
#include "steerable_catheter/image_guidance.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "steerable_catheter/catheter_robot.hpp"

namespace tendril::server {

namespace {

// The robot file's planning design ("kinematics", as the planning service reads it).
teleop::CatheterParameters configured_design(const nlohmann::json& k) {
  teleop::CatheterParameters p;
  p.proximal_length = k.at("segment_lengths_mm").at(0).get<double>();
  p.distal_length = k.at("segment_lengths_mm").at(1).get<double>();
  p.proximal_curvature_gain = k.at("bend_gain_rad_per_mm").at(0).get<double>();
  p.distal_curvature_gain = k.at("bend_gain_rad_per_mm").at(1).get<double>();
  p.plane_offset = k.at("plane_offset_rad").get<double>();
  p.flexure = k.value("flexure_rad", 0.0);
  return p;
}

// Arc length of the centerline point nearest to x (mm from the vessel start), and the distance.
double nearest_arc_length(const teleop::VesselCenterline& v, const Eigen::Vector3d& x) {
  const auto& pts = v.points();
  double best = std::numeric_limits<double>::infinity(), s = 0.0;
  for (std::size_t i = 0; i + 1 < pts.size(); ++i) {
    const Eigen::Vector3d d = pts[i + 1] - pts[i];
    const double u = std::clamp((x - pts[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    const double dist = (pts[i] + u * d - x).squaredNorm();
    if (dist < best) {
      best = dist;
      s = v.arc_length(i) + u * v.spacing();
    }
  }
  return s;
}

}  // namespace

const char* to_string(ImageGuidanceState state) noexcept {
  switch (state) {
    case ImageGuidanceState::kWaiting:
      return "waiting";
    case ImageGuidanceState::kTracking:
      return "tracking";
    case ImageGuidanceState::kNotFound:
      return "not_found";
    case ImageGuidanceState::kRefused:
      return "refused";
    case ImageGuidanceState::kInactive:
      break;
  }
  return "inactive";
}

void ImageGuidance::tracking_attached(std::function<void(bool wanted)> demand) {
  demand_ = std::move(demand);
  attached_.store(true, std::memory_order_release);
}

bool ImageGuidance::imaged_backbone(std::vector<Eigen::Vector3d>& out) const {
  return robot_.true_backbone(out);
}

std::optional<ServiceError> ImageGuidance::prepare(const std::vector<Eigen::Vector3d>& plan_vessel_world) {
  const std::string& robot = robot_.config().name;
  const auto entry = robot_.vessel_entry();
  teleop::CenterlinePolyline vessel;
  vessel.points.reserve(plan_vessel_world.size());
  for (const auto& p : plan_vessel_world) vessel.points.push_back(entry->inverse() * p);
  teleop::ShapeErrorPlannerOptions options;
  // The target is one replanning step ahead of the measured tip. The plans' dq1 (3 mm) suits stepwise
  // playback; here the operator inserts continuously and a frame comes every 1/15 s, so the step is
  // kReplanStepMm: about how far the tip gets while the bends move to a new target.
  options.insertion_step = kReplanStepMm;
  const auto& joints = robot_.config().joints;
  options.proximal_drive_min = joints[2].limit.lower + joints[2].limit.soft_margin;
  options.proximal_drive_max = joints[2].limit.upper - joints[2].limit.soft_margin;
  options.distal_drive_min = joints[3].limit.lower + joints[3].limit.soft_margin;
  options.distal_drive_max = joints[3].limit.upper - joints[3].limit.soft_margin;
  std::unique_ptr<teleop::ImageGuidedReplanner> replanner;
  try {
    const auto design =
        configured_design(robot_.config().settings.value("kinematics", nlohmann::json::object()));
    replanner =
        std::make_unique<teleop::ImageGuidedReplanner>(teleop::ConstantCurvatureCatheter(design), options,
                                                       teleop::VesselCenterline::from_polyline(vessel, 0.5));
  } catch (const std::exception& e) {
    return ServiceError{ErrorKind::conflict, "no_plan",
                        "robot '" + robot + "': the loaded plan's vessel cannot be replanned on (" +
                            e.what() + "); load another plan"};
  }
  auto state = std::make_unique<teleop::ReplannerState>(replanner->make_state());
  {
    std::lock_guard lock(mutex_);
    replanner_ = std::move(replanner);
    state_ = std::move(state);
    to_insertion_ = entry->inverse();
    status_ = ImageGuidanceStatus{};
    status_.state = ImageGuidanceState::kWaiting;
    demanded_ = true;
  }
  if (demand_) demand_(true);
  return std::nullopt;
}

void ImageGuidance::on_tip(const ImagedTip& tip) {
  const auto snapshot = robot_.snapshot();
  std::unique_lock lock(mutex_);
  if (snapshot.mode != kImageGuidedMode || !replanner_) {
    // The mode ended: tracking goes back to whoever watches /imaging/tracking.
    status_.state = ImageGuidanceState::kInactive;
    const bool release = std::exchange(demanded_, false);
    lock.unlock();
    if (release && demand_) demand_(false);
    return;
  }
  status_.drive_insertion_mm = snapshot.position[0];
  if (!tip.found) {
    status_.state = ImageGuidanceState::kNotFound;
    status_.reason = "a plane did not find the tip";
    return;
  }
  const Eigen::Vector3d tip_insertion = to_insertion_ * tip.position;
  const double image_s = nearest_arc_length(replanner_->planner().prepared_vessel(), tip_insertion);
  const double drive_s = snapshot.position[0];
  teleop::ReplanInput in;
  in.measured_tip = tip_insertion;
  in.measured_insertion =
      std::clamp(std::clamp(image_s, drive_s - kLagMm, drive_s + kLeadMm), 0.0, replanner_->vessel_length());
  // ψ commanded at the exposure: the setpoint's, through the configuration map (loss lines, coupling).
  // Not the configuration controller's goal: with a new target every frame the bends are still on
  // their way to it, and the tip error must be taken against the shape actually commanded.
  const Eigen::Vector4d psi_now = robot_.map().configuration(Eigen::Vector4d(
      snapshot.setpoint[0], snapshot.setpoint[1], snapshot.setpoint[2], snapshot.setpoint[3]));
  in.commanded_configuration = psi_now;
  const auto result = replanner_->replan(*state_, in);
  status_.image_insertion_mm = image_s;
  status_.measured_insertion_mm = in.measured_insertion;
  for (int i = 0; i < 3; ++i) status_.tip_mm[static_cast<std::size_t>(i)] = tip.position[i];
  if (result.status != teleop::ReplanStatus::kOk) {
    status_.state = ImageGuidanceState::kRefused;
    status_.reason = result.status == teleop::ReplanStatus::kTipOutlier
                         ? "the imaged tip is too far from the model's prediction"
                     : result.status == teleop::ReplanStatus::kInsertionOutOfRange
                         ? "the measured insertion is outside the plan's vessel"
                         : "a measured value is not finite";
    return;
  }
  ImageGuidedTarget target;
  target.sequence = ++sequence_;
  for (int i = 0; i < 4; ++i) target.psi[static_cast<std::size_t>(i)] = result.configuration[i];
  // The replanner unwraps the roll to the one nearest the commanded roll; it may lie beyond the roll
  // joint's range, and near straight poses the solver may land on the roll π away with both bends
  // negated — the same shape (each segment's bending plane turned by π, its curvature reversed), but
  // reached by swinging the whole catheter through half a turn. Of the equivalent targets (roll + mπ,
  // bends × (−1)^m) inside the roll range and the bend drives' range, the one nearest the roll setpoint.
  const auto& roll = robot_.config().joints[1].limit;
  const double lo = roll.lower + roll.soft_margin, hi = roll.upper - roll.soft_margin;
  const auto& options = replanner_->planner().options();
  const auto& design = replanner_->planner().model().parameters();
  const auto bends_in_range = [&](double sign) {
    const double q3 = sign * target.psi[2] / design.proximal_curvature_gain;
    const double q4 = sign * target.psi[3] / design.distal_curvature_gain;
    return q3 >= options.proximal_drive_min && q3 <= options.proximal_drive_max &&
           q4 >= options.distal_drive_min && q4 <= options.distal_drive_max;
  };
  const double now = snapshot.setpoint[1];
  bool found = false;
  double best_roll = 0.0, best_sign = 1.0;
  for (int m = -4; m <= 4; ++m) {
    const double r = target.psi[1] + m * std::numbers::pi;
    const double sign = m % 2 == 0 ? 1.0 : -1.0;
    if (r < lo || r > hi || !bends_in_range(sign)) continue;
    if (!found || std::abs(r - now) < std::abs(best_roll - now)) {
      found = true;
      best_roll = r;
      best_sign = sign;
    }
  }
  if (!found) best_roll = std::clamp(target.psi[1], lo, hi);  // out of reach: as near as the range allows
  target.psi[1] = best_roll;
  target.psi[2] *= best_sign;
  target.psi[3] *= best_sign;
  target_.store(target);  // one writer at a time: mutex_ is held
  status_.state = ImageGuidanceState::kTracking;
  status_.reason.clear();
  status_.replans = sequence_;
  status_.last_fix_ns = tip.capture_ns;
  status_.target = target.psi;
}

ImageGuidanceStatus ImageGuidance::status() const {
  std::lock_guard lock(mutex_);
  return status_;
}

}  // namespace tendril::server
