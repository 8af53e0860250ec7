// CANopen (CiA 301) and drive-profile (CiA 402) constants and codecs shared by the master and the
// simulated nodes. NMT: network management; SDO: service data; PDO: process data; EMCY: emergency.
#pragma once

#include <cstdint>

namespace tendril::canopen {

// Predefined connection set: COB-ID = function code + node id.
namespace cob {
inline constexpr std::uint32_t nmt = 0x000;
inline constexpr std::uint32_t sync = 0x080;
inline constexpr std::uint32_t emcy = 0x080;  // + node id (1..127)
inline constexpr std::uint32_t tpdo1 = 0x180, rpdo1 = 0x200, tpdo2 = 0x280, rpdo2 = 0x300;
inline constexpr std::uint32_t tpdo3 = 0x380, rpdo3 = 0x400, tpdo4 = 0x480, rpdo4 = 0x500;
inline constexpr std::uint32_t sdo_tx = 0x580;                  // server -> client (answers), + node id
inline constexpr std::uint32_t sdo_rx = 0x600;                  // client -> server (requests), + node id
inline constexpr std::uint32_t heartbeat = 0x700;               // + node id
inline constexpr std::uint32_t pdo_invalid_bit = 0x8000'0000u;  // bit 31 of a PDO COB-ID entry
}  // namespace cob

enum class NmtCommand : std::uint8_t {
  start = 0x01,
  stop = 0x02,
  enter_pre_operational = 0x80,
  reset_node = 0x81,
  reset_communication = 0x82,
};

// States as carried in heartbeat / boot-up frames.
enum class NmtState : std::uint8_t {
  boot_up = 0x00,
  stopped = 0x04,
  operational = 0x05,
  pre_operational = 0x7F,
};

// Object dictionary indices used by tendril.
namespace od {
inline constexpr std::uint16_t device_type = 0x1000;
inline constexpr std::uint16_t error_register = 0x1001;
inline constexpr std::uint16_t cob_id_sync = 0x1005;
inline constexpr std::uint16_t communication_cycle_period = 0x1006;
inline constexpr std::uint16_t cob_id_emcy = 0x1014;
inline constexpr std::uint16_t consumer_heartbeat_time = 0x1016;  // sub n: (node id << 16) | ms
inline constexpr std::uint16_t producer_heartbeat_time = 0x1017;  // ms, u16
inline constexpr std::uint16_t identity = 0x1018;
inline constexpr std::uint16_t rpdo_communication = 0x1400;  // + pdo number (0-based)
inline constexpr std::uint16_t rpdo_mapping = 0x1600;
inline constexpr std::uint16_t tpdo_communication = 0x1800;
inline constexpr std::uint16_t tpdo_mapping = 0x1A00;
inline constexpr std::uint16_t abort_connection_option = 0x6007;  // i16: 3 = quick stop on comm loss
inline constexpr std::uint16_t error_code = 0x603F;
inline constexpr std::uint16_t controlword = 0x6040;
inline constexpr std::uint16_t statusword = 0x6041;
inline constexpr std::uint16_t quick_stop_option_code = 0x605A;
inline constexpr std::uint16_t modes_of_operation = 0x6060;
inline constexpr std::uint16_t modes_of_operation_display = 0x6061;
inline constexpr std::uint16_t position_actual_value = 0x6064;
inline constexpr std::uint16_t following_error_window = 0x6065;
inline constexpr std::uint16_t velocity_actual_value = 0x606C;
inline constexpr std::uint16_t torque_actual_value = 0x6077;
inline constexpr std::uint16_t target_position = 0x607A;
inline constexpr std::uint16_t software_position_limit = 0x607D;
inline constexpr std::uint16_t max_profile_velocity = 0x607F;
inline constexpr std::uint16_t quick_stop_deceleration = 0x6085;
inline constexpr std::uint16_t position_encoder_resolution = 0x608F;
inline constexpr std::uint16_t interpolation_time_period = 0x60C2;  // sub1 value, sub2 index (10^x s)
inline constexpr std::uint16_t target_velocity = 0x60FF;
}  // namespace od

// SDO abort codes (CiA 301 §7.2.4.3.17).
namespace sdo_abort {
inline constexpr std::uint32_t toggle_bit = 0x0503'0000;
inline constexpr std::uint32_t timeout = 0x0504'0000;
inline constexpr std::uint32_t invalid_command = 0x0504'0001;
inline constexpr std::uint32_t out_of_memory = 0x0504'0005;
inline constexpr std::uint32_t unsupported_access = 0x0601'0000;
inline constexpr std::uint32_t write_only = 0x0601'0001;
inline constexpr std::uint32_t read_only = 0x0601'0002;
inline constexpr std::uint32_t no_object = 0x0602'0000;
inline constexpr std::uint32_t cannot_map = 0x0604'0041;
inline constexpr std::uint32_t map_too_long = 0x0604'0042;
inline constexpr std::uint32_t length_mismatch = 0x0607'0010;
inline constexpr std::uint32_t length_too_high = 0x0607'0012;
inline constexpr std::uint32_t length_too_low = 0x0607'0013;
inline constexpr std::uint32_t no_subindex = 0x0609'0011;
inline constexpr std::uint32_t value_range = 0x0609'0030;
inline constexpr std::uint32_t general = 0x0800'0000;
inline constexpr std::uint32_t wrong_state = 0x0800'0022;
}  // namespace sdo_abort

// Text for an abort code, for messages written to a person.
const char* sdo_abort_text(std::uint32_t code) noexcept;

// CiA 402 power state machine (statusword decoding, controlword commands).
enum class Cia402State : std::uint8_t {
  not_ready_to_switch_on,
  switch_on_disabled,
  ready_to_switch_on,
  switched_on,
  operation_enabled,
  quick_stop_active,
  fault_reaction_active,
  fault,
};

const char* to_string(Cia402State s) noexcept;

// Decode the 8 states from statusword bits 0,1,2,3,5,6 (CiA 402 Table 30).
Cia402State decode_statusword(std::uint16_t statusword) noexcept;
// Statusword bits a drive in `s` reports (bits 0..6 only; callers OR in others such as bit 9 remote).
std::uint16_t encode_statusword(Cia402State s) noexcept;

namespace controlword {
inline constexpr std::uint16_t shutdown = 0x0006;           // -> ready to switch on
inline constexpr std::uint16_t switch_on = 0x0007;          // -> switched on
inline constexpr std::uint16_t enable_operation = 0x000F;   // -> operation enabled
inline constexpr std::uint16_t disable_voltage = 0x0000;    // -> switch on disabled
inline constexpr std::uint16_t quick_stop = 0x0002;         // -> quick stop active
inline constexpr std::uint16_t disable_operation = 0x0007;  // -> switched on
inline constexpr std::uint16_t fault_reset_bit = 0x0080;    // acts on the rising edge
}  // namespace controlword

namespace statusword_bit {
inline constexpr std::uint16_t voltage_enabled = 1u << 4;
inline constexpr std::uint16_t warning = 1u << 7;
inline constexpr std::uint16_t remote = 1u << 9;
inline constexpr std::uint16_t target_reached = 1u << 10;
inline constexpr std::uint16_t internal_limit = 1u << 11;
inline constexpr std::uint16_t following_error = 1u << 13;  // CSP: following error
}  // namespace statusword_bit

enum class OperationMode : std::int8_t {
  profile_position = 1,
  profile_velocity = 3,
  homing = 6,
  cyclic_synchronous_position = 8,
  cyclic_synchronous_velocity = 9,
};

// EMCY error codes used by tendril's drives (CiA 301 / CiA 402 classes).
namespace emcy_code {
inline constexpr std::uint16_t no_error = 0x0000;
inline constexpr std::uint16_t generic = 0x1000;
inline constexpr std::uint16_t over_current = 0x2310;
inline constexpr std::uint16_t over_voltage = 0x3210;
inline constexpr std::uint16_t over_temperature = 0x4210;
inline constexpr std::uint16_t heartbeat_lost = 0x8130;  // life guard / heartbeat error
inline constexpr std::uint16_t following_error = 0x8611;
inline constexpr std::uint16_t position_limit = 0x8612;
}  // namespace emcy_code

// Little-endian helpers for SDO/PDO payloads.
inline void put_u16(std::uint8_t* p, std::uint16_t v) noexcept {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
inline void put_u32(std::uint8_t* p, std::uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline std::uint16_t get_u16(const std::uint8_t* p) noexcept {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
inline std::uint32_t get_u32(const std::uint8_t* p) noexcept {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

}  // namespace tendril::canopen
