// The ultrasound sweep: the "ultrasound" section, the plan (network thread) and the phase machine of
// mode sweep (control thread). See ultrasound_sweep.hpp.
#include "serial_arm/ultrasound_sweep.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "tendril/server/config_reader.hpp"
#include "tendril/ultrasound/preoperative_plan.hpp"

namespace tendril::server {

namespace {

using detail::Reader;

std::array<double, 16> matrix16(const Eigen::Isometry3d& pose) noexcept {
  std::array<double, 16> out{};
  Eigen::Map<Eigen::Matrix4d>(out.data()) = pose.matrix();
  return out;
}

Eigen::Isometry3d isometry(const std::array<double, 16>& m) noexcept {
  Eigen::Isometry3d pose;
  pose.matrix() = Eigen::Map<const Eigen::Matrix4d>(m.data());
  return pose;
}

std::vector<double> numbers(const Reader& r, const std::string& key, std::size_t count) {
  const auto& v = r.raw(key);
  if (!v.is_array() || v.size() != count ||
      !std::all_of(v.begin(), v.end(), [](const nlohmann::json& x) { return x.is_number(); }))
    r.fail(key, std::to_string(count) + " numbers", v);
  std::vector<double> out;
  for (const auto& x : v) out.push_back(x.get<double>());
  return out;
}

FourierTerms fourier_terms(const Reader& r, const std::string& key) {
  if (!r.has(key)) return {};
  const auto v = numbers(r, key, 5);
  return {v[0], v[1], v[2], v[3], v[4]};
}

bool active_phase(SweepPhase p) noexcept {
  return p == SweepPhase::pre_positioning || p == SweepPhase::ready || p == SweepPhase::approaching ||
         p == SweepPhase::acquiring || p == SweepPhase::moving;
}

}  // namespace

const char* to_string(SweepPhase phase) noexcept {
  switch (phase) {
    case SweepPhase::idle:
      return "idle";
    case SweepPhase::planned:
      return "planned";
    case SweepPhase::pre_positioning:
      return "pre_positioning";
    case SweepPhase::ready:
      return "ready";
    case SweepPhase::approaching:
      return "approaching";
    case SweepPhase::acquiring:
      return "acquiring";
    case SweepPhase::moving:
      return "moving";
    case SweepPhase::paused:
      return "paused";
    case SweepPhase::done:
      return "done";
    case SweepPhase::aborted:
      return "aborted";
  }
  return "idle";
}

const char* to_string(SweepAction action) noexcept {
  static const char* names[] = {"plan", "preview", "pre_position", "start", "pause", "abort"};
  return names[static_cast<int>(action)];
}

std::optional<SweepAction> sweep_action(const std::string& name) {
  for (int i = 0; i <= static_cast<int>(SweepAction::abort); ++i)
    if (name == to_string(static_cast<SweepAction>(i))) return static_cast<SweepAction>(i);
  return std::nullopt;
}

// ---- settings ---------------------------------------------------------------------------------------

std::optional<UltrasoundSettings> parse_ultrasound_settings(const RobotConfig& rc) {
  const auto it = rc.settings.find("ultrasound");
  if (it == rc.settings.end()) return std::nullopt;
  const std::string file = rc.file.string();
  const Reader u(*it, file, "ultrasound");
  UltrasoundSettings s;
  if (u.has("plan")) {
    const Reader p = u.child("plan");
    s.via_points = static_cast<int>(p.integer_in_or("via_points", 2, kMaxViaPoints, s.via_points));
    s.start_x = p.number_or("start_x_mm", s.start_x);
    s.end_x = p.number_or("end_x_mm", s.end_x);
    s.nearest = static_cast<int>(p.integer_in_or("nearest", 1, 50, s.nearest));
    if (!(s.end_x - s.start_x >= 5.0)) p.fail("end_x_mm", "at least 5 mm past start_x_mm", p.raw("end_x_mm"));
  }
  s.force.contact_force = u.positive_or("force_target_n", s.force.contact_force);
  if (u.has("gate")) {
    const Reader g = u.child("gate");
    s.gate.position_setpoint = g.positive_or("position_mm", s.gate.position_setpoint);
    s.gate.orientation_setpoint = g.positive_or("angle_rad", s.gate.orientation_setpoint);
    s.gate.force_tolerance = g.positive_or("force_tolerance_n", s.gate.force_tolerance);
    s.gate.hold_time = g.non_negative_or("hold_ms", s.gate.hold_time * 1e3) / 1e3;
  }
  s.approach_height = u.positive_or("approach_height_mm", s.approach_height);
  s.pre_position_tolerance = u.positive_or("pre_position_tolerance_mm", s.pre_position_tolerance);
  s.acquire_time = u.non_negative_or("acquire_ms", s.acquire_time * 1e3) / 1e3;
  s.retract_speed = u.positive_or("retract_speed_mm_s", s.retract_speed);
  if (s.retract_speed > 10.0) u.fail("retract_speed_mm_s", "at most 10", u.raw("retract_speed_mm_s"));
  s.retract_distance = u.positive_or("retract_distance_mm", s.retract_distance);
  s.velocity_feed_forward = u.boolean_or("velocity_feed_forward", s.velocity_feed_forward);
  s.tracker_filter_hz = u.non_negative_or("tracker_filter_hz", s.tracker_filter_hz);
  if (s.tracker_filter_hz > 10.0)
    u.fail("tracker_filter_hz", "at most 10 Hz (0: off)", u.raw("tracker_filter_hz"));

  if (!u.has("limb"))
    throw ConfigError(file +
                      ": ultrasound.limb: expected this section: the limb, its tracker and its CT are "
                      "SIMULATED and configured here (tendril has no motion-capture or CT import yet)");
  const Reader l = u.child("limb");
  auto& p = s.limb;
  const auto rest = numbers(l, "rest_position_mm", 3);
  p.rest_pose = Eigen::Isometry3d::Identity();
  p.rest_pose.translation() = Eigen::Vector3d(rest[0], rest[1], rest[2]);
  p.cylinder_radius = l.positive_or("cylinder_radius_mm", p.cylinder_radius);
  if (l.has("bumps")) {
    const auto& bumps = l.array("bumps", false);
    for (std::size_t i = 0; i < bumps.size(); ++i) {
      const Reader b(bumps[i], file, "ultrasound.limb.bumps[" + std::to_string(i) + "]");
      p.bumps.push_back({b.number("x_mm"), b.number("y_mm"), b.number("height_mm"), b.positive("sigma_mm")});
    }
  }
  p.stiffness = l.positive_or("stiffness_n_per_mm", p.stiffness);
  p.damping = l.non_negative_or("damping_n_s_per_mm", p.damping);
  if (l.has("artery")) {
    const Reader a = l.child("artery");
    if (a.has("x_range_mm")) {
      const auto x = numbers(a, "x_range_mm", 2);
      p.artery_x_start = x[0];
      p.artery_x_end = x[1];
    }
    p.artery_depth = a.positive_or("depth_mm", p.artery_depth);
    p.artery_dip = a.number_or("dip_mm", p.artery_dip);
    p.artery_lateral = a.number_or("lateral_mm", p.artery_lateral);
    p.artery_radius = a.positive_or("radius_mm", p.artery_radius);
  }
  if (l.has("motion")) {
    const Reader m = l.child("motion");
    p.period = m.positive_or("period_s", p.period);
    p.y = fourier_terms(m, "y_mm");
    p.z = fourier_terms(m, "z_mm");
    p.rx = fourier_terms(m, "rx_rad");
  }
  if (l.has("tracker")) {
    const Reader t = l.child("tracker");
    p.tracker_rate = t.positive_or("rate_hz", p.tracker_rate);
    p.tracker_latency = t.non_negative_or("latency_ms", p.tracker_latency * 1e3) / 1e3;
    p.tracker_noise = t.non_negative_or("noise_mm", p.tracker_noise);
  }
  if (l.has("ct")) {
    const Reader c = l.child("ct");
    p.ct_T_limb = Eigen::Isometry3d::Identity();
    if (c.has("misregistration_mm")) {
      const auto t = numbers(c, "misregistration_mm", 3);
      p.ct_T_limb.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
    }
    p.ct_T_limb.linear() =
        Eigen::AngleAxisd(c.number_or("misregistration_rz_rad", 0.0), Eigen::Vector3d::UnitZ())
            .toRotationMatrix();
    p.ct_noise = c.non_negative_or("noise_mm", p.ct_noise);
  }
  p.scan_noise = l.non_negative_or("scan_noise_mm", p.scan_noise);
  p.seed = static_cast<std::uint64_t>(l.integer_in_or("seed", 0, 1L << 40, static_cast<long>(p.seed)));
  try {
    validate(p);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": ultrasound.limb." + e.what());
  }
  if (s.start_x < p.artery_x_start || s.end_x > p.artery_x_end)
    throw ConfigError(file +
                      ": ultrasound.plan: expected start_x_mm and end_x_mm within the artery's x_range_mm");
  return s;
}

// ---- the plan (network thread) ----------------------------------------------------------------------

SweepPlan make_sweep_plan(const LimbSimulation& limb, const UltrasoundSettings& settings) {
  const auto started = std::chrono::steady_clock::now();
  SweepPlan plan;
  plan.skin = limb.skin_scan();
  const auto ct_wall = limb.ct_wall_cloud();
  // ICP (Heunis et al. 2021, §2.4): the calibration stick in the CT (data) onto its model in {P} gives T: CT
  // → {P}. (The skin alone registers poorly: a limb is nearly a cylinder, free to slide along and turn about
  // its axis; we measured 0.9 mm across the limb that way against 0.1 mm on the stick.)
  const auto icp = ultrasound::icp(limb.stick_model(), limb.ct_stick_cloud());
  plan.ct_to_limb = icp.transform;
  plan.icp_rms = icp.rms;
  plan.icp_iterations = icp.iterations;
  // How far the registration puts the CT from where it belongs (the simulation knows the truth).
  const Eigen::Isometry3d truth = limb.parameters().ct_T_limb.inverse();
  // The skin is nearly a cylinder along x: the bumps alone pin the CT along the limb, so that part of
  // the error is the larger one; across the limb (y, z) is what moves the via-points off the artery.
  double sum = 0.0, across = 0.0;
  for (const auto& p : ct_wall) {
    const Eigen::Vector3d e = plan.ct_to_limb * p - truth * p;
    sum += e.norm();
    across += e.tail<2>().norm();
  }
  const double count = std::max<double>(1.0, static_cast<double>(ct_wall.size()));
  plan.registration_error = sum / count;
  plan.registration_error_across = across / count;
  ultrasound::CentroidPlanOptions c;
  c.count = settings.via_points;
  c.start_x = settings.start_x;
  c.end_x = settings.end_x;
  plan.centroids = ultrasound::arterial_centroids(ct_wall, plan.ct_to_limb, c);
  ultrasound::ViaPointOptions v;
  v.up = Eigen::Vector3d::UnitZ();  // the limb frame's z is out of the skin
  v.nearest = settings.nearest;
  for (const auto& via : ultrasound::probe_via_points(plan.skin, plan.centroids, v))
    plan.via_points.push_back(via.pose());
  plan.planning_time = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return plan;
}

// ---- the tracked limb's filter (control thread) -----------------------------------------------------

void LimbPoseFilter::configure(double natural_hz, double nominal_period) noexcept {
  period_ = nominal_period;
  const double rho = std::exp(-2.0 * std::numbers::pi * natural_hz * nominal_period);
  alpha_ = 1.0 - rho * rho;
  beta_ = (1.0 - rho) * (1.0 - rho);
  initialised_ = false;
}

void LimbPoseFilter::update(const Eigen::Isometry3d& pose, double t) noexcept {
  const double dt = t - t_;
  if (!initialised_ || !(dt > 1e-6) || dt > 0.1) {
    if (initialised_ && dt > -1e-9 && dt <= 1e-6) return;  // the same report again
    initialised_ = true;
    t_ = t;
    r0_ = pose.linear();
    x_ = pose.translation();
    v_.setZero();
    r_.setZero();
    w_.setZero();
    return;
  }
  // Predict to the report's time, then correct by the residual.
  const Eigen::Vector3d x_pred = x_ + v_ * dt, r_pred = r_ + w_ * dt;
  const Eigen::AngleAxisd measured(r0_.transpose() * pose.linear());
  const Eigen::Vector3d r_meas = measured.angle() * measured.axis();
  const Eigen::Vector3d ex = pose.translation() - x_pred, er = r_meas - r_pred;
  x_ = x_pred + alpha_ * ex;
  v_ += (beta_ / dt) * ex;
  r_ = r_pred + alpha_ * er;
  w_ += (beta_ / dt) * er;
  t_ = t;
}

Eigen::Isometry3d LimbPoseFilter::pose_after(double h) const noexcept {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.translation() = x_ + v_ * h;
  const Eigen::Vector3d r = r_ + w_ * h;
  const double angle = r.norm();
  out.linear() =
      angle > 1e-12 ? Eigen::Matrix3d(r0_ * Eigen::AngleAxisd(angle, r / angle).toRotationMatrix()) : r0_;
  return out;
}

Eigen::Vector3d LimbPoseFilter::point_velocity(const Eigen::Vector3d& p_limb) const noexcept {
  // A difference of the filtered motion itself over one tracker period (exact for the chart's linear
  // motion), not of two noisy reports.
  return (pose_after(period_) * p_limb - pose_after(0.0) * p_limb) / period_;
}

// ---- the sweep (control thread) ---------------------------------------------------------------------

UltrasoundSweep::UltrasoundSweep(const UltrasoundSettings& settings, const teleop::TaskSpaceGains& gains,
                                 const teleop::CartesianLimits& limits)
    : settings_(settings),
      limits_(limits),
      controller_(teleop::HybridControlParameters{gains, settings.force, settings.gate}),
      rest_(settings.limb.rest_pose.translation()) {
  limb_filter_.configure(settings.tracker_filter_hz, 1.0 / settings.limb.tracker_rate);
}

bool UltrasoundSweep::running() const noexcept {
  return active_phase(snapshot_.phase) || snapshot_.retracting;
}

void UltrasoundSweep::load(const SweepPlanData& plan) noexcept {
  if (active_phase(snapshot_.phase) || snapshot_.phase == SweepPhase::paused) return;
  plan_ = plan;
  snapshot_ = SweepSnapshot{};
  snapshot_.phase = SweepPhase::planned;
  snapshot_.via_points = plan.count;
  set_message("planned: %d via-points; pre_position next", plan.count);
}

Eigen::Matrix4d UltrasoundSweep::plan_via(int i) const noexcept {
  const int k = std::clamp(i, 0, std::max(plan_.count - 1, 0));
  return Eigen::Map<const Eigen::Matrix4d>(plan_.via_points[static_cast<std::size_t>(k)].data());
}

Eigen::Isometry3d UltrasoundSweep::target(int i, const Eigen::Isometry3d& world_T_limb) const noexcept {
  const int k = std::clamp(i, 0, std::max(plan_.count - 1, 0));
  return world_T_limb * isometry(plan_.via_points[static_cast<std::size_t>(k)]);
}

void UltrasoundSweep::start_retraction(SweepPhase phase) noexcept {
  snapshot_.phase = phase;
  snapshot_.retracting = true;
  snapshot_.gate_open = false;
  retracted_ = 0.0;
  // Out of the skin: against the probe axis of the target (its z points into the tissue).
  retract_direction_ = -isometry(snapshot_.target).linear().col(2);
  if (!retract_direction_.allFinite() || retract_direction_.norm() < 0.5)
    retract_direction_ = Eigen::Vector3d::UnitZ();
}

void UltrasoundSweep::command(SweepAction action, double t) noexcept {
  (void)t;
  auto& s = snapshot_;
  switch (action) {
    case SweepAction::pre_position:
      if (s.phase == SweepPhase::planned || s.phase == SweepPhase::done || s.phase == SweepPhase::aborted) {
        s = SweepSnapshot{};
        s.via_points = plan_.count;
        s.phase = SweepPhase::pre_positioning;
        state_.reset();
        ready_since_ = -1.0;
        set_message("pre-positioning %.0f mm above via-point 1", settings_.approach_height);
      }
      return;
    case SweepAction::start:
      if (s.phase == SweepPhase::ready) {
        s.phase = SweepPhase::approaching;
        state_.reset();
        set_message("approaching via-point 1 (position, then force control on %.2f N)",
                    settings_.force.contact_force);
      } else if (s.phase == SweepPhase::paused) {
        const SweepPhase from = s.paused_from;
        if (from == SweepPhase::pre_positioning || from == SweepPhase::ready) {
          s.phase = SweepPhase::pre_positioning;
          ready_since_ = -1.0;
        } else {
          // In contact the hybrid state carries on (the force phase persists); after a hold it restarts.
          s.phase = state_.phase == teleop::ProbePhase::force ? SweepPhase::moving : SweepPhase::approaching;
        }
        set_message("continuing at via-point %d of %d", s.via_point + 1, s.via_points);
      }
      return;
    case SweepAction::pause:
      if (active_phase(s.phase)) {
        s.paused_from = s.phase;
        s.phase = SweepPhase::paused;
        s.gate_open = false;
        set_message(
            "paused at via-point %d of %d: holding %.2f N on the skin; start continues, abort lifts off",
            s.via_point + 1, s.via_points, settings_.force.contact_force);
      }
      return;
    case SweepAction::abort:
      if (active_phase(s.phase) || s.phase == SweepPhase::paused) {
        start_retraction(SweepPhase::aborted);
        set_message("aborted: retracting %.0f mm along the skin normal at %.0f mm/s, then holding",
                    settings_.retract_distance, settings_.retract_speed);
      }
      return;
    case SweepAction::plan:
    case SweepAction::preview:
      return;  // network-thread actions
  }
}

void UltrasoundSweep::interrupt(const char* why) noexcept {
  auto& s = snapshot_;
  if (s.retracting) {
    // A retraction stops where it is; the phase (done, aborted) stays.
    s.retracting = false;
    return;
  }
  if (!active_phase(s.phase)) return;
  s.paused_from = s.phase;
  s.phase = SweepPhase::paused;
  s.gate_open = false;
  interrupted_ = true;
  set_message("paused at via-point %d of %d: %s; start continues", s.via_point + 1, s.via_points, why);
}

bool UltrasoundSweep::step(const teleop::SerialArmKinematics& model, teleop::SerialArmData& data,
                           const Inputs& in, teleop::CartesianCommandResult& out) noexcept {
  auto& s = snapshot_;
  out = teleop::CartesianCommandResult{};
  const bool filtered = settings_.tracker_filter_hz > 0.0;
  if (in.limb_t != latest_limb_t_) {  // a new tracker sample
    previous_limb_ = latest_limb_;
    previous_limb_t_ = latest_limb_t_;
    latest_limb_ = in.world_T_limb;
    latest_limb_t_ = in.limb_t;
    if (filtered) limb_filter_.update(in.world_T_limb, in.limb_t);
  }
  // The limb as the targets see it: the filtered tracker reports (or the latest raw one).
  const Eigen::Isometry3d world_T_limb =
      filtered && limb_filter_.valid() ? limb_filter_.pose() : in.world_T_limb;
  s.world_T_limb = matrix16(world_T_limb);
  const Eigen::Vector3d offset = world_T_limb.translation() - rest_;
  s.limb_offset_mm = {offset.x(), offset.y(), offset.z()};
  if (interrupted_) {
    state_.reset();
    interrupted_ = false;
  }
  if (s.phase == SweepPhase::idle || s.phase == SweepPhase::planned || plan_.count == 0) return false;

  if (s.phase == SweepPhase::done || s.phase == SweepPhase::aborted) {
    if (!s.retracting) return false;
    model.update(in.q, data);
    teleop::Twist twist = teleop::Twist::Zero();
    twist.head<3>() = settings_.retract_speed * retract_direction_;
    out = teleop::servo_cv(model, data, in.q, twist, limits_, in.dt);
    retracted_ += out.twist.head<3>().norm() * in.dt;
    if (!out.joints.valid || retracted_ >= settings_.retract_distance) {
      s.retracting = false;
      return false;
    }
    return true;
  }

  // The target of this cycle, from the limb's tracked pose (motion compensation).
  const bool in_air = s.phase == SweepPhase::pre_positioning || s.phase == SweepPhase::ready ||
                      (s.phase == SweepPhase::paused &&
                       (s.paused_from == SweepPhase::pre_positioning || s.paused_from == SweepPhase::ready));
  Eigen::Isometry3d goal = target(s.via_point, world_T_limb);
  if (in_air) goal.translation() -= settings_.approach_height * goal.linear().col(2);
  s.target = matrix16(goal);

  teleop::HybridControlInputs h;
  h.q = in.q;
  h.target = goal;
  h.force = in.force;
  h.force_valid = in.force_valid;
  h.contact_enabled = !in_air;
  const auto r = controller_.step(model, data, state_, h, in.dt);
  s.force_n = r.normal_force;
  s.position_error_mm = r.gate_position_error;
  s.angle_error_rad = std::max(r.orientation.about_y, r.orientation.about_z);
  s.force_ok = std::abs(r.force_error) <= settings_.gate.force_tolerance;
  s.in_contact = r.phase == teleop::ProbePhase::force;
  s.gate_open = r.acquire && s.phase != SweepPhase::paused;
  out.joints.joint_velocity = r.joint_velocity;
  out.joints.valid = r.status == teleop::HybridControlStatus::ok;
  out.joints.velocity_limited = r.velocity_limited;
  out.joints.position_limited = r.position_limited;
  out.twist = r.twist;
  out.twist_limited = r.twist_limited;
  const double dt_limb = latest_limb_t_ - previous_limb_t_;
  const bool raw_velocity = !filtered && previous_limb_t_ >= 0.0 && dt_limb > 1e-6 && dt_limb < 0.1;
  if (settings_.velocity_feed_forward && out.joints.valid && (raw_velocity || limb_filter_.valid())) {
    // The via-point's velocity (its point on the limb, so the limb's rotation counts too) — from the
    // filter, or between the last two tracker samples without one —, added to the law's twist and
    // resolved again (caps, damped inverse, joint limits): the probe moves with the limb instead of
    // behind it.
    const Eigen::Matrix4d via = plan_via(s.via_point);
    const Eigen::Vector3d p = via.block<3, 1>(0, 3);
    const Eigen::Vector3d v = raw_velocity
                                  ? Eigen::Vector3d((latest_limb_ * p - previous_limb_ * p) / dt_limb)
                                  : limb_filter_.point_velocity(p);
    if (v.allFinite()) {
      teleop::Twist twist = r.twist;
      twist.head<3>() += v;
      model.update(in.q, data);
      out = teleop::servo_cv(model, data, in.q, twist, limits_, in.dt);
    }
  }

  switch (s.phase) {
    case SweepPhase::pre_positioning: {
      const bool near = r.gate_position_error <= settings_.pre_position_tolerance &&
                        s.angle_error_rad <= settings_.gate.orientation_setpoint;
      if (!near) {
        ready_since_ = -1.0;
      } else if (ready_since_ < 0.0) {
        ready_since_ = in.t;
      } else if (in.t - ready_since_ >= settings_.gate.hold_time) {
        s.phase = SweepPhase::ready;
        set_message("ready %.0f mm above via-point 1 (following the limb); start begins the sweep",
                    settings_.approach_height);
      }
      break;
    }
    case SweepPhase::approaching:
    case SweepPhase::moving:
      if (s.gate_open) {
        s.phase = SweepPhase::acquiring;
        acquire_since_ = in.t;
        set_message("acquiring at via-point %d of %d", s.via_point + 1, s.via_points);
      }
      break;
    case SweepPhase::acquiring:
      if (!s.gate_open) {
        // The gate closed before the slice was complete (the limb jerked, the force left its band).
        s.phase = s.in_contact ? SweepPhase::moving : SweepPhase::approaching;
        set_message("the gate closed at via-point %d; waiting for it again", s.via_point + 1);
      } else if (in.t - acquire_since_ >= settings_.acquire_time) {
        ++s.slices;
        if (s.via_point + 1 >= plan_.count) {
          s.progress = 1.0;
          start_retraction(SweepPhase::done);
          set_message("done: %d slices; retracting %.0f mm, then holding", s.slices,
                      settings_.retract_distance);
        } else {
          ++s.via_point;
          s.phase = SweepPhase::moving;
          set_message("moving to via-point %d of %d", s.via_point + 1, s.via_points);
        }
      }
      break;
    default:
      break;
  }
  if (s.phase != SweepPhase::done) s.progress = static_cast<double>(s.slices) / std::max(plan_.count, 1);
  return true;
}

}  // namespace tendril::server
