#include "tendril/continuum/sdu_safety.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <stdexcept>
#include <string>

namespace tendril::continuum {

double effective_distance(double range_mm, double angle_to_normal_rad) noexcept {
  return range_mm * std::cos(angle_to_normal_rad);
}

double proximity_speed_limit(const ProximityParameters& p, double d_e) noexcept {
  if (!std::isfinite(d_e) || d_e < 0.0) return p.v_min_mm_s;
  if (d_e >= p.d_max_mm) return p.v_max_mm_s;
  return d_e / p.d_max_mm * (p.v_max_mm_s - p.v_min_mm_s) + p.v_min_mm_s;
}

Eigen::Vector3d cap_speed(const Eigen::Vector3d& v, double limit) noexcept {
  if (!v.allFinite() || !std::isfinite(limit) || limit <= 0.0) return Eigen::Vector3d::Zero();
  const double n = v.norm();
  return n <= limit ? v : Eigen::Vector3d(v * (limit / n));
}

Eigen::Matrix<double, 6, 1> no_slip_roll_twist(const Eigen::Vector3d& r_c, const Eigen::Vector3d& z_hat,
                                               double omega_z) noexcept {
  Eigen::Matrix<double, 6, 1> twist = Eigen::Matrix<double, 6, 1>::Zero();
  if (!r_c.allFinite() || !z_hat.allFinite() || !std::isfinite(omega_z) || z_hat.norm() < 1e-9) return twist;
  const Eigen::Vector3d z = z_hat.normalized();
  twist.head<3>() = r_c.cross(z) * omega_z;  // [r_c]× ẑ ω_z
  twist.tail<3>() = z * omega_z;
  return twist;
}

const char* to_string(GuidanceMode mode) noexcept {
  switch (mode) {
    case GuidanceMode::kOff:
      return "off";
    case GuidanceMode::kContactless:
      return "contactless";
    case GuidanceMode::kContactBased:
      return "contact_based";
  }
  return "unknown";
}

namespace {
double saturate(double v, double limit) noexcept { return std::clamp(v, -limit, limit); }
}  // namespace

double contactless_guidance(const GuidanceParameters& p, double d_right, double d_left) noexcept {
  const double r =
      std::isfinite(d_right) ? std::clamp(d_right, 0.0, p.no_target_range_mm) : p.no_target_range_mm;
  const double l =
      std::isfinite(d_left) ? std::clamp(d_left, 0.0, p.no_target_range_mm) : p.no_target_range_mm;
  const double diff = r - l;
  if (std::abs(diff) < p.deadband_mm || !std::isfinite(p.gain)) return 0.0;
  return saturate(p.gain * diff, p.max_speed_mm_s);
}

double contact_guidance(const GuidanceParameters& p, double dbz_right, double dbz_left) noexcept {
  if (!std::isfinite(dbz_right) || !std::isfinite(dbz_left) || !std::isfinite(p.contact_gain)) return 0.0;
  const double diff = dbz_right - dbz_left;
  if (std::abs(diff) < p.contact_deadband_mT) return 0.0;
  return saturate(-p.contact_gain * diff, p.max_speed_mm_s);
}

const char* to_string(SduSafetyState state) noexcept {
  switch (state) {
    case SduSafetyState::kUnbiasing:
      return "unbiasing";
    case SduSafetyState::kClear:
      return "clear";
    case SduSafetyState::kSlowed:
      return "slowed";
    case SduSafetyState::kContact:
      return "contact";
    case SduSafetyState::kHold:
      return "hold";
  }
  return "unknown";
}

const char* to_string(SduCause cause) noexcept {
  switch (cause) {
    case SduCause::kNone:
      return "none";
    case SduCause::kUnbiasing:
      return "unbiasing";
    case SduCause::kSduSilent:
      return "sdu_silent";
    case SduCause::kHallInvalid:
      return "hall_invalid";
    case SduCause::kTofInvalid:
      return "tof_invalid";
    case SduCause::kContact:
      return "contact";
    case SduCause::kBaselineDrift:
      return "baseline_drift";
  }
  return "unknown";
}

const char* describe(const SduSafetyDecision& d, char* buf, std::size_t size) noexcept {
  if (size == 0) return buf;
  switch (d.cause) {
    case SduCause::kNone:
      std::snprintf(buf, size, "SDU sensors clear: nearest %.0f mm, speed limit %.2f mm/s", d.nearest_d_e_mm,
                    d.speed_limit_mm_s);
      break;
    case SduCause::kUnbiasing:
      std::snprintf(buf, size, "Hall unbiasing at start-up (%.0f samples so far): holding", d.value);
      break;
    case SduCause::kSduSilent:
      if (d.value < 0.0)
        std::snprintf(buf, size, "SDU %d has sent no sample yet: holding", d.disk);
      else
        std::snprintf(buf, size, "SDU %d silent for %.0f ms: holding", d.disk, d.value);
      break;
    case SduCause::kHallInvalid:
      std::snprintf(buf, size,
                    "SDU %d Hall %d reading unusable (sensor error, not finite or implausible): holding",
                    d.disk, d.slot);
      break;
    case SduCause::kTofInvalid:
      std::snprintf(
          buf, size,
          "SDU %d ToF %d reading unusable (sensor error, not finite or out of range): slowed to %.2f mm/s",
          d.disk, d.slot, d.speed_limit_mm_s);
      break;
    case SduCause::kContact:
      std::snprintf(buf, size, "contact on SDU %d Hall %d (%.1f deg), %.2f N: stopped", d.disk, d.slot,
                    d.contact.slot_angle_rad * 180.0 / M_PI, d.value);
      break;
    case SduCause::kBaselineDrift:
      std::snprintf(buf, size, "SDU %d Hall %d baseline drifted %.3f mT: holding until unbiased again",
                    d.disk, d.slot, d.value);
      break;
  }
  return buf;
}

SduSupervisor::SduSupervisor(const SduSegmentModel& model, std::size_t disks,
                             const SduSupervisorParameters& p)
    : model_(model), disks_(disks), p_(p) {
  model_.validate();
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (disks == 0 || disks > kSdusPerSegment)
    throw std::invalid_argument("SDU supervisor: disks must be 1.." + std::to_string(kSdusPerSegment) +
                                ", got " + std::to_string(disks));
  if (!positive(p.proximity.d_max_mm) || !positive(p.proximity.v_max_mm_s) ||
      !positive(p.proximity.v_min_mm_s) || p.proximity.v_min_mm_s > p.proximity.v_max_mm_s)
    throw std::invalid_argument("SDU supervisor: proximity needs 0 < v_min <= v_max and d_max > 0");
  if (p.stale_after_ns <= 0 || p.unbias_samples == 0)
    throw std::invalid_argument("SDU supervisor: stale_after_ns and unbias_samples must be positive");
  if (!positive(p.contact_threshold_n) || !positive(p.contact_release_n) ||
      p.contact_release_n > p.contact_threshold_n)
    throw std::invalid_argument("SDU supervisor: need 0 < contact_release_n <= contact_threshold_n");
  if (!positive(p.slope_mT_per_N) || !positive(p.max_plausible_field_mT) || !positive(p.max_tof_mm) ||
      !positive(p.drift_bound_mT) || !positive(p.drift_filter_s) || !positive(p.drift_time_s) ||
      !positive(p.retreat_speed_mm_s))
    throw std::invalid_argument(
        "SDU supervisor: slope, field bound, ToF span, drift and retreat parameters must be positive");
  for (auto& disk : drift_filter_) disk.fill(Eigen::Vector3d::Zero());
  decision_.state = SduSafetyState::kUnbiasing;
  decision_.cause = SduCause::kUnbiasing;
}

void SduSupervisor::set_planes(std::span<const Plane> planes, double inlier_distance_mm) noexcept {
  plane_count_ = 0;
  plane_inlier_mm_ =
      std::isfinite(inlier_distance_mm) && inlier_distance_mm > 0.0 ? inlier_distance_mm : 40.0;
  for (const auto& p : planes) {
    if (plane_count_ == kMaxPlanes) break;
    if (!p.normal.allFinite() || !std::isfinite(p.offset_mm) || std::abs(p.normal.norm() - 1.0) > 1e-6)
      continue;
    planes_[plane_count_++] = p;
  }
}

bool SduSupervisor::request_unbias() noexcept {
  if (decision_.state == SduSafetyState::kContact) return false;
  unbiased_ = false;
  drift_latched_ = false;
  for (auto& u : unbiaser_) u.reset();
  return true;
}

const SduSafetyDecision& SduSupervisor::step(std::int64_t now_ns, std::span<const Eigen::Isometry3d> poses,
                                             std::span<const SduSample> samples) noexcept {
  const SduSafetyDecision before = decision_;
  const double dt =
      last_step_ns_ != 0 ? std::max(0.0, static_cast<double>(now_ns - last_step_ns_) * 1e-9) : 0.0;
  last_step_ns_ = now_ns;
  SduSafetyDecision d;
  d.nearest_d_e_mm = p_.proximity.d_max_mm;
  auto set = [&](SduSafetyState state, SduCause cause, int disk, int slot, double value) {
    d.state = state;
    d.cause = cause;
    d.disk = disk;
    d.slot = slot;
    d.value = value;
  };
  const std::size_t n = std::min({disks_, samples.size(), poses.size()});
  bool decided = false;

  // 1. A disk that is silent (or missing from the input) holds the robot: it can neither see nor feel.
  for (std::size_t i = 0; i < disks_ && !decided; ++i) {
    if (i >= n || !samples[i].received) {
      set(SduSafetyState::kHold, SduCause::kSduSilent, static_cast<int>(i), -1, -1.0);
      decided = true;
    } else if (now_ns - samples[i].stamp_ns > p_.stale_after_ns) {
      set(SduSafetyState::kHold, SduCause::kSduSilent, static_cast<int>(i), -1,
          static_cast<double>(now_ns - samples[i].stamp_ns) * 1e-6);
      decided = true;
    }
  }
  // 2. A Hall reading that cannot be used: that window cannot feel a contact.
  for (std::size_t i = 0; i < n && !decided; ++i) {
    for (std::size_t j = 0; j < kHallPerSdu && !decided; ++j) {
      bool ok = samples[i].hall_ok[j];
      for (double b : samples[i].hall_mT[j])
        ok = ok && std::isfinite(b) && std::abs(b) <= p_.max_plausible_field_mT;
      if (!ok) {
        set(SduSafetyState::kHold, SduCause::kHallInvalid, static_cast<int>(i), static_cast<int>(j), 0.0);
        decided = true;
      }
    }
  }
  const bool sensors_ok = !decided;
  std::array<bool, kSdusPerSegment> fresh{};
  for (std::size_t i = 0; i < n; ++i) {
    fresh[i] = samples[i].stamp_ns != last_stamp_[i];
    last_stamp_[i] = samples[i].stamp_ns;
  }

  // 3. Unbiasing: the baseline comes from fresh, valid samples only.
  if (!unbiased_) {
    std::size_t least = p_.unbias_samples;
    if (sensors_ok) {
      for (std::size_t i = 0; i < disks_; ++i) {
        if (fresh[i]) unbiaser_[i].add(samples[i]);
        least = std::min(least, unbiaser_[i].count());
      }
      if (least >= p_.unbias_samples) {
        for (std::size_t i = 0; i < disks_; ++i) bias_[i] = unbiaser_[i].bias();
        for (auto& disk : drift_filter_) disk.fill(Eigen::Vector3d::Zero());
        for (auto& disk : drift_since_s_) disk.fill(0.0);
        unbiased_ = true;
        in_contact_ = false;
      }
    } else {
      least = 0;
    }
    if (!unbiased_ && !decided) {
      set(SduSafetyState::kUnbiasing, SduCause::kUnbiasing, -1, -1, static_cast<double>(least));
      decided = true;
    }
  }

  if (unbiased_ && sensors_ok) {
    // 4. Forces and contact (with hysteresis), then 5. drift of the baseline.
    for (std::size_t i = 0; i < n; ++i) forces_[i] = hall_forces(samples[i], bias_[i], p_.slope_mT_per_N);
    const auto contact = locate_contact(model_, poses.first(n), std::span(forces_).first(n),
                                        in_contact_ ? p_.contact_release_n : p_.contact_threshold_n);
    in_contact_ = contact.contact;
    const double alpha = std::min(1.0, dt / p_.drift_filter_s);
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t j = 0; j < kHallPerSdu; ++j) {
        const Eigen::Vector3d db(samples[i].hall_mT[j][0] - bias_[i].b0_mT[j][0],
                                 samples[i].hall_mT[j][1] - bias_[i].b0_mT[j][1],
                                 samples[i].hall_mT[j][2] - bias_[i].b0_mT[j][2]);
        auto& f = drift_filter_[i][j];
        f += alpha * (db - f);
        const bool beyond = f.norm() > p_.drift_bound_mT && !(forces_[i][j] >= p_.contact_release_n);
        drift_since_s_[i][j] = beyond ? drift_since_s_[i][j] + dt : 0.0;
        if (!drift_latched_ && drift_since_s_[i][j] >= p_.drift_time_s && !in_contact_) {
          drift_latched_ = true;
          drift_disk_ = static_cast<int>(i);
          drift_slot_ = static_cast<int>(j);
          drift_value_ = f.norm();
        }
      }
    }
    if (contact.contact) {
      set(SduSafetyState::kContact, SduCause::kContact, contact.disk, contact.slot, contact.force_n);
      d.contact = contact;
      decided = true;
    } else if (drift_latched_) {
      set(SduSafetyState::kHold, SduCause::kBaselineDrift, drift_disk_, drift_slot_, drift_value_);
      decided = true;
    }
  }

  // 6. Proximity from every usable range; an unusable one slows the robot to the safe speed.
  if (sensors_ok) {
    bool tof_bad = false;
    for (std::size_t i = 0; i < n; ++i) {
      for (std::size_t j = 0; j < kTofPerSdu; ++j) {
        const double r = samples[i].tof_mm[j];
        const TofStatus st = samples[i].tof_status[j];
        if (st == TofStatus::kNoTarget) continue;
        if (st == TofStatus::kSensorError || !std::isfinite(r) || r < 0.0 || r > p_.max_tof_mm) {
          if (!tof_bad && !decided)
            set(SduSafetyState::kSlowed, SduCause::kTofInvalid, static_cast<int>(i), static_cast<int>(j),
                0.0);
          tof_bad = true;
          continue;
        }
        double d_e = r;
        if (plane_count_ > 0 && i < poses.size()) {
          // The dissertation's (3.5): the sensor's angle to the normal of the mapped surface its range lands
          // on.
          const Eigen::Isometry3d sensor = poses[i] * tof_sensor_in_disk(model_, j);
          const Eigen::Vector3d axis = sensor.linear().col(2);
          const Eigen::Vector3d hit = sensor.translation() + r * axis;
          double nearest = plane_inlier_mm_;
          for (std::size_t k = 0; k < plane_count_; ++k) {
            const double off = std::abs(planes_[k].distance(hit));
            if (off <= nearest) {
              nearest = off;
              d_e = r * std::abs(axis.dot(planes_[k].normal));
            }
          }
        }
        d.nearest_d_e_mm = std::min(d.nearest_d_e_mm, d_e);
      }
    }
    if (tof_bad) decided = true;
  }
  if (!decided) set(SduSafetyState::kClear, SduCause::kNone, -1, -1, 0.0);

  switch (d.state) {
    case SduSafetyState::kClear:
      d.speed_limit_mm_s = proximity_speed_limit(p_.proximity, d.nearest_d_e_mm);
      break;
    case SduSafetyState::kSlowed:
      d.speed_limit_mm_s = p_.proximity.v_min_mm_s;
      break;
    default:
      d.speed_limit_mm_s = 0.0;
      break;
  }
  decision_ = d;
  log_change(now_ns, before);
  return decision_;
}

void SduSupervisor::log_change(std::int64_t now_ns, const SduSafetyDecision& before) noexcept {
  const auto& d = decision_;
  const bool first = !logged_any_;
  logged_any_ = true;
  if (!first && d.state == before.state && d.cause == before.cause && d.disk == before.disk) {
    if (d.slot == before.slot) return;
    // A contact between two neighbouring Hall windows moves its strongest window back and forth with
    // the noise (every 10 ms sample in the simulation): the same contact, not a new event — logging
    // each move flooded the event log with 100 warnings a second. The state still names the window.
    const int apart = std::abs(d.slot - before.slot);
    const int slots = static_cast<int>(kHallPerSdu);
    if (d.cause == SduCause::kContact && (apart == 1 || apart == slots - 1)) return;
  }
  safety::SafetyEvent e;
  e.time = static_cast<double>(now_ns) * 1e-9;
  switch (d.state) {
    case SduSafetyState::kClear:
      e.kind = safety::EventKind::kRecovery;
      break;
    case SduSafetyState::kSlowed:
      e.kind = safety::EventKind::kWarning;
      break;
    default:
      e.kind = safety::EventKind::kHold;
      break;
  }
  switch (d.cause) {
    case SduCause::kSduSilent:
      e.code = safety::FaultCode::kSensorStale;
      break;
    case SduCause::kHallInvalid:
    case SduCause::kTofInvalid:
      e.code = safety::FaultCode::kInvalidMeasurement;
      break;
    case SduCause::kNone:
      e.code = safety::FaultCode::kNone;
      break;
    default:
      e.code = safety::FaultCode::kExternal;
      break;
  }
  describe(d, e.text, sizeof e.text);
  events_.push(e);
}

Eigen::Vector3d apply_sdu_safety(const SduSafetyDecision& d, const SduSupervisorParameters& p,
                                 const Eigen::Vector3d& v) noexcept {
  if (!v.allFinite()) return Eigen::Vector3d::Zero();
  switch (d.state) {
    case SduSafetyState::kClear:
    case SduSafetyState::kSlowed:
      return cap_speed(v, d.speed_limit_mm_s);
    case SduSafetyState::kContact: {
      const Eigen::Vector3d n = d.contact.normal;
      if (!n.allFinite() || n.norm() < 1e-9) return Eigen::Vector3d::Zero();
      const Eigen::Vector3d u = n.normalized();
      const double away = -v.dot(u);
      if (away <= 1e-9) return Eigen::Vector3d::Zero();  // rounding of a sideways command is not a retreat
      return -u * std::min(away, p.retreat_speed_mm_s);
    }
    default:
      return Eigen::Vector3d::Zero();
  }
}

double apply_sdu_roll(const SduSafetyDecision& d, const SduSupervisorParameters& p, double omega) noexcept {
  if (d.state != SduSafetyState::kContact || !std::isfinite(omega)) return 0.0;
  const double lever = d.contact.from_centre.norm();
  if (!std::isfinite(lever) || lever <= 0.0) return 0.0;
  const double limit = p.retreat_speed_mm_s / lever;
  return std::clamp(omega, -limit, limit);
}

double guidance_command(GuidanceMode mode, const GuidanceParameters& g, const GuidancePair& pair,
                        const SduSample& top, const HallBias& bias) noexcept {
  if (!top.received) return 0.0;
  switch (mode) {
    case GuidanceMode::kOff:
      return 0.0;
    case GuidanceMode::kContactless: {
      if (pair.tof_right >= kTofPerSdu || pair.tof_left >= kTofPerSdu) return 0.0;
      auto range = [&](std::size_t j) {
        return top.tof_status[j] == TofStatus::kValid ? top.tof_mm[j]
                                                      : std::numeric_limits<double>::quiet_NaN();
      };
      return contactless_guidance(g, range(pair.tof_right), range(pair.tof_left));
    }
    case GuidanceMode::kContactBased: {
      if (pair.hall_right >= kHallPerSdu || pair.hall_left >= kHallPerSdu) return 0.0;
      if (!top.hall_ok[pair.hall_right] || !top.hall_ok[pair.hall_left]) return 0.0;
      return contact_guidance(g, top.hall_mT[pair.hall_right][2] - bias.b0_mT[pair.hall_right][2],
                              top.hall_mT[pair.hall_left][2] - bias.b0_mT[pair.hall_left][2]);
    }
  }
  return 0.0;
}

}  // namespace tendril::continuum
