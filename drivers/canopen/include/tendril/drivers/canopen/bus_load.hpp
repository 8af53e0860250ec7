// Worst-case CAN bus load of the cyclic traffic a CanopenMaster puts on one bus.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "tendril/drivers/canopen/master.hpp"

namespace tendril::canopen {

// Bits on the wire for one classic CAN data frame with `len` data bytes, including the worst-case
// stuff bits (Davis et al.): 11-bit id: 47 + 8·len + ⌊(34 + 8·len − 1)/4⌋;
// 29-bit id: 67 + 8·len + ⌊(54 + 8·len − 1)/4⌋. Interframe space included.
std::uint32_t worst_case_frame_bits(std::uint8_t len, bool extended = false) noexcept;

struct BusLoad {
  double load = 0.0;             // fraction of the bitrate (1.0 = saturated)
  double bits_per_second = 0.0;  // worst case
  double bits_per_cycle = 0.0;   // SYNC + PDOs of one SYNC period (heartbeats excluded)
  std::string breakdown;         // one line a person can read: what costs how much
};

// Per SYNC period: SYNC (0 bytes), and per drive RPDO1 (6 bytes), TPDO1 (6) and TPDO2 (6);
// plus each drive's heartbeat (1 byte every heartbeat_producer_ms, if non-zero) and the master's
// heartbeat. Throws std::invalid_argument for a zero bitrate or a non-positive period.
BusLoad estimate_bus_load(std::uint32_t bitrate, std::chrono::microseconds sync_period,
                          const std::vector<DriveSetup>& drives,
                          std::chrono::milliseconds master_heartbeat_period);

}  // namespace tendril::canopen
