#include "serial_arm/calibration_motion.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace tendril::server {

namespace {

std::array<double, 16> to_array16(const Eigen::Isometry3d& t) {
  std::array<double, 16> out{};
  Eigen::Map<Eigen::Matrix4d>(out.data()) = t.matrix();
  return out;
}

Eigen::Isometry3d from_array16(const std::array<double, 16>& a) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.matrix() = Eigen::Map<const Eigen::Matrix4d>(a.data());
  return t;
}

}  // namespace

const char* to_string(CalibrationPhase phase) noexcept {
  switch (phase) {
    case CalibrationPhase::idle:
      return "idle";
    case CalibrationPhase::moving:
      return "moving";
    case CalibrationPhase::dwelling:
      return "dwelling";
    case CalibrationPhase::returning:
      return "returning";
    case CalibrationPhase::collected:
      return "collected";
    case CalibrationPhase::failed:
      return "failed";
  }
  return "?";
}

// ---- the SIMULATED optical tracker ----------------------------------------------------------------

SimulatedOpticalTracker::SimulatedOpticalTracker(const OpticalTrackerSettings& settings)
    : settings_(settings), rng_(settings.seed) {}

Eigen::Vector3d SimulatedOpticalTracker::robot_error(const teleop::ArmVector& q) const noexcept {
  // Fixed geometric errors of the arm against its model show as an error that depends smoothly on the
  // joints: a direction and a magnitude (0.3 ± 0.1 mm, the article's budget) that turn with them.
  const Eigen::Vector3d direction(std::sin(q[0] + 0.7 * q[1] + 0.3), std::cos(1.3 * q[2] - q[3] + 0.2),
                                  std::sin(q[4] - 0.6 * q[5] + 1.1 * q[1]));
  const double magnitude = settings_.robot_error_mean_mm +
                           settings_.robot_error_sd_mm * std::sin(2.0 * q[1] + q[2] - 1.5 * q[4] + 0.4);
  const double n = direction.norm();
  return n > 1e-9 ? Eigen::Vector3d(direction * (magnitude / n)) : Eigen::Vector3d::Zero();
}

void SimulatedOpticalTracker::step(double t, const teleop::ArmVector& q,
                                   const Eigen::Isometry3d& probe_kinematic) noexcept {
  if (t < next_) return;
  next_ = std::max(next_ + 1.0 / settings_.rate_hz, t);
  if (silent_) return;
  Eigen::Isometry3d probe = probe_kinematic;  // where the probe really is
  probe.translation() += robot_error(q);
  Eigen::Isometry3d marker = settings_.global_T_base * probe * settings_.marker_T_probe.inverse();
  const Eigen::Vector3d direction(normal_(rng_), normal_(rng_), normal_(rng_));
  const double magnitude =
      std::max(0.0, settings_.triangulation_mean_mm + settings_.triangulation_sd_mm * normal_(rng_));
  if (direction.norm() > 1e-12) marker.translation() += direction.normalized() * magnitude;
  const double s = settings_.rotation_noise_deg * M_PI / 180.0;
  const Eigen::Matrix3d noise = (Eigen::AngleAxisd(s * normal_(rng_), Eigen::Vector3d::UnitX()) *
                                 Eigen::AngleAxisd(s * normal_(rng_), Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(s * normal_(rng_), Eigen::Vector3d::UnitZ()))
                                    .toRotationMatrix();
  marker.linear() = marker.linear() * noise;
  latest_.t = t;
  latest_.marker = to_array16(marker);
  latest_.visible = true;
}

// ---- poses ----------------------------------------------------------------------------------------

int calibration_poses(const Eigen::Isometry3d& current, int count, double tilt, double shift,
                      CalibrationPosesData& out) noexcept {
  count = std::clamp(count, 0, kMaxCalibrationPoses);
  out.count = count;
  for (int i = 0; i < count; ++i) {
    const double a = 2.0 * M_PI * i / count;
    // Tilt about an axis in the tool's x–y plane that goes round with i, and turn about the tool's own
    // axis by up to 0.6 tilt (smoothly, so consecutive poses stay close): the relative rotations then
    // span all three directions.
    const Eigen::Vector3d axis(std::cos(a), std::sin(a), 0.0);
    const double roll = 0.6 * tilt * std::sin(a);
    Eigen::Isometry3d pose = current;
    pose.linear() =
        current.linear() * (Eigen::AngleAxisd(tilt, axis) * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()))
                               .toRotationMatrix();
    pose.translation() += current.linear() * Eigen::Vector3d(shift * std::cos(a), shift * std::sin(a),
                                                             -shift * 0.5 * std::cos(2.0 * a));
    out.poses[static_cast<std::size_t>(i)] = to_array16(pose);
  }
  return count;
}

// ---- the routine ----------------------------------------------------------------------------------

CalibrationMotion::CalibrationMotion(const teleop::CartesianLimits& limits,
                                     const teleop::TaskSpaceGains& gains, double dwell,
                                     double tracker_timeout)
    : limits_(limits), gains_(gains), dwell_(dwell), tracker_timeout_(tracker_timeout) {}

void CalibrationMotion::message(const char* format, double a, double b) noexcept {
  std::snprintf(snapshot_.message.data(), snapshot_.message.size(), format, a, b);
}

bool CalibrationMotion::plan_to(const Eigen::Isometry3d& from, const Eigen::Isometry3d& goal,
                                double t) noexcept {
  delay_ = 0.0;
  return trajectory_.plan(from, goal, limits_, t);
}

void CalibrationMotion::start(const CalibrationPosesData& poses, const Eigen::Isometry3d& tool,
                              double t) noexcept {
  poses_ = poses;
  pairs_ = CalibrationPairsData{};
  pairs_.run = poses.run;
  snapshot_ = CalibrationSnapshot{};
  snapshot_.run = poses.run;
  snapshot_.poses = poses.count;
  home_ = tool;
  if (poses.count < 1 || !plan_to(tool, from_array16(poses.poses[0]), t)) {
    snapshot_.phase = CalibrationPhase::failed;
    message("robot calibration: no poses to visit");
    return;
  }
  snapshot_.phase = CalibrationPhase::moving;
  message("moving to pose 1 of %.0f", poses.count);
}

void CalibrationMotion::fail(const char* why) noexcept {
  if (!running()) return;
  snapshot_.phase = CalibrationPhase::failed;
  std::snprintf(snapshot_.message.data(), snapshot_.message.size(),
                "robot calibration ended at pose %d of %d: %s", snapshot_.pose + 1, snapshot_.poses, why);
}

bool CalibrationMotion::step(const teleop::SerialArmKinematics& model, teleop::SerialArmData& data,
                             const teleop::ArmVector& q, const Eigen::Isometry3d& measured_tool,
                             const TrackerSample& tracker, double t, double dt,
                             teleop::CartesianCommandResult& result) noexcept {
  if (!running()) return false;
  // The tracker must keep reporting throughout: a hidden marker or a silent tracker ends the routine.
  const double age = tracker.t < 0.0 ? 1e9 : t - tracker.t;
  if (!tracker.visible || age > tracker_timeout_) {
    char why[96];
    std::snprintf(why, sizeof why, "the tracker has not seen the marker for %.0f ms (bound %.0f ms)",
                  std::min(age, 9999.0) * 1e3, tracker_timeout_ * 1e3);
    fail(why);
    return false;
  }
  const double tt = t - delay_;
  result = teleop::track(model, data, q, trajectory_.sample(tt), gains_, limits_, dt);
  if (!result.joints.valid) {
    fail("the damped inverse found no joint velocities (a singularity)");
    return false;
  }
  const int i = snapshot_.pose;
  switch (snapshot_.phase) {
    case CalibrationPhase::moving:
    case CalibrationPhase::returning: {
      if (!trajectory_.done(tt)) break;
      const double e = (data.tool.translation() - trajectory_.goal_position()).norm();
      const double a = Eigen::AngleAxisd(data.tool.linear().transpose() *
                                         trajectory_.goal_orientation().toRotationMatrix())
                           .angle();
      // On the goal (the setpoint within 0.05 mm and 0.5 mrad), or 3 s after the trajectory ended.
      if ((e > 0.05 || a > 5e-4) && tt < trajectory_.start_time() + trajectory_.duration() + 3.0) break;
      if (snapshot_.phase == CalibrationPhase::returning) {
        snapshot_.phase = CalibrationPhase::collected;
        message("recorded %.0f poses; back at the start pose", pairs_.count);
        return true;
      }
      snapshot_.phase = CalibrationPhase::dwelling;
      dwell_start_ = t;
      message("pose %.0f of %.0f: standing still", i + 1, snapshot_.poses);
      break;
    }
    case CalibrationPhase::dwelling: {
      // The tracker's sample must be taken after the arm stood still for the dwell.
      if (t - dwell_start_ < dwell_ || tracker.t < dwell_start_ + 0.5 * dwell_) break;
      const auto k = static_cast<std::size_t>(pairs_.count);
      pairs_.kinematic[k] = to_array16(measured_tool);
      pairs_.tracked[k] = tracker.marker;
      ++pairs_.count;
      snapshot_.pose = i + 1;
      if (snapshot_.pose >= poses_.count) {
        snapshot_.pose = poses_.count - 1;
        snapshot_.phase = CalibrationPhase::returning;
        plan_to(data.tool, home_, t);
        message("recorded %.0f poses; returning to the start pose", pairs_.count);
      } else {
        snapshot_.phase = CalibrationPhase::moving;
        plan_to(data.tool, from_array16(poses_.poses[static_cast<std::size_t>(snapshot_.pose)]), t);
        message("moving to pose %.0f of %.0f", snapshot_.pose + 1, snapshot_.poses);
      }
      break;
    }
    default:
      break;
  }
  return true;
}

}  // namespace tendril::server
