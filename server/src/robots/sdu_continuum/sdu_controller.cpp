// The sdu_continuum's part of the control cycle (control thread): the disks' newest samples through the
// SduSupervisor (unbiasing, silent disks, unusable readings, drift, contact), the hold in the same cycle
// for every hold cause, the proximity speed law on every mode's step (limit_step), the guidance mode,
// and the ways out of a contact hold (contact-based guidance yielding to the push, the no-slip roll).
// No allocation, no locks, no exceptions: the samples come through LatestValue slots, the Jacobians
// are fixed-size.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "sdu_continuum/sdu_robot.hpp"

namespace tendril::server {

namespace {

namespace cont = tendril::continuum;
using safety::OperatingState;

// Numerical Jacobian step (rad): well above rounding at the segment's 370 mm scale, far below its curvature.
constexpr double kJacobianStep = 1e-6;
// Damping of the least-squares inverse (mm/rad): keeps the rates bounded where a joint does not move the
// disk (the bending plane of a straight segment).
constexpr double kDamping = 5.0;

safety::FaultCode hold_code(cont::SduCause cause) noexcept {
  switch (cause) {
    case cont::SduCause::kSduSilent:
      return safety::FaultCode::kSensorStale;
    case cont::SduCause::kHallInvalid:
    case cont::SduCause::kTofInvalid:
      return safety::FaultCode::kInvalidMeasurement;
    default:
      return safety::FaultCode::kExternal;
  }
}

bool holds(cont::SduSafetyState state) noexcept {
  return state == cont::SduSafetyState::kUnbiasing || state == cont::SduSafetyState::kHold ||
         state == cont::SduSafetyState::kContact;
}

}  // namespace

SduController::SduController(SduContinuum& robot)
    : robot_(robot), supervisor_(robot.settings_.model, kSdus, robot.settings_.supervisor) {
  poses_.fill(Eigen::Isometry3d::Identity());
}

void SduController::sense(ControlContext& ctx) noexcept {
  ++tick_;
  samples_ = robot_.samples_.load();
  if (const auto v = robot_.planes_.version(); v != planes_version_) {
    planes_version_ = v;
    const auto set = robot_.planes_.load();
    std::array<cont::Plane, cont::SduSupervisor::kMaxPlanes> planes{};
    const std::size_t n = std::min(set.count, planes.size());
    for (std::size_t k = 0; k < n; ++k) {
      planes[k].normal = Eigen::Vector3d(set.plane[k][0], set.plane[k][1], set.plane[k][2]);
      planes[k].offset_mm = set.plane[k][3];
    }
    supervisor_.set_planes(std::span<const cont::Plane>(planes.data(), n), set.inlier_mm);
  }
  // The disks are where the joints measure them (the readings were taken there).
  poses_ = cont::disk_poses(robot_.settings_.model, segment_configuration(ctx.q));
  const auto& d = supervisor_.step(ctx.now_ns, poses_, samples_.disk);
  // Every change of the supervisor's state goes to the robot's event log (its holds are logged again
  // below, as holds, when they stop a moving robot).
  supervisor_.events().drain([&](const safety::SafetyEvent& e) {
    const auto kind = e.kind == safety::EventKind::kHold ? safety::EventKind::kWarning : e.kind;
    ctx.supervisor->record(ctx.t, kind, e.code, -1, e.text);
  });
  if (ctx.state != OperatingState::kEnabled || !ctx.drives_ready || !holds(d.state)) return;
  // Stop in this cycle: the hold keeps the setpoint where it is before any mode moves it.
  char detail[96];
  cont::describe(d, detail, sizeof detail);
  ctx.hold(hold_code(d.cause), -1, detail);
}

void SduController::integrate(ControlContext& ctx, const Eigen::Vector3d& rates) noexcept {
  // Keep the direction: one factor for all joints brings the fastest within its velocity limit.
  double k = 1.0;
  for (std::size_t j = 0; j < kSduJoints; ++j) {
    const double r = std::abs(rates[static_cast<Eigen::Index>(j)]);
    if (r > ctx.limits->max_velocity[j]) k = std::min(k, ctx.limits->max_velocity[j] / r);
  }
  if (!rates.allFinite()) k = 0.0;
  for (std::size_t j = 0; j < kSduJoints; ++j) {
    const double r = k * rates[static_cast<Eigen::Index>(j)];
    ctx.qd_des[j] = r;
    ctx.q_des[j] += r * ctx.period;
  }
}

Eigen::Vector3d SduController::rates_for_velocity(std::span<const double> q, std::size_t disk,
                                                  const Eigen::Vector3d& v) const noexcept {
  const auto& model = robot_.settings_.model;
  std::array<double, kSduJoints> qq{q[0], q[1], q[2]};
  const Eigen::Vector3d p0 = cont::disk_pose(model, segment_configuration(qq), disk).translation();
  Eigen::Matrix3d J;
  for (std::size_t j = 0; j < kSduJoints; ++j) {
    auto qp = qq;
    qp[j] += kJacobianStep;
    J.col(static_cast<Eigen::Index>(j)) =
        (cont::disk_pose(model, segment_configuration(qp), disk).translation() - p0) / kJacobianStep;
  }
  const Eigen::Matrix3d A = J * J.transpose() + kDamping * kDamping * Eigen::Matrix3d::Identity();
  return J.transpose() * A.ldlt().solve(v);
}

Eigen::Vector3d SduController::rates_for_twist(std::span<const double> q, std::size_t disk,
                                               const Eigen::Matrix<double, 6, 1>& twist) const noexcept {
  const auto& model = robot_.settings_.model;
  std::array<double, kSduJoints> qq{q[0], q[1], q[2]};
  const Eigen::Isometry3d h0 = cont::disk_pose(model, segment_configuration(qq), disk);
  Eigen::Matrix<double, 6, 3> J;
  for (std::size_t j = 0; j < kSduJoints; ++j) {
    auto qp = qq;
    qp[j] += kJacobianStep;
    const Eigen::Isometry3d h1 = cont::disk_pose(model, segment_configuration(qp), disk);
    const Eigen::AngleAxisd turn(h1.linear() * h0.linear().transpose());
    J.block<3, 1>(0, static_cast<Eigen::Index>(j)) = (h1.translation() - h0.translation()) / kJacobianStep;
    J.block<3, 1>(3, static_cast<Eigen::Index>(j)) = turn.axis() * turn.angle() / kJacobianStep;
  }
  // Rotation rows weighted by the disk radius: a radian of turn counts as the rim's travel.
  Eigen::Matrix<double, 6, 1> w;
  const double r = model.disk_radius_mm;
  w << 1.0, 1.0, 1.0, r, r, r;
  const Eigen::Matrix<double, 6, 3> WJ = w.asDiagonal() * J;
  const Eigen::Matrix3d A = WJ.transpose() * WJ + kDamping * kDamping * Eigen::Matrix3d::Identity();
  const Eigen::Matrix<double, 6, 1> wt = w.asDiagonal() * twist;
  return A.ldlt().solve(WJ.transpose() * wt);
}

double SduController::max_window_step(std::span<const double> a, std::span<const double> b) const noexcept {
  const auto& model = robot_.settings_.model;
  const auto pa = cont::disk_poses(model, segment_configuration(a));
  const auto pb = cont::disk_poses(model, segment_configuration(b));
  double step = 0.0;
  for (std::size_t i = 0; i < kSdus; ++i)
    for (std::size_t j = 0; j < cont::kTofPerSdu; ++j) {
      const Eigen::Vector3d w = cont::tof_sensor_in_disk(model, j).translation();
      step = std::max(step, (pb[i] * w - pa[i] * w).norm());
    }
  return step;
}

void SduController::control(ControlContext& ctx) noexcept {
  guidance_mm_s_ = 0.0;
  for (std::size_t j = 0; j < ctx.n; ++j) ctx.qd_des[j] = 0.0;
  if (ctx.mode != kGuidanceMode || hri_ == cont::GuidanceMode::kOff) return;
  const std::size_t top = kSdus - 1;
  const auto& s = robot_.settings_;
  guidance_mm_s_ =
      cont::guidance_command(hri_, s.guidance, s.guidance_pair, samples_.disk[top], supervisor_.bias()[top]);
  if (guidance_mm_s_ == 0.0) return;
  // Positive towards the right window: along its line of sight, in {0}.
  const Eigen::Vector3d right =
      poses_[top].linear() * cont::tof_sensor_in_disk(s.model, s.guidance_pair.tof_right).linear().col(2);
  integrate(ctx, rates_for_velocity(ctx.q_des, top, guidance_mm_s_ * right));
}

bool SduController::while_held(ControlContext& ctx) noexcept {
  guidance_mm_s_ = 0.0;
  const auto& d = supervisor_.decision();
  if (d.state != cont::SduSafetyState::kContact) return false;
  const auto& s = robot_.settings_;
  if (roll_until_ > ctx.t && roll_rate_ != 0.0 && d.contact.disk >= 0) {
    // (3.6): roll about the contact without slipping, at most the retreat speed at the disk's centre.
    const auto disk = static_cast<std::size_t>(d.contact.disk);
    const double omega = cont::apply_sdu_roll(d, s.supervisor, roll_rate_);
    const auto twist = cont::no_slip_roll_twist(d.contact.from_centre, poses_[disk].linear().col(2), omega);
    integrate(ctx, rates_for_twist(ctx.q_des, disk, twist));
    return true;
  }
  if (ctx.mode == kGuidanceMode && hri_ == cont::GuidanceMode::kContactBased) {
    // Yield to the push: the contact law's command, of which only the part straight away from the
    // contact survives (apply_sdu_safety), at most the retreat speed.
    const std::size_t top = kSdus - 1;
    guidance_mm_s_ = cont::guidance_command(hri_, s.guidance, s.guidance_pair, samples_.disk[top],
                                            supervisor_.bias()[top]);
    const Eigen::Vector3d right =
        poses_[top].linear() * cont::tof_sensor_in_disk(s.model, s.guidance_pair.tof_right).linear().col(2);
    const Eigen::Vector3d v = cont::apply_sdu_safety(d, s.supervisor, guidance_mm_s_ * right);
    if (v.squaredNorm() == 0.0) return false;
    integrate(ctx, rates_for_velocity(ctx.q_des, top, v));
    return true;
  }
  return false;
}

void SduController::apply(ControlContext& ctx, const PluginCommand& command) noexcept {
  switch (static_cast<SduCommand>(command.id)) {
    case SduCommand::hri_mode: {
      const auto m = static_cast<int>(command.values[0]);
      hri_ = m == 1 ? cont::GuidanceMode::kContactless
                    : (m == 2 ? cont::GuidanceMode::kContactBased : cont::GuidanceMode::kOff);
      break;
    }
    case SduCommand::roll:
      // A stream like servo_jv: it stops when not refreshed within the servo timeout.
      roll_rate_ = command.values[0];
      roll_until_ = ctx.t + ctx.limits->servo_timeout_s;
      break;
    case SduCommand::unbias:
      supervisor_.request_unbias();
      break;
  }
}

bool SduController::moving(const ControlContext& ctx) const noexcept {
  return (roll_until_ > ctx.t && roll_rate_ != 0.0) || guidance_mm_s_ != 0.0;
}

bool SduController::hold_cleared(const ControlContext& ctx, char* why, std::size_t why_size) const noexcept {
  (void)ctx;
  const auto& d = supervisor_.decision();
  if (!holds(d.state)) return true;
  if (why && why_size > 0) cont::describe(d, why, why_size);
  return false;
}

double SduController::limit_step(ControlContext& ctx, std::span<const double> before) noexcept {
  const double step = max_window_step(before, ctx.q_des);
  const double speed = step / ctx.period;
  step_kept_ = 1.0;
  // A held motion is one of the contact hold's own ways out, capped by its law already.
  if (ctx.state == OperatingState::kEnabled) {
    const double limit = supervisor_.decision().speed_limit_mm_s;
    if (speed > limit * (1.0 + 1e-9)) {
      step_kept_ = speed > 0.0 ? std::clamp(limit / speed, 0.0, 1.0) : 0.0;
      for (std::size_t j = 0; j < ctx.n; ++j) {
        ctx.q_des[j] = before[j] + step_kept_ * (ctx.q_des[j] - before[j]);
        ctx.qd_des[j] *= step_kept_;
      }
    }
  }
  surface_speed_ = speed * step_kept_;
  return step_kept_;
}

void SduController::publish(const ControlContext& ctx) noexcept {
  const auto& d = supervisor_.decision();
  SduSnapshot s;
  s.tick = tick_;
  s.now_ns = ctx.now_ns;
  for (std::size_t j = 0; j < kSduJoints && j < ctx.n; ++j) s.q[j] = ctx.q[j];
  s.state = d.state;
  s.cause = d.cause;
  s.cause_disk = d.disk;
  s.cause_slot = d.slot;
  s.cause_value = d.value;
  s.speed_limit_mm_s = d.speed_limit_mm_s;
  s.nearest_mm = d.nearest_d_e_mm;
  s.step_kept = step_kept_;
  s.surface_speed_mm_s = surface_speed_;
  s.contact = d.state == cont::SduSafetyState::kContact;
  s.contact_disk = s.contact ? d.contact.disk : -1;
  s.contact_slot = s.contact ? d.contact.slot : -1;
  s.contact_force_n = s.contact ? d.contact.force_n : 0.0;
  s.hri = hri_;
  s.guidance_mm_s = guidance_mm_s_;
  s.rolling = roll_until_ > ctx.t && roll_rate_ != 0.0;
  const auto stale = robot_.settings_.supervisor.stale_after_ns;
  for (std::size_t i = 0; i < kSdus; ++i) {
    const auto& sample = samples_.disk[i];
    s.age_ns[i] = sample.received ? ctx.now_ns - sample.stamp_ns : -1;
    s.fresh[i] = sample.received && s.age_ns[i] <= stale;
    s.forces_n[i] = supervisor_.forces()[i];
  }
  cont::describe(d, s.reason, sizeof s.reason);
  robot_.published_.store(s);
  step_kept_ = 1.0;
  surface_speed_ = 0.0;
}

}  // namespace tendril::server
