// The SDU safety laws (Abah 2022, §3.4 and §3.6) as the control thread applies them: pure functions
// and one small supervisor, all noexcept and allocation-free. They sit in the safety path: a robot
// type built on them passes every commanded velocity through apply_sdu_safety(), whatever its mode, so
// no mode can bypass proximity scaling, stop on contact or the sensor fault states.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <span>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_perception.hpp"
#include "tendril/continuum/sdu_segment.hpp"
#include "tendril/safety/safety_event_log.hpp"

namespace tendril::continuum {

// --- laws ---------------------------------------------------------------------------------------------

struct ProximityParameters {
  double v_max_mm_s = 50.0;  // Abah 2022, §3.4
  double v_min_mm_s = 0.25;  // Abah 2022, §3.4
  // The dissertation leaves d_max open between the nominal 100 mm and the measured usable 130 mm; tendril
  // takes 130 mm: the robot starts slowing at the first reading it can trust, which is the safer side.
  double d_max_mm = 130.0;
};

// (3.5) d_e = d·cos θ, θ the sensor's angle to the surface normal.
double effective_distance(double range_mm, double angle_to_normal_rad) noexcept;
// (3.4) ‖v‖ = (d_e/d_max)(v_max − v_min) + v_min for d_e < d_max, else v_max. A d_e that is negative
// or not finite gives v_min (the safe speed).
double proximity_speed_limit(const ProximityParameters& p, double d_e_mm) noexcept;
// The command with its direction kept and its magnitude capped at limit; zero for a non-finite command
// or limit.
Eigen::Vector3d cap_speed(const Eigen::Vector3d& v, double limit_mm_s) noexcept;

// (3.6) The twist [v; ω] of the disk frame for a no-slip roll about the contact: ω = ẑ·ω_z and
// v = [r_c]×ẑ·ω_z, so the contact point (disk centre + r_c) does not move. The plug-in maps it to
// joint rates with its Jacobian's (pseudo-)inverse (the dissertation prints J where J⁻¹ is meant).
Eigen::Matrix<double, 6, 1> no_slip_roll_twist(const Eigen::Vector3d& r_c, const Eigen::Vector3d& z_hat,
                                               double omega_z_rad_s) noexcept;

// Operator-selectable guidance (HRI) modes of the top SDU (Abah 2022, §3.6.2).
enum class GuidanceMode : std::uint8_t { kOff, kContactless, kContactBased };
const char* to_string(GuidanceMode mode) noexcept;

struct GuidanceParameters {
  double gain = 0.5;           // γ: mm/s per mm (contactless) — the dissertation tuned it by hand
  double contact_gain = 20.0;  // γ: mm/s per mT (contact-based)
  double deadband_mm = 2.0;    // |d_r − d_l| below this commands nothing
  double contact_deadband_mT = 0.05;
  double max_speed_mm_s = 20.0;       // the guidance never asks for more; the safety laws may cap further
  double no_target_range_mm = 130.0;  // what a side that sees nothing (NaN) counts as
};
// (3.8) v = γ(d_r − d_l): positive towards the right sensor, so a hand near the left sensor moves the
// robot right, away from it. A side that sees nothing reads as the farthest usable range.
double contactless_guidance(const GuidanceParameters& p, double d_right_mm, double d_left_mm) noexcept;
// (3.9) v = γ(ΔB_z,r − ΔB_z,l), here returned positive towards the right as well, i.e. −γ(ΔB_z,r − ΔB_z,l):
// a push on the right sensor moves the robot left, yielding to it. (The dissertation's two laws differ in
// the sign of γ, which it leaves to tuning; tendril fixes one direction for both.)
double contact_guidance(const GuidanceParameters& p, double dBz_right_mT, double dBz_left_mT) noexcept;

// --- supervisor ---------------------------------------------------------------------------------------

enum class SduSafetyState : std::uint8_t {
  kUnbiasing,  // collecting the Hall baseline; the robot holds
  kClear,      // proximity scaling only
  kSlowed,     // a sensor cannot vouch for its direction: safe speed v_min
  kContact,    // a Hall window is pressed: stopped; only retreat and the no-slip roll
  kHold,       // a disk is silent, a Hall reading is unusable or a baseline drifted: the robot holds
};
const char* to_string(SduSafetyState state) noexcept;

enum class SduCause : std::uint8_t {
  kNone,
  kUnbiasing,
  kSduSilent,
  kHallInvalid,  // error code, not finite, or beyond the plausible field
  kTofInvalid,   // error code, not finite, negative or beyond the wire's span
  kContact,
  kBaselineDrift,
};
const char* to_string(SduCause cause) noexcept;

struct SduSupervisorParameters {
  ProximityParameters proximity{};
  std::int64_t stale_after_ns = 30'000'000;  // three 100 Hz samples
  std::size_t unbias_samples = 50;           // 0.5 s at 100 Hz
  double contact_threshold_n = 0.5;          // ≈ 0.13 mT: 26 σ of the simulated Hall noise
  double contact_release_n = 0.25;           // hysteresis
  double slope_mT_per_N = kHallSlopeMilliTeslaPerNewton;
  double max_plausible_field_mT = 200.0;  // |B| beyond this on any axis is a broken sensor
  double max_tof_mm = 253.0;              // the wire's span: beyond it a value is corrupt
  // Drift: the low-passed baseline-corrected field (all axes) staying beyond drift_bound_mT for
  // drift_time_s while no contact is seen means the zero has moved under the contact threshold.
  double drift_bound_mT = 0.06;
  double drift_filter_s = 0.5;
  double drift_time_s = 2.0;
  double retreat_speed_mm_s = 5.0;  // while in contact, motion straight away from it, at most this fast
};

struct SduSafetyDecision {
  SduSafetyState state = SduSafetyState::kUnbiasing;
  SduCause cause = SduCause::kUnbiasing;
  int disk = -1;  // where the cause is, when it is one place
  int slot = -1;
  double speed_limit_mm_s = 0.0;  // for free motion
  double nearest_d_e_mm = 0.0;    // nearest effective distance seen (d_max when nothing is near)
  ContactLocation contact{};      // valid in kContact
  double value = 0.0;             // the number behind the cause (ms silent, N, mT)
};
// Writes a sentence for a person ("SDU 3 silent for 42 ms: holding") into buf; returns buf.
const char* describe(const SduSafetyDecision& d, char* buf, std::size_t size) noexcept;

// Runs once per control cycle on the newest sample of every disk. Allocation-free after construction;
// every change of state or cause is pushed to the event log with its sentence.
class SduSupervisor {
 public:
  // Throws std::invalid_argument for a disk count outside 1..kSdusPerSegment or parameters that are not
  // positive and finite where they must be.
  SduSupervisor(const SduSegmentModel& model, std::size_t disks, const SduSupervisorParameters& p);

  // One cycle at now_ns with the disks' poses (for contact localisation) and newest samples.
  const SduSafetyDecision& step(std::int64_t now_ns, std::span<const Eigen::Isometry3d> disk_poses,
                                std::span<const SduSample> samples) noexcept;
  // Starts a new unbiasing (operator command, e.g. after a drift hold). Refused (false) in contact.
  bool request_unbias() noexcept;
  // The mapped planes (from the map's RANSAC, on a worker) that give (3.5) its θ: a range whose point
  // lies within the inlier distance of a plane counts as d_e = d·|cos θ|, θ between the sensor's line
  // of sight and the plane's normal; other ranges count as d_e = d. Keeps the first kMaxPlanes; copies,
  // no allocation. An empty span forgets them. Call it on the control thread, between steps (the
  // plug-in hands the worker's planes over through a latest-value slot).
  static constexpr std::size_t kMaxPlanes = 8;
  void set_planes(std::span<const Plane> planes, double inlier_distance_mm = 40.0) noexcept;

  const SduSafetyDecision& decision() const noexcept { return decision_; }
  const std::array<HallBias, kSdusPerSegment>& bias() const noexcept { return bias_; }
  const std::array<std::array<double, kHallPerSdu>, kSdusPerSegment>& forces() const noexcept {
    return forces_;
  }
  safety::SafetyEventLog& events() noexcept { return events_; }

 private:
  void log_change(std::int64_t now_ns, const SduSafetyDecision& before) noexcept;
  SduSegmentModel model_;
  std::size_t disks_;
  SduSupervisorParameters p_;
  SduSafetyDecision decision_{};
  std::array<HallUnbiaser, kSdusPerSegment> unbiaser_{};
  std::array<HallBias, kSdusPerSegment> bias_{};
  std::array<std::array<double, kHallPerSdu>, kSdusPerSegment> forces_{};
  std::array<std::array<Eigen::Vector3d, kHallPerSdu>, kSdusPerSegment> drift_filter_{};
  std::array<std::array<double, kHallPerSdu>, kSdusPerSegment> drift_since_s_{};
  std::array<std::int64_t, kSdusPerSegment> last_stamp_{};
  bool unbiased_ = false;
  bool drift_latched_ = false;
  int drift_disk_ = -1, drift_slot_ = -1;
  double drift_value_ = 0.0;
  bool in_contact_ = false;
  bool logged_any_ = false;
  std::array<Plane, kMaxPlanes> planes_{};
  std::size_t plane_count_ = 0;
  double plane_inlier_mm_ = 40.0;  // the first cycle's state is logged whatever it is
  std::int64_t last_step_ns_ = 0;
  safety::SafetyEventLog events_;
};

// The commanded Cartesian velocity (mm/s, {0}) after the supervisor's decision: zero while unbiasing or
// holding; in contact only its part straight away from the contact (−normal), capped at the retreat
// speed; v_min when slowed; the proximity limit when clear.
Eigen::Vector3d apply_sdu_safety(const SduSafetyDecision& d, const SduSupervisorParameters& p,
                                 const Eigen::Vector3d& v_cmd) noexcept;

// The no-slip roll's rate after the supervisor: allowed only in contact (it rolls about the contact the
// decision names), with the disk centre's speed |ω_z|·|r_c| at most the retreat speed; zero otherwise.
double apply_sdu_roll(const SduSafetyDecision& d, const SduSupervisorParameters& p,
                      double omega_z_rad_s) noexcept;

// Which windows of the top SDU are the operator's right and left (Abah 2022, §3.6.2 leaves the choice open):
// tendril's default looks across the bending plane's y axis, ToF slots 6 (270°) and 2 (90°) and the
// Hall windows beside them, 5 (247.5°) and 1 (67.5°).
struct GuidancePair {
  std::size_t tof_right = 6, tof_left = 2;
  std::size_t hall_right = 5, hall_left = 1;
};
// The guidance speed of the selected mode from the top disk's sample (positive towards the right):
// contactless from the two ranges (a side without a valid range counts as seeing nothing), contact-based
// from the two windows' ΔB_z against the baseline; 0 when off, for an unusable Hall reading or slots
// out of range.
double guidance_command(GuidanceMode mode, const GuidanceParameters& g, const GuidancePair& pair,
                        const SduSample& top, const HallBias& bias) noexcept;

}  // namespace tendril::continuum
