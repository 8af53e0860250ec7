#include "tendril/drivers/canopen/protocol.hpp"

namespace tendril::canopen {

const char* sdo_abort_text(std::uint32_t code) noexcept {
  switch (code) {
    case sdo_abort::toggle_bit:
      return "toggle bit not alternated";
    case sdo_abort::timeout:
      return "SDO protocol timed out";
    case sdo_abort::invalid_command:
      return "client/server command specifier not valid or unknown";
    case 0x0504'0002:
      return "invalid block size";
    case 0x0504'0003:
      return "invalid sequence number";
    case 0x0504'0004:
      return "CRC error";
    case sdo_abort::out_of_memory:
      return "out of memory";
    case sdo_abort::unsupported_access:
      return "unsupported access to an object";
    case sdo_abort::write_only:
      return "attempt to read a write-only object";
    case sdo_abort::read_only:
      return "attempt to write a read-only object";
    case sdo_abort::no_object:
      return "object does not exist in the object dictionary";
    case sdo_abort::cannot_map:
      return "object cannot be mapped to the PDO";
    case sdo_abort::map_too_long:
      return "number and length of mapped objects would exceed the PDO length";
    case 0x0604'0043:
      return "general parameter incompatibility";
    case 0x0604'0047:
      return "general internal incompatibility in the device";
    case 0x0606'0000:
      return "access failed due to a hardware error";
    case sdo_abort::length_mismatch:
      return "data type does not match, length of service parameter does not match";
    case sdo_abort::length_too_high:
      return "data type does not match, length of service parameter too high";
    case sdo_abort::length_too_low:
      return "data type does not match, length of service parameter too low";
    case sdo_abort::no_subindex:
      return "sub-index does not exist";
    case 0x0609'0031:
      return "value of parameter written too high";
    case 0x0609'0032:
      return "value of parameter written too low";
    case 0x0609'0036:
      return "maximum value is less than minimum value";
    case sdo_abort::value_range:
      return "value range of parameter exceeded";
    case 0x060A'0023:
      return "resource not available: SDO connection";
    case sdo_abort::general:
      return "general error";
    case 0x0800'0020:
      return "data cannot be transferred or stored to the application";
    case 0x0800'0021:
      return "data cannot be transferred or stored because of local control";
    case sdo_abort::wrong_state:
      return "data cannot be transferred or stored because of the present device state";
    case 0x0800'0023:
      return "object dictionary not present or dynamic generation failed";
    case 0x0800'0024:
      return "no data available";
  }
  return "unknown abort code";
}

const char* to_string(Cia402State s) noexcept {
  switch (s) {
    case Cia402State::not_ready_to_switch_on:
      return "not_ready_to_switch_on";
    case Cia402State::switch_on_disabled:
      return "switch_on_disabled";
    case Cia402State::ready_to_switch_on:
      return "ready_to_switch_on";
    case Cia402State::switched_on:
      return "switched_on";
    case Cia402State::operation_enabled:
      return "operation_enabled";
    case Cia402State::quick_stop_active:
      return "quick_stop_active";
    case Cia402State::fault_reaction_active:
      return "fault_reaction_active";
    case Cia402State::fault:
      return "fault";
  }
  return "unknown";
}

// CiA 402 statusword patterns. Bit 0 ready to switch on, 1 switched on, 2 operation enabled,
// 3 fault, 5 quick stop (active low), 6 switch on disabled.
Cia402State decode_statusword(std::uint16_t sw) noexcept {
  const std::uint16_t m4f = sw & 0x4F;
  const std::uint16_t m6f = sw & 0x6F;
  if (m4f == 0x00) return Cia402State::not_ready_to_switch_on;
  if (m4f == 0x40) return Cia402State::switch_on_disabled;
  if (m6f == 0x21) return Cia402State::ready_to_switch_on;
  if (m6f == 0x23) return Cia402State::switched_on;
  if (m6f == 0x27) return Cia402State::operation_enabled;
  if (m6f == 0x07) return Cia402State::quick_stop_active;
  if (m4f == 0x0F) return Cia402State::fault_reaction_active;
  if (m4f == 0x08) return Cia402State::fault;
  // Patterns the table does not define (e.g. 0x01 with bit 5 clear) are treated as a fault so a
  // confused drive is never taken for an enabled one.
  return Cia402State::fault;
}

std::uint16_t encode_statusword(Cia402State s) noexcept {
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
  return 0x0008;
}

}  // namespace tendril::canopen
