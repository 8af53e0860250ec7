// SIMULATION of a CiA 402 servo drive on CANopen. See simulated_drive.hpp.
#include "tendril/drivers/sim/simulated_drive.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace tendril::sim {

using canopen::Cia402State;
using canopen::NmtState;
namespace od = canopen::od;
namespace abort_code = canopen::sdo_abort;
namespace sw = canopen::statusword_bit;

namespace {

constexpr std::uint16_t kDeviceName = 0x1008;
constexpr std::uint16_t kDriveLabel = 0x2000;  // manufacturer area: a writable visible string
constexpr std::uint16_t kFollowingErrorTimeout = 0x6066;
constexpr std::uint16_t kEmcyPdoLength = 0x8210;
constexpr std::uint16_t kEmcyErrorReset = 0x0000;
constexpr std::uint8_t kErrRegGeneric = 0x01;
constexpr std::uint8_t kErrRegCommunication = 0x10;
constexpr std::uint8_t kErrRegProfile = 0x20;
constexpr auto kSdoServerTimeout = std::chrono::seconds(1);

// Private copy of the CiA 402 statusword encoding (bits 0..3, 5, 6), kept here so the simulation
// does not depend on the master's codec it is meant to test.
std::uint16_t sim_state_bits(Cia402State s) noexcept {
  switch (s) {
    case Cia402State::not_ready_to_switch_on:
      return 0x0000;
    case Cia402State::switch_on_disabled:
      return 0x0040;
    case Cia402State::ready_to_switch_on:
      return 0x0021;
    case Cia402State::switched_on:
      return 0x0023;
    case Cia402State::operation_enabled:
      return 0x0027;
    case Cia402State::quick_stop_active:
      return 0x0007;
    case Cia402State::fault_reaction_active:
      return 0x000F;
    case Cia402State::fault:
      return 0x0008;
  }
  return 0;
}

std::int64_t to_counts_clamped(double v) noexcept {
  const double lo = std::numeric_limits<std::int32_t>::min();
  const double hi = std::numeric_limits<std::int32_t>::max();
  return static_cast<std::int64_t>(std::llround(std::clamp(v, lo, hi)));
}

std::int64_t to_u32_clamped(double v) noexcept {
  return static_cast<std::int64_t>(std::llround(std::clamp(v, 0.0, 4294967295.0)));
}

bool is_rpdo_comm(std::uint16_t i) { return i >= od::rpdo_communication && i < od::rpdo_communication + 2; }
bool is_rpdo_map(std::uint16_t i) { return i >= od::rpdo_mapping && i < od::rpdo_mapping + 2; }
bool is_tpdo_comm(std::uint16_t i) { return i >= od::tpdo_communication && i < od::tpdo_communication + 2; }
bool is_tpdo_map(std::uint16_t i) { return i >= od::tpdo_mapping && i < od::tpdo_mapping + 2; }

}  // namespace

// ---------------------------------------------------------------------------------------------
// Parameters

double DriveParameters::motor_rad_per_unit() const noexcept {
  return 2.0 * std::numbers::pi * gear_ratio / units_per_output_rev;
}

double DriveParameters::counts_per_unit() const noexcept {
  return static_cast<double>(encoder_counts_per_motor_rev) * gear_ratio / units_per_output_rev;
}

void DriveParameters::validate() const {
  auto fail = [&](const std::string& what) {
    throw SimulationSetupError("simulated drive '" + name + "': " + what);
  };
  auto positive = [&](double v, const char* field) {
    if (!(v > 0.0) || !std::isfinite(v)) fail(std::string(field) + " must be a positive finite number");
  };
  positive(gear_ratio, "gear_ratio");
  positive(units_per_output_rev, "units_per_output_rev");
  positive(unit_in_si, "unit_in_si");
  positive(motor_inertia, "motor_inertia");
  positive(rated_torque, "rated_torque");
  positive(max_torque, "max_torque");
  positive(servo_bandwidth_hz, "servo_bandwidth_hz");
  positive(velocity_filter_hz, "velocity_filter_hz");
  positive(max_physics_dt, "max_physics_dt");
  positive(quick_stop_deceleration, "quick_stop_deceleration");
  positive(max_velocity, "max_velocity");
  if (encoder_counts_per_motor_rev < 4) fail("encoder_counts_per_motor_rev must be at least 4");
  if (load_inertia < 0 || viscous_friction < 0 || coulomb_friction < 0 || encoder_noise_counts < 0)
    fail("inertia, friction and noise must not be negative");
  if (coulomb_friction >= max_torque)
    fail("coulomb_friction must be below max_torque or the motor cannot move");
  if (!(hard_stop_min < hard_stop_max)) fail("hard_stop_min must be below hard_stop_max");
  if (!(position_limit_min < position_limit_max)) fail("position_limit_min must be below position_limit_max");
  if (initial_position < hard_stop_min || initial_position > hard_stop_max)
    fail("initial_position lies outside the hard stops");
  if (!(following_error_window > 0)) fail("following_error_window must be positive");
  // Servo and filter must be resolvable by the physics step (explicit integration stays stable).
  if (servo_bandwidth_hz * max_physics_dt > 0.05) fail("servo_bandwidth_hz too high for max_physics_dt");
  // Bounded travel must fit the 32-bit position counts (unbounded axes wrap like real drives).
  const double max_counts = std::max(std::abs(hard_stop_min), std::abs(hard_stop_max)) * counts_per_unit();
  if (std::abs(hard_stop_min) < 1e8 && std::abs(hard_stop_max) < 1e8 && max_counts > 2.0e9)
    fail("travel between the hard stops overflows 32-bit position counts");
}

DriveParameters DriveParameters::srmc_bend(std::string name) {
  DriveParameters p;
  p.name = std::move(name);
  p.gear_ratio = 1.0;
  p.units_per_output_rev = 1.27;  // Velmex A1506B-S1.5, 20 tpi
  p.unit_in_si = 1e-3;
  p.encoder_counts_per_motor_rev = 8192;  // 6450 counts/mm, 0.155 um per count
  // 4.5" (114.3 mm) of travel, centred on the neutral carriage position.
  p.hard_stop_min = -57.15;
  p.hard_stop_max = 57.15;
  p.position_limit_min = -50.0;
  p.position_limit_max = 50.0;
  p.following_error_window = 0.5;
  p.quick_stop_deceleration = 200.0;
  p.max_velocity = 20.0;
  return p;
}

DriveParameters DriveParameters::srmc_insertion(std::string name) {
  DriveParameters p;
  p.name = std::move(name);
  p.gear_ratio = 1.0;
  p.units_per_output_rev = 2.0;  // 2 mm lead linear stage (not given by the dissertation: assumed)
  p.encoder_counts_per_motor_rev = 8192;
  p.load_inertia = 2.0e-6;
  p.hard_stop_min = -5.0;
  p.hard_stop_max = 305.0;
  p.position_limit_min = 0.0;
  p.position_limit_max = 300.0;
  p.following_error_window = 1.0;
  p.quick_stop_deceleration = 300.0;
  p.max_velocity = 30.0;
  return p;
}

DriveParameters DriveParameters::srmc_roll(std::string name) {
  DriveParameters p;
  p.name = std::move(name);
  p.gear_ratio = 10.0;
  p.units_per_output_rev = 2.0 * std::numbers::pi;
  p.unit_in_si = 1.0;
  p.encoder_counts_per_motor_rev = 8192;
  p.hard_stop_min = -1e9;  // continuous rotation
  p.hard_stop_max = 1e9;
  p.position_limit_min = -4.0 * std::numbers::pi;
  p.position_limit_max = 4.0 * std::numbers::pi;
  p.following_error_window = 0.05;
  p.quick_stop_deceleration = 20.0;
  p.max_velocity = 6.0;
  return p;
}

// ---------------------------------------------------------------------------------------------
// Construction and dictionary

SimulatedCia402Drive::SimulatedCia402Drive(std::uint8_t node_id, can::Bus& endpoint, DriveParameters params)
    : node_id_(node_id), bus_(endpoint), params_(std::move(params)), rng_(params_.noise_seed) {
  if (node_id_ < 1 || node_id_ > 127) {
    throw SimulationSetupError("simulated drive '" + params_.name + "': node id " + std::to_string(node_id_) +
                               " is outside 1..127");
  }
  params_.validate();
  build_dictionary();
  compute_gains();
  motor_angle_ = params_.initial_position * params_.motor_rad_per_unit();
  measured_counts_prev_ = motor_angle_ * params_.encoder_counts_per_motor_rev / (2.0 * std::numbers::pi);
  demand_pos_ = measured_counts_prev_;
  latched_target_ = demand_pos_;
  position_counts_ = static_cast<std::int32_t>(std::floor(measured_counts_prev_));
  rebuild_all_pdos();
  publish_actuals();
}

void SimulatedCia402Drive::build_dictionary() {
  using T = OdType;
  using A = OdAccess;
  const double cpu = params_.counts_per_unit();
  const std::uint8_t id = node_id_;

  od_.add(od::device_type, 0, T::u32, A::constant, 0x00020192);  // CiA 402 servo drive
  od_.add(od::error_register, 0, T::u8, A::read_only, 0, true);
  od_.add(od::cob_id_sync, 0, T::u32, A::read_write, canopen::cob::sync);
  od_.add_string(kDeviceName, 0, A::constant, "tendril SIMULATED CiA 402 drive", 40);
  od_.add(od::cob_id_emcy, 0, T::u32, A::read_only, canopen::cob::emcy + id);
  od_.add(od::consumer_heartbeat_time, 0, T::u8, A::constant, 1);
  od_.add(od::consumer_heartbeat_time, 1, T::u32, A::read_write, 0);
  od_.add(od::producer_heartbeat_time, 0, T::u16, A::read_write, 0);
  od_.add(od::identity, 0, T::u8, A::constant, 4);
  od_.add(od::identity, 1, T::u32, A::read_only, params_.vendor_id);
  od_.add(od::identity, 2, T::u32, A::read_only, params_.product_code);
  od_.add(od::identity, 3, T::u32, A::read_only, 0x00010000);
  od_.add(od::identity, 4, T::u32, A::read_only, 0x51000000u + id);

  // PDO communication (sub1 COB-ID, sub2 transmission type) and mapping (sub0 count, sub1..8).
  const std::uint32_t rpdo_cob[2] = {canopen::cob::rpdo1 + id,
                                     canopen::cob::pdo_invalid_bit | (canopen::cob::rpdo2 + id)};
  const std::uint32_t tpdo_cob[2] = {canopen::cob::tpdo1 + id, canopen::cob::tpdo2 + id};
  const std::uint32_t rpdo_map[2][2] = {{0x60400010, 0x607A0020}, {0x60FF0020, 0}};
  const std::uint32_t tpdo_map[2][2] = {{0x60410010, 0x60640020}, {0x606C0020, 0x60770010}};
  const std::uint8_t rpdo_count[2] = {2, 1};
  for (std::uint16_t n = 0; n < 2; ++n) {
    od_.add(od::rpdo_communication + n, 0, T::u8, A::constant, 2);
    od_.add(od::rpdo_communication + n, 1, T::u32, A::read_write, rpdo_cob[n]);
    od_.add(od::rpdo_communication + n, 2, T::u8, A::read_write, 1);
    od_.add(od::tpdo_communication + n, 0, T::u8, A::constant, 2);
    od_.add(od::tpdo_communication + n, 1, T::u32, A::read_write, tpdo_cob[n]);
    od_.add(od::tpdo_communication + n, 2, T::u8, A::read_write, 1);
    od_.add(od::rpdo_mapping + n, 0, T::u8, A::read_write, rpdo_count[n]);
    od_.add(od::tpdo_mapping + n, 0, T::u8, A::read_write, 2);
    for (std::uint8_t s = 1; s <= 8; ++s) {
      od_.add(od::rpdo_mapping + n, s, T::u32, A::read_write, s <= 2 ? rpdo_map[n][s - 1] : 0);
      od_.add(od::tpdo_mapping + n, s, T::u32, A::read_write, s <= 2 ? tpdo_map[n][s - 1] : 0);
    }
  }
  od_.add_string(kDriveLabel, 0, A::read_write, params_.name.substr(0, 64), 64);

  // CiA 402 objects. Positions in encoder counts, velocities in counts/s.
  od_.add(od::abort_connection_option, 0, T::i16, A::read_write, 3);
  od_.add(od::error_code, 0, T::u16, A::read_only, 0, true);
  od_.add(od::controlword, 0, T::u16, A::read_write, 0, true);
  od_.add(od::statusword, 0, T::u16, A::read_only, 0, true);
  od_.add(od::quick_stop_option_code, 0, T::i16, A::read_write, 6);
  od_.add(od::modes_of_operation, 0, T::i8, A::read_write, 8, true);
  od_.add(od::modes_of_operation_display, 0, T::i8, A::read_only, 8, true);
  od_.add(od::position_actual_value, 0, T::i32, A::read_only, 0, true);
  od_.add(od::following_error_window, 0, T::u32, A::read_write,
          to_u32_clamped(params_.following_error_window * cpu));
  od_.add(kFollowingErrorTimeout, 0, T::u16, A::read_write, params_.following_error_timeout_ms);
  od_.add(od::velocity_actual_value, 0, T::i32, A::read_only, 0, true);
  od_.add(od::torque_actual_value, 0, T::i16, A::read_only, 0, true);
  od_.add(od::target_position, 0, T::i32, A::read_write, 0, true);
  od_.add(od::software_position_limit, 0, T::u8, A::constant, 2);
  od_.add(od::software_position_limit, 1, T::i32, A::read_write,
          to_counts_clamped(params_.position_limit_min * cpu));
  od_.add(od::software_position_limit, 2, T::i32, A::read_write,
          to_counts_clamped(params_.position_limit_max * cpu));
  od_.add(od::max_profile_velocity, 0, T::u32, A::read_write, to_u32_clamped(params_.max_velocity * cpu));
  od_.add(od::quick_stop_deceleration, 0, T::u32, A::read_write,
          to_u32_clamped(params_.quick_stop_deceleration * cpu));
  od_.add(od::position_encoder_resolution, 0, T::u8, A::constant, 2);
  od_.add(od::position_encoder_resolution, 1, T::u32, A::read_only, params_.encoder_counts_per_motor_rev);
  od_.add(od::position_encoder_resolution, 2, T::u32, A::read_only, 1);
  od_.add(od::interpolation_time_period, 0, T::u8, A::constant, 2);
  od_.add(od::interpolation_time_period, 1, T::u8, A::read_write, 1);
  od_.add(od::interpolation_time_period, 2, T::i8, A::read_write, -3);
  od_.add(od::target_velocity, 0, T::i32, A::read_write, 0, true);

  for (std::uint16_t n = 0; n < 2; ++n) {
    od_.set_range(od::rpdo_mapping + n, 0, 0, 8);
    od_.set_range(od::tpdo_mapping + n, 0, 0, 8);
  }
  od_.set_range(od::abort_connection_option, 0, 0, 3);
  od_.set_range(od::interpolation_time_period, 2, -6, 0);
  od_.set_range(od::quick_stop_deceleration, 0, 1, 0xFFFFFFFF);
  od_.set_range(od::following_error_window, 0, 1, 0xFFFFFFFF);
  od_.set_write_check(
      [this](std::uint16_t index, std::uint8_t sub, std::int64_t v) { return check_write(index, sub, v); });
  od_.freeze();

  controlword_ = &od_.at(od::controlword, 0);
  statusword_ = &od_.at(od::statusword, 0);
  position_actual_ = &od_.at(od::position_actual_value, 0);
  velocity_actual_ = &od_.at(od::velocity_actual_value, 0);
  torque_actual_ = &od_.at(od::torque_actual_value, 0);
  target_position_ = &od_.at(od::target_position, 0);
  target_velocity_ = &od_.at(od::target_velocity, 0);
  mode_ = &od_.at(od::modes_of_operation, 0);
  mode_display_ = &od_.at(od::modes_of_operation_display, 0);
  error_code_ = &od_.at(od::error_code, 0);
  error_register_ = &od_.at(od::error_register, 0);
  heartbeat_time_ = &od_.at(od::producer_heartbeat_time, 0);
  consumer_hb_ = &od_.at(od::consumer_heartbeat_time, 1);
  abort_option_ = &od_.at(od::abort_connection_option, 0);
  quick_stop_option_ = &od_.at(od::quick_stop_option_code, 0);
  following_window_ = &od_.at(od::following_error_window, 0);
  following_timeout_ = &od_.at(kFollowingErrorTimeout, 0);
  limit_min_ = &od_.at(od::software_position_limit, 1);
  limit_max_ = &od_.at(od::software_position_limit, 2);
  quick_stop_decel_ = &od_.at(od::quick_stop_deceleration, 0);
  max_velocity_ = &od_.at(od::max_profile_velocity, 0);
  interp_value_ = &od_.at(od::interpolation_time_period, 1);
  interp_index_ = &od_.at(od::interpolation_time_period, 2);
  for (std::uint16_t n = 0; n < 2; ++n) {
    rpdos_[n].comm_index = od::rpdo_communication + n;
    rpdos_[n].map_index = od::rpdo_mapping + n;
    tpdos_[n].comm_index = od::tpdo_communication + n;
    tpdos_[n].map_index = od::tpdo_mapping + n;
  }
}

std::uint32_t SimulatedCia402Drive::check_write(std::uint16_t index, std::uint8_t sub,
                                                std::int64_t v) noexcept {
  if (index == od::modes_of_operation) {
    const auto mode = static_cast<canopen::OperationMode>(v);
    if (mode != canopen::OperationMode::cyclic_synchronous_position &&
        mode != canopen::OperationMode::cyclic_synchronous_velocity)
      return abort_code::value_range;
    return 0;
  }
  if (index == od::quick_stop_option_code) return (v == 0 || v == 2 || v == 6) ? 0 : abort_code::value_range;
  if (index == od::software_position_limit) {
    const std::int64_t lo = sub == 1 ? v : limit_min_->value;
    const std::int64_t hi = sub == 2 ? v : limit_max_->value;
    return lo < hi ? 0 : abort_code::value_range;
  }
  if (index == od::interpolation_time_period && sub == 1 && v == 0) return abort_code::value_range;
  if (is_rpdo_comm(index) || is_tpdo_comm(index)) {
    const auto* cur = od_.find(index, sub);
    if (sub == 1) {
      const auto now_cob = static_cast<std::uint32_t>(cur->value);
      const auto new_cob = static_cast<std::uint32_t>(v);
      const bool both_valid =
          !(now_cob & canopen::cob::pdo_invalid_bit) && !(new_cob & canopen::cob::pdo_invalid_bit);
      // CiA 301: a valid PDO's identifier can only change by passing through "invalid".
      if (both_valid && (now_cob & 0x7FF) != (new_cob & 0x7FF)) return abort_code::value_range;
      if ((new_cob & 0x1FFFF800u) != 0) return abort_code::value_range;  // 29-bit ids not supported
      return 0;
    }
    if (sub == 2) return (v <= 240 || v >= 254) ? 0 : abort_code::value_range;
    return 0;
  }
  if (is_rpdo_map(index) || is_tpdo_map(index)) {
    const bool receive = is_rpdo_map(index);
    const auto* count = od_.find(index, 0);
    if (sub != 0) {
      // Entries may only change while the mapping is disabled (sub0 = 0).
      return count->value == 0 ? 0 : abort_code::unsupported_access;
    }
    unsigned total_bits = 0;
    // v is range-checked to 0..8 by the dictionary; a wide loop variable keeps that bound safe anyway.
    for (std::int64_t s = 1; s <= v; ++s) {
      const auto m = static_cast<std::uint32_t>(od_.find(index, static_cast<std::uint8_t>(s))->value);
      const auto* target = od_.find(static_cast<std::uint16_t>(m >> 16), static_cast<std::uint8_t>(m >> 8));
      const unsigned bits = m & 0xFF;
      if (!target || !target->pdo_mappable || bits != od_type_size(target->type) * 8)
        return abort_code::cannot_map;
      if (receive ? !target->writable() : !target->readable()) return abort_code::cannot_map;
      total_bits += bits;
    }
    return total_bits <= 64 ? 0 : abort_code::map_too_long;
  }
  return 0;
}

void SimulatedCia402Drive::after_write(std::uint16_t index, std::uint8_t sub) noexcept {
  (void)sub;
  if (index == od::controlword) {
    apply_controlword(static_cast<std::uint16_t>(controlword_->value));
  } else if (index == od::producer_heartbeat_time) {
    heartbeat_started_ = false;  // restart the producer timer from the next step
  } else if (index == od::consumer_heartbeat_time) {
    consumer_armed_ = false;
    consumer_tripped_ = false;
  } else if (index == od::modes_of_operation) {
    mode_display_->value = mode_->value;
    latched_target_ = demand_pos_;
    interp_start_ = demand_pos_;
    latched_velocity_ = 0.0;
  } else if (is_rpdo_comm(index) || is_rpdo_map(index)) {
    rebuild_pdo(rpdos_[index & 0x1]);
  } else if (is_tpdo_comm(index) || is_tpdo_map(index)) {
    rebuild_pdo(tpdos_[index & 0x1]);
  }
}

void SimulatedCia402Drive::rebuild_pdo(Pdo& pdo) noexcept {
  const auto count = static_cast<std::uint8_t>(od_.find(pdo.map_index, 0)->value);
  pdo.count = 0;
  pdo.bytes = 0;
  for (std::uint8_t s = 1; s <= count && s <= 8; ++s) {
    const auto m = static_cast<std::uint32_t>(od_.find(pdo.map_index, s)->value);
    auto* target = od_.find(static_cast<std::uint16_t>(m >> 16), static_cast<std::uint8_t>(m >> 8));
    const auto bits = static_cast<std::uint8_t>(m & 0xFF);
    if (!target || bits != od_type_size(target->type) * 8 || pdo.bytes + bits / 8 > 8) break;
    pdo.map[pdo.count++] = {target, bits};
    pdo.bytes = static_cast<std::uint8_t>(pdo.bytes + bits / 8);
  }
  pdo.sync_counter = 0;
  pdo.sent_once = false;
  pdo.pending = false;
}

void SimulatedCia402Drive::rebuild_all_pdos() noexcept {
  for (auto& p : rpdos_) rebuild_pdo(p);
  for (auto& p : tpdos_) rebuild_pdo(p);
}

// ---------------------------------------------------------------------------------------------
// Transmission

void SimulatedCia402Drive::send(const can::Frame& f) noexcept {
  if (silent_ || !powered_) {
    ++counters_.frames_suppressed;
    return;
  }
  if (bus_.send(f) == can::SendResult::ok) {
    ++counters_.frames_sent;
  } else {
    ++counters_.send_failures;
  }
}

void SimulatedCia402Drive::send_emcy(std::uint16_t code) noexcept {
  if (nmt_ == NmtState::stopped || nmt_ == NmtState::boot_up) return;
  can::Frame f;
  f.id = static_cast<std::uint32_t>(od_.find(od::cob_id_emcy, 0)->value) & 0x7FF;
  f.len = 8;
  canopen::put_u16(f.data.data(), code);
  f.data[2] = static_cast<std::uint8_t>(error_register_->value);
  f.data[3] = static_cast<std::uint8_t>(state_);  // manufacturer-specific: the CiA 402 state
  ++counters_.emcy_sent;
  send(f);
}

void SimulatedCia402Drive::send_heartbeat(Clock::time_point now) noexcept {
  can::Frame f;
  f.id = canopen::cob::heartbeat + node_id_;
  f.len = 1;
  f.data[0] = static_cast<std::uint8_t>(nmt_);
  f.timestamp = now;
  send(f);
}

void SimulatedCia402Drive::sdo_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept {
  can::Frame f;
  f.id = canopen::cob::sdo_tx + node_id_;
  f.len = 8;
  f.data[0] = 0x80;
  canopen::put_u16(&f.data[1], index);
  f.data[3] = sub;
  canopen::put_u32(&f.data[4], code);
  sdo_.kind = SdoTransfer::Kind::none;
  ++counters_.sdo_aborts_sent;
  send(f);
}

// ---------------------------------------------------------------------------------------------
// Reception

void SimulatedCia402Drive::pump(Clock::time_point now, double dt) noexcept {
  while (auto f = bus_.receive(std::chrono::nanoseconds::zero())) handle(*f, now);
  step(now, dt);
}

void SimulatedCia402Drive::handle(const can::Frame& f, Clock::time_point now) noexcept {
  if (!powered_ || boot_pending_ || f.error || f.extended || f.rtr) return;
  ++counters_.frames_handled;
  if (f.id == canopen::cob::nmt) {
    handle_nmt(f, now);
    return;
  }
  if (f.id > canopen::cob::heartbeat && f.id <= canopen::cob::heartbeat + 127) {
    handle_heartbeat(static_cast<std::uint8_t>(f.id - canopen::cob::heartbeat), now);
    return;
  }
  if (nmt_ == NmtState::stopped) return;
  if (f.id == (static_cast<std::uint32_t>(od_.find(od::cob_id_sync, 0)->value) & 0x7FF)) {
    handle_sync(now);
    return;
  }
  if (f.id == canopen::cob::sdo_rx + node_id_) {
    handle_sdo(f, now);
    return;
  }
  if (nmt_ != NmtState::operational) return;
  for (auto& pdo : rpdos_) {
    const auto cob = static_cast<std::uint32_t>(od_.find(pdo.comm_index, 1)->value);
    if ((cob & canopen::cob::pdo_invalid_bit) || (cob & 0x7FF) != f.id) continue;
    if (f.len < pdo.bytes) {
      send_emcy(kEmcyPdoLength);  // CiA 301: PDO not processed, length error
      return;
    }
    ++counters_.rpdos;
    const auto type = od_.find(pdo.comm_index, 2)->value;
    if (type <= 240) {
      pdo.pending = true;  // synchronous: takes effect at the next SYNC
      pdo.pending_data = f.data;
      pdo.pending_len = f.len;
    } else {
      apply_rpdo(pdo, f.data.data(), f.len);
    }
    return;
  }
}

void SimulatedCia402Drive::handle_nmt(const can::Frame& f, Clock::time_point now) noexcept {
  (void)now;
  if (f.len < 2) return;
  if (f.data[1] != 0 && f.data[1] != node_id_) return;
  switch (static_cast<canopen::NmtCommand>(f.data[0])) {
    case canopen::NmtCommand::start:
      nmt_ = NmtState::operational;
      break;
    case canopen::NmtCommand::stop:
      nmt_ = NmtState::stopped;
      sdo_.kind = SdoTransfer::Kind::none;
      break;
    case canopen::NmtCommand::enter_pre_operational:
      nmt_ = NmtState::pre_operational;
      break;
    case canopen::NmtCommand::reset_node:
      reset_communication(true);
      break;
    case canopen::NmtCommand::reset_communication:
      reset_communication(false);
      break;
  }
}

void SimulatedCia402Drive::reset_communication(bool full) noexcept {
  if (full) {
    // Reset application: the drive re-initialises and its power stage switches off.
    od_.reset_all();
    enter_state(Cia402State::not_ready_to_switch_on);
    last_controlword_ = 0;
    limit_warning_ = limit_emcy_sent_ = false;
  } else {
    od_.reset_communication();
  }
  rebuild_all_pdos();
  sdo_.kind = SdoTransfer::Kind::none;
  consumer_armed_ = consumer_tripped_ = false;
  nmt_ = NmtState::boot_up;
  boot_pending_ = true;  // boot-up goes out on the next step
}

void SimulatedCia402Drive::handle_heartbeat(std::uint8_t producer, Clock::time_point now) noexcept {
  const auto cfg = static_cast<std::uint32_t>(consumer_hb_->value);
  const auto watched = static_cast<std::uint8_t>((cfg >> 16) & 0x7F);
  if (watched == 0 || watched != producer) return;
  consumer_last_seen_ = now;
  consumer_armed_ = true;
  consumer_tripped_ = false;
}

void SimulatedCia402Drive::handle_sync(Clock::time_point now) noexcept {
  if (nmt_ != NmtState::operational) return;
  ++counters_.syncs;
  for (auto& pdo : rpdos_) {
    if (!pdo.pending) continue;
    pdo.pending = false;
    apply_rpdo(pdo, pdo.pending_data.data(), pdo.pending_len);
  }
  latch_targets();
  publish_actuals();
  for (auto& pdo : tpdos_) {
    const auto cob = static_cast<std::uint32_t>(od_.find(pdo.comm_index, 1)->value);
    if (cob & canopen::cob::pdo_invalid_bit) continue;
    const auto type = od_.find(pdo.comm_index, 2)->value;
    if (type == 0) {
      send_tpdo(pdo, now);  // acyclic synchronous: only if changed (checked in send_tpdo)
    } else if (type <= 240) {
      if (++pdo.sync_counter >= static_cast<std::uint32_t>(type)) {
        pdo.sync_counter = 0;
        pdo.sent_once = false;  // cyclic: always send
        send_tpdo(pdo, now);
      }
    }
  }
}

void SimulatedCia402Drive::apply_rpdo(Pdo& pdo, const std::uint8_t* data, std::uint8_t len) noexcept {
  std::size_t offset = 0;
  bool controlword_written = false;
  for (std::uint8_t i = 0; i < pdo.count; ++i) {
    const auto& m = pdo.map[i];
    const std::size_t n = m.bits / 8;
    if (offset + n > len) break;
    m.entry->value = od_decode(m.entry->type, data + offset);
    if (m.entry == controlword_) controlword_written = true;
    if (m.entry == mode_) after_write(od::modes_of_operation, 0);
    offset += n;
  }
  if (controlword_written) apply_controlword(static_cast<std::uint16_t>(controlword_->value));
}

void SimulatedCia402Drive::send_tpdo(Pdo& pdo, Clock::time_point now) noexcept {
  can::Frame f;
  f.id = static_cast<std::uint32_t>(od_.find(pdo.comm_index, 1)->value) & 0x7FF;
  f.timestamp = now;
  std::size_t offset = 0;
  for (std::uint8_t i = 0; i < pdo.count; ++i) {
    const auto& m = pdo.map[i];
    od_encode(m.entry->type, m.entry->value, f.data.data() + offset);
    offset += m.bits / 8;
  }
  f.len = static_cast<std::uint8_t>(offset);
  if (pdo.sent_once && f.data == pdo.last_sent) return;
  pdo.last_sent = f.data;
  pdo.sent_once = true;
  send(f);
}

void SimulatedCia402Drive::handle_sdo(const can::Frame& f, Clock::time_point now) noexcept {
  ++counters_.sdo_requests;
  const std::uint8_t* d = f.data.data();
  const std::uint8_t ccs = d[0] >> 5;
  const std::uint16_t index = canopen::get_u16(d + 1);
  const std::uint8_t sub = d[3];
  if (f.len != 8) {
    sdo_abort(sdo_.kind == SdoTransfer::Kind::none ? index : sdo_.index, sub, abort_code::invalid_command);
    return;
  }
  can::Frame r;
  r.id = canopen::cob::sdo_tx + node_id_;
  r.len = 8;
  r.timestamp = now;

  switch (ccs) {
    case 1: {  // initiate download
      const bool expedited = d[0] & 0x02;
      const bool size_indicated = d[0] & 0x01;
      sdo_.kind = SdoTransfer::Kind::none;
      if (expedited) {
        std::size_t size = size_indicated ? 4u - ((d[0] >> 2) & 0x3) : 0u;
        if (!size_indicated) {
          // Size unspecified: the object's own size (CiA 301 allows it for expedited transfers).
          const auto* e = od_.find(index, sub);
          size = e && e->type != OdType::visible_string ? od_type_size(e->type) : 4u;
        }
        if (const auto code = od_.write(index, sub, d + 4, size)) {
          sdo_abort(index, sub, code);
          return;
        }
        r.data[0] = 0x60;
        canopen::put_u16(&r.data[1], index);
        r.data[3] = sub;
        send(r);
        after_write(index, sub);
        return;
      }
      const auto* e = od_.find(index, sub);
      if (!e) {
        sdo_abort(index, sub, od_.has_index(index) ? abort_code::no_subindex : abort_code::no_object);
        return;
      }
      if (!e->writable()) {
        sdo_abort(index, sub, abort_code::read_only);
        return;
      }
      const std::size_t size = size_indicated ? canopen::get_u32(d + 4) : 0;
      if (size_indicated) {
        if (e->type == OdType::visible_string ? size > e->text_capacity : size != od_type_size(e->type)) {
          sdo_abort(
              index, sub,
              e->type == OdType::visible_string ? abort_code::length_too_high : abort_code::length_mismatch);
          return;
        }
      }
      sdo_.kind = SdoTransfer::Kind::download;
      sdo_.index = index;
      sdo_.sub = sub;
      sdo_.toggle = false;
      sdo_.size = size;
      sdo_.offset = 0;
      sdo_.last_activity = now;
      r.data[0] = 0x60;
      canopen::put_u16(&r.data[1], index);
      r.data[3] = sub;
      send(r);
      return;
    }
    case 0: {  // download segment
      if (sdo_.kind != SdoTransfer::Kind::download) {
        sdo_abort(sdo_.index, sdo_.sub, abort_code::invalid_command);
        return;
      }
      const bool toggle = d[0] & 0x10;
      if (toggle != sdo_.toggle) {
        sdo_abort(sdo_.index, sdo_.sub, abort_code::toggle_bit);
        return;
      }
      const std::size_t n = 7u - ((d[0] >> 1) & 0x7);
      const bool last = d[0] & 0x01;
      if (sdo_.offset + n > sdo_.buffer.size() || (sdo_.size && sdo_.offset + n > sdo_.size)) {
        sdo_abort(sdo_.index, sdo_.sub, abort_code::length_too_high);
        return;
      }
      std::copy(d + 1, d + 1 + n, sdo_.buffer.begin() + static_cast<std::ptrdiff_t>(sdo_.offset));
      sdo_.offset += n;
      sdo_.last_activity = now;
      if (last) {
        if (sdo_.size && sdo_.offset != sdo_.size) {
          sdo_abort(sdo_.index, sdo_.sub, abort_code::length_too_low);
          return;
        }
        if (const auto code = od_.write(sdo_.index, sdo_.sub, sdo_.buffer.data(), sdo_.offset)) {
          sdo_abort(sdo_.index, sdo_.sub, code);
          return;
        }
      }
      r.data[0] = static_cast<std::uint8_t>(0x20 | (toggle ? 0x10 : 0));
      sdo_.toggle = !sdo_.toggle;
      send(r);
      if (last) {
        sdo_.kind = SdoTransfer::Kind::none;
        after_write(sdo_.index, sdo_.sub);
      }
      return;
    }
    case 2: {  // initiate upload
      sdo_.kind = SdoTransfer::Kind::none;
      std::size_t size = 0;
      if (const auto code = od_.read(index, sub, sdo_.buffer.data(), sdo_.buffer.size(), size)) {
        sdo_abort(index, sub, code);
        return;
      }
      canopen::put_u16(&r.data[1], index);
      r.data[3] = sub;
      if (size <= 4 && size > 0) {
        r.data[0] = static_cast<std::uint8_t>(0x43 | ((4 - size) << 2));
        std::copy(sdo_.buffer.begin(), sdo_.buffer.begin() + static_cast<std::ptrdiff_t>(size),
                  r.data.begin() + 4);
        send(r);
        return;
      }
      r.data[0] = 0x41;  // segmented, size indicated
      canopen::put_u32(&r.data[4], static_cast<std::uint32_t>(size));
      sdo_.kind = SdoTransfer::Kind::upload;
      sdo_.index = index;
      sdo_.sub = sub;
      sdo_.toggle = false;
      sdo_.size = size;
      sdo_.offset = 0;
      sdo_.last_activity = now;
      send(r);
      return;
    }
    case 3: {  // upload segment
      if (sdo_.kind != SdoTransfer::Kind::upload) {
        sdo_abort(sdo_.index, sdo_.sub, abort_code::invalid_command);
        return;
      }
      const bool toggle = d[0] & 0x10;
      if (toggle != sdo_.toggle) {
        sdo_abort(sdo_.index, sdo_.sub, abort_code::toggle_bit);
        return;
      }
      const std::size_t n = std::min<std::size_t>(7, sdo_.size - sdo_.offset);
      const bool last = sdo_.offset + n >= sdo_.size;
      r.data[0] = static_cast<std::uint8_t>((toggle ? 0x10 : 0) | ((7 - n) << 1) | (last ? 1 : 0));
      std::copy(sdo_.buffer.begin() + static_cast<std::ptrdiff_t>(sdo_.offset),
                sdo_.buffer.begin() + static_cast<std::ptrdiff_t>(sdo_.offset + n), r.data.begin() + 1);
      sdo_.offset += n;
      sdo_.toggle = !sdo_.toggle;
      sdo_.last_activity = now;
      if (last) sdo_.kind = SdoTransfer::Kind::none;
      send(r);
      return;
    }
    case 4:  // abort from the client: drop the transfer, no answer
      sdo_.kind = SdoTransfer::Kind::none;
      return;
    default:  // block transfers (5, 6) and reserved command specifiers
      sdo_abort(index, sub, abort_code::invalid_command);
      return;
  }
}

// ---------------------------------------------------------------------------------------------
// CiA 402 state machine

void SimulatedCia402Drive::apply_controlword(std::uint16_t cw) noexcept {
  const bool reset_edge = (cw & 0x80) && !(last_controlword_ & 0x80);
  last_controlword_ = cw;
  switch (state_) {
    case Cia402State::fault:
      if (reset_edge) {
        error_code_->value = 0;
        error_register_->value = 0;
        following_error_flag_ = false;
        following_error_time_ = 0.0;
        enter_state(Cia402State::switch_on_disabled);
        send_emcy(kEmcyErrorReset);
      }
      return;
    case Cia402State::fault_reaction_active:
    case Cia402State::not_ready_to_switch_on:
      return;
    default:
      break;
  }
  if (cw & 0x80) return;  // "fault reset" outside FAULT: no transition
  const bool disable_voltage = (cw & 0x02) == 0;
  const bool quick_stop = (cw & 0x06) == 0x02;
  const bool shutdown = (cw & 0x07) == 0x06;
  const bool switch_on = (cw & 0x0F) == 0x07;
  const bool enable = (cw & 0x0F) == 0x0F;
  switch (state_) {
    case Cia402State::switch_on_disabled:
      if (shutdown) enter_state(Cia402State::ready_to_switch_on);
      break;
    case Cia402State::ready_to_switch_on:
      if (switch_on) {
        enter_state(Cia402State::switched_on);
      } else if (enable) {
        enter_state(Cia402State::switched_on);  // transitions 3 + 4
        enter_state(Cia402State::operation_enabled);
      } else if (disable_voltage || quick_stop) {
        enter_state(Cia402State::switch_on_disabled);
      }
      break;
    case Cia402State::switched_on:
      if (enable) {
        enter_state(Cia402State::operation_enabled);
      } else if (shutdown) {
        enter_state(Cia402State::ready_to_switch_on);
      } else if (disable_voltage || quick_stop) {
        enter_state(Cia402State::switch_on_disabled);
      }
      break;
    case Cia402State::operation_enabled:
      if (disable_voltage) {
        enter_state(Cia402State::switch_on_disabled);
      } else if (quick_stop) {
        enter_state(Cia402State::quick_stop_active);
      } else if (shutdown) {
        enter_state(Cia402State::ready_to_switch_on);
      } else if (switch_on) {
        enter_state(Cia402State::switched_on);
      }
      break;
    case Cia402State::quick_stop_active:
      if (disable_voltage) {
        enter_state(Cia402State::switch_on_disabled);
      } else if (enable && quick_stop_option_->value >= 5) {
        enter_state(Cia402State::operation_enabled);  // transition 16
      }
      break;
    default:
      break;
  }
}

void SimulatedCia402Drive::enter_state(Cia402State s) noexcept {
  const double cpr = params_.encoder_counts_per_motor_rev;
  const double measured = motor_angle_ * cpr / (2.0 * std::numbers::pi) + encoder_offset_counts_;
  switch (s) {
    case Cia402State::operation_enabled:
      // Hold where the load is until the next SYNC latches a target.
      if (state_ != Cia402State::quick_stop_active) {
        demand_pos_ = measured;
        servo_.reset();
      }
      demand_vel_ = 0.0;
      latched_target_ = interp_start_ = demand_pos_;
      interp_elapsed_ = 1e9;
      latched_velocity_ = 0.0;
      ramping_ = false;
      break;
    case Cia402State::quick_stop_active:
      ramping_ = true;  // decelerate from the current demand
      if (quick_stop_option_->value == 0) {
        state_ = s;
        enter_state(Cia402State::switch_on_disabled);
        return;
      }
      break;
    case Cia402State::fault_reaction_active:
      // Start the stop ramp from where the load actually is (the demand may be the fault's cause).
      demand_pos_ = measured;
      demand_vel_ = velocity_estimate_;
      ramping_ = true;
      break;
    default:
      ramping_ = false;
      demand_vel_ = 0.0;
      servo_.reset();
      break;
  }
  state_ = s;
  statusword_->value = statusword();
}

void SimulatedCia402Drive::raise_fault(std::uint16_t emcy_code, std::uint8_t error_register_bits) noexcept {
  if (state_ == Cia402State::fault || state_ == Cia402State::fault_reaction_active) return;
  error_code_->value = emcy_code;
  error_register_->value = error_register_->value | kErrRegGeneric | error_register_bits;
  const bool moving = servo_active();
  enter_state(moving ? Cia402State::fault_reaction_active : Cia402State::fault);
  send_emcy(emcy_code);
}

void SimulatedCia402Drive::inject_fault(std::uint16_t emcy_code) noexcept { raise_fault(emcy_code, 0); }

void SimulatedCia402Drive::on_comm_loss() noexcept {
  const auto option = abort_option_->value;
  const bool powered_stage = state_ == Cia402State::ready_to_switch_on ||
                             state_ == Cia402State::switched_on || state_ == Cia402State::operation_enabled ||
                             state_ == Cia402State::quick_stop_active;
  // 1 = fault; 3 = quick stop, then FAULT (the fault reaction ramps at the quick-stop deceleration).
  if (option == 1 || (option == 3 && powered_stage)) {
    raise_fault(canopen::emcy_code::heartbeat_lost, kErrRegCommunication);
    return;
  }
  error_register_->value = error_register_->value | kErrRegCommunication;
  send_emcy(canopen::emcy_code::heartbeat_lost);
  if (option == 2 && powered_stage) enter_state(Cia402State::switch_on_disabled);
}

bool SimulatedCia402Drive::servo_active() const noexcept {
  return state_ == Cia402State::operation_enabled || state_ == Cia402State::quick_stop_active ||
         state_ == Cia402State::fault_reaction_active;
}

std::uint16_t SimulatedCia402Drive::statusword() const noexcept {
  std::uint16_t s = sim_state_bits(state_) | sw::remote;
  if (state_ != Cia402State::not_ready_to_switch_on) s |= sw::voltage_enabled;
  if (limit_warning_) s |= sw::warning | sw::internal_limit;
  if (following_error_flag_) s |= sw::following_error;
  const double window = params_.target_reached_window * params_.counts_per_unit();
  if (state_ == Cia402State::operation_enabled) {
    if (mode_->value == static_cast<std::int8_t>(canopen::OperationMode::cyclic_synchronous_position)) {
      s |= 1u << 12;  // CSP: drive follows the target
      if (std::abs(latched_target_ - position_counts_) <= window) s |= sw::target_reached;
    } else {
      s |= 1u << 12;
      if (std::abs(latched_velocity_ - velocity_estimate_) <= window) s |= sw::target_reached;
    }
  } else if (state_ == Cia402State::quick_stop_active && !ramping_) {
    s |= sw::target_reached;  // halted
  }
  return s;
}

void SimulatedCia402Drive::latch_targets() noexcept {
  if (state_ != Cia402State::operation_enabled) return;
  if (mode_->value == static_cast<std::int8_t>(canopen::OperationMode::cyclic_synchronous_velocity)) {
    const double vmax = static_cast<double>(max_velocity_->value);
    latched_velocity_ = std::clamp(static_cast<double>(target_velocity_->value), -vmax, vmax);
    return;
  }
  const auto requested = target_position_->value;
  const auto clamped = std::clamp(requested, limit_min_->value, limit_max_->value);
  if (clamped != requested) {
    limit_warning_ = true;
    if (!limit_emcy_sent_) {
      limit_emcy_sent_ = true;
      send_emcy(canopen::emcy_code::position_limit);
    }
  } else {
    limit_warning_ = false;
    limit_emcy_sent_ = false;
  }
  interp_start_ = demand_pos_;
  interp_elapsed_ = 0.0;
  latched_target_ = static_cast<double>(clamped);
}

// ---------------------------------------------------------------------------------------------
// Physics

void SimulatedCia402Drive::compute_gains() noexcept {
  const double inertia = params_.motor_inertia + params_.load_inertia;
  const double w = 2.0 * std::numbers::pi * params_.servo_bandwidth_hz;
  teleop::PidGains g;
  g.kp = inertia * w * w;
  g.kd = 2.0 * inertia * w;
  g.ki = g.kp * w / 8.0;
  g.output_limit = params_.max_torque;
  g.integral_limit = params_.max_torque;
  g.derivative_filter_time = 1.0 / (2.0 * std::numbers::pi * params_.velocity_filter_hz);
  g.anti_windup = teleop::AntiWindup::kConditional;
  servo_ = teleop::Pid(g);
}

void SimulatedCia402Drive::update_demand(double dt) noexcept {
  if (ramping_) {
    const double decel = static_cast<double>(quick_stop_decel_->value);
    const double dv = decel * dt;
    if (std::abs(demand_vel_) <= dv) {
      demand_pos_ += demand_vel_ * 0.5 * dt;
      demand_vel_ = 0.0;
      ramping_ = false;
      if (state_ == Cia402State::fault_reaction_active) {
        enter_state(Cia402State::fault);
      } else if (state_ == Cia402State::quick_stop_active && quick_stop_option_->value == 2) {
        enter_state(Cia402State::switch_on_disabled);
      }
      return;
    }
    demand_vel_ -= std::copysign(dv, demand_vel_);
    demand_pos_ += demand_vel_ * dt;
    return;
  }
  if (state_ != Cia402State::operation_enabled) {
    demand_vel_ = 0.0;
    return;
  }
  if (mode_->value == static_cast<std::int8_t>(canopen::OperationMode::cyclic_synchronous_velocity)) {
    demand_vel_ = latched_velocity_;
    demand_pos_ += demand_vel_ * dt;
    return;
  }
  const double period =
      static_cast<double>(interp_value_->value) * std::pow(10.0, static_cast<double>(interp_index_->value));
  interp_elapsed_ += dt;
  // The last substep of a period still carries the slope (feed-forward); hold only after it.
  if (period <= 0.0 || interp_elapsed_ > period + 1e-9) {
    demand_pos_ = latched_target_;
    demand_vel_ = 0.0;
    return;
  }
  const double slope = (latched_target_ - interp_start_) / period;
  demand_pos_ = interp_start_ + slope * std::min(interp_elapsed_, period);
  demand_vel_ = slope;
}

void SimulatedCia402Drive::physics_substep(double h) noexcept {
  const double cpr = params_.encoder_counts_per_motor_rev;
  const double rad_per_count = 2.0 * std::numbers::pi / cpr;
  // Encoder: true angle -> counts, plus noise, quantised.
  double true_counts = motor_angle_ / rad_per_count + encoder_offset_counts_;
  if (params_.encoder_noise_counts > 0.0) true_counts += params_.encoder_noise_counts * noise_(rng_);
  const double measured = std::floor(true_counts);
  position_counts_ =
      static_cast<std::int32_t>(std::clamp(measured, double{std::numeric_limits<std::int32_t>::min()},
                                           double{std::numeric_limits<std::int32_t>::max()}));
  const double raw_velocity = (measured - measured_counts_prev_) / h;
  measured_counts_prev_ = measured;
  const double alpha = 1.0 - std::exp(-2.0 * std::numbers::pi * params_.velocity_filter_hz * h);
  velocity_estimate_ += alpha * (raw_velocity - velocity_estimate_);

  update_demand(h);

  // Servo: PID on position with velocity feed-forward, torque-limited, conditional integration.
  double torque = 0.0;
  if (servo_active() && powered_) {
    // teleop::Pid damps on the measured velocity; the demanded velocity enters as feed-forward
    // (kd·v_demand + viscous friction), which makes the damping act on the velocity error.
    const double v_demand = demand_vel_ * rad_per_count;
    const double feed_forward = (servo_.gains().kd + params_.viscous_friction) * v_demand;
    torque = servo_.update(demand_pos_ * rad_per_count, measured * rad_per_count, h, feed_forward);
  } else {
    servo_.reset();
  }
  motor_torque_ = torque;

  // Mechanics: inertia + viscous + Coulomb friction (stiction when at rest), external load.
  const double inertia = params_.motor_inertia + params_.load_inertia;
  const double external = external_load_ * params_.unit_in_si / params_.motor_rad_per_unit();
  double drive = torque + external - params_.viscous_friction * motor_speed_;
  const double coulomb = params_.coulomb_friction;
  if (motor_speed_ == 0.0) {
    if (std::abs(drive) <= coulomb) return;  // stuck
    drive -= std::copysign(coulomb, drive);
  } else {
    drive -= std::copysign(coulomb, motor_speed_);
  }
  double speed = motor_speed_ + drive / inertia * h;
  if (motor_speed_ != 0.0 && (speed > 0) != (motor_speed_ > 0))
    speed = 0.0;  // friction stops, never reverses
  motor_speed_ = speed;
  motor_angle_ += motor_speed_ * h;
  const double lo = params_.hard_stop_min * params_.motor_rad_per_unit();
  const double hi = params_.hard_stop_max * params_.motor_rad_per_unit();
  if (motor_angle_ < lo || motor_angle_ > hi) {
    motor_angle_ = std::clamp(motor_angle_, lo, hi);
    motor_speed_ = 0.0;
  }
}

void SimulatedCia402Drive::publish_actuals() noexcept {
  position_actual_->value = position_counts_;
  velocity_actual_->value = to_counts_clamped(velocity_estimate_);
  torque_actual_->value = std::clamp<std::int64_t>(
      std::llround(motor_torque_ / params_.rated_torque * 1000.0), std::numeric_limits<std::int16_t>::min(),
      std::numeric_limits<std::int16_t>::max());
  statusword_->value = statusword();
}

void SimulatedCia402Drive::step(Clock::time_point now, double dt) noexcept {
  if (!(dt >= 0.0) || !std::isfinite(dt)) return;
  // dt = 0 runs only the protocol timers (used to process frames without advancing the physics).
  const int substeps =
      dt > 0.0 ? std::max(1, static_cast<int>(std::ceil(dt / params_.max_physics_dt - 1e-9))) : 0;
  const double h = substeps > 0 ? dt / substeps : 0.0;
  if (!powered_) {
    // No power: the load coasts to rest on friction; no protocol at all.
    for (int i = 0; i < substeps; ++i) physics_substep(h);
    return;
  }
  if (boot_pending_) {
    boot_pending_ = false;
    if (state_ == Cia402State::not_ready_to_switch_on) enter_state(Cia402State::switch_on_disabled);
    send_heartbeat(now);  // nmt_ is boot_up: this is the boot-up message (data 0x00)
    nmt_ = NmtState::pre_operational;
    heartbeat_started_ = false;
  }

  for (int i = 0; i < substeps; ++i) {
    physics_substep(h);
    // Following error: |demand - actual| beyond 0x6065 for longer than 0x6066 -> fault.
    const auto window = static_cast<std::uint32_t>(following_window_->value);
    const bool checked = state_ == Cia402State::operation_enabled || state_ == Cia402State::quick_stop_active;
    if (checked && window != 0xFFFFFFFFu && std::abs(demand_pos_ - position_counts_) > window) {
      following_error_flag_ = true;
      following_error_time_ += h;
      if (following_error_time_ * 1000.0 > static_cast<double>(following_timeout_->value)) {
        raise_fault(canopen::emcy_code::following_error, kErrRegProfile);
      }
    } else if (checked) {
      following_error_flag_ = false;
      following_error_time_ = 0.0;
    }
  }

  // Heartbeat producer (0x1017, ms).
  const auto period = std::chrono::milliseconds(heartbeat_time_->value);
  if (period.count() > 0) {
    if (!heartbeat_started_) {
      heartbeat_started_ = true;
      last_heartbeat_sent_ = now;
    } else if (now - last_heartbeat_sent_ >= period) {
      last_heartbeat_sent_ += period;
      if (now - last_heartbeat_sent_ >= period) last_heartbeat_sent_ = now;  // fell far behind
      send_heartbeat(now);
    }
  }

  // Heartbeat consumer (0x1016 sub1: node id << 16 | ms).
  const auto consumer_ms = std::chrono::milliseconds(consumer_hb_->value & 0xFFFF);
  if (consumer_armed_ && !consumer_tripped_ && consumer_ms.count() > 0 &&
      now - consumer_last_seen_ > consumer_ms) {
    consumer_tripped_ = true;
    on_comm_loss();
  }

  // SDO server timeout for an abandoned segmented transfer.
  if (sdo_.kind != SdoTransfer::Kind::none && now - sdo_.last_activity > kSdoServerTimeout) {
    sdo_abort(sdo_.index, sdo_.sub, abort_code::timeout);
  }

  publish_actuals();

  // Event-driven TPDOs (transmission type 254/255): sent when their data changes.
  if (nmt_ == NmtState::operational) {
    for (auto& pdo : tpdos_) {
      const auto cob = static_cast<std::uint32_t>(od_.find(pdo.comm_index, 1)->value);
      if (cob & canopen::cob::pdo_invalid_bit) continue;
      if (od_.find(pdo.comm_index, 2)->value >= 254) send_tpdo(pdo, now);
    }
  }
}

void SimulatedCia402Drive::power_cycle() noexcept {
  // Power lost and restored: all volatile state is gone; the mechanics keep where they are.
  od_.reset_all();
  rebuild_all_pdos();
  state_ = Cia402State::not_ready_to_switch_on;
  ramping_ = false;
  demand_vel_ = 0.0;
  servo_.reset();
  motor_torque_ = 0.0;
  last_controlword_ = 0;
  limit_warning_ = limit_emcy_sent_ = false;
  following_error_flag_ = false;
  following_error_time_ = 0.0;
  sdo_.kind = SdoTransfer::Kind::none;
  consumer_armed_ = consumer_tripped_ = false;
  heartbeat_started_ = false;
  for (auto& p : rpdos_) p.pending = false;
  if (!params_.absolute_encoder) {
    encoder_offset_counts_ = -motor_angle_ * params_.encoder_counts_per_motor_rev / (2.0 * std::numbers::pi);
  }
  measured_counts_prev_ =
      std::floor(motor_angle_ * params_.encoder_counts_per_motor_rev / (2.0 * std::numbers::pi) +
                 encoder_offset_counts_);
  velocity_estimate_ = 0.0;
  position_counts_ = static_cast<std::int32_t>(measured_counts_prev_);
  demand_pos_ = latched_target_ = interp_start_ = measured_counts_prev_;
  nmt_ = NmtState::boot_up;
  boot_pending_ = true;
  publish_actuals();
}

void SimulatedCia402Drive::set_powered(bool on) noexcept {
  if (on == powered_) return;
  if (on) {
    powered_ = true;
    power_cycle();  // boots again
    return;
  }
  powered_ = false;
  state_ = Cia402State::not_ready_to_switch_on;
  nmt_ = NmtState::boot_up;
  ramping_ = false;
  demand_vel_ = 0.0;
  servo_.reset();
  motor_torque_ = 0.0;
}

DriveTruth SimulatedCia402Drive::truth() const noexcept {
  DriveTruth t;
  t.position = motor_angle_ / params_.motor_rad_per_unit();
  t.velocity = motor_speed_ / params_.motor_rad_per_unit();
  t.motor_torque = motor_torque_;
  t.state = state_;
  t.nmt = nmt_;
  t.powered = powered_;
  return t;
}

}  // namespace tendril::sim
