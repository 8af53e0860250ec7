#include "tendril/drivers/canopen/bus_load.hpp"

#include <cstdio>
#include <stdexcept>

namespace tendril::canopen {

std::uint32_t worst_case_frame_bits(std::uint8_t len, bool extended) noexcept {
  const std::uint32_t n = len > 8 ? 8 : len;
  if (extended) return 67 + 8 * n + (54 + 8 * n - 1) / 4;
  return 47 + 8 * n + (34 + 8 * n - 1) / 4;
}

BusLoad estimate_bus_load(std::uint32_t bitrate, std::chrono::microseconds sync_period,
                          const std::vector<DriveSetup>& drives,
                          std::chrono::milliseconds master_heartbeat_period) {
  if (bitrate == 0) throw std::invalid_argument("bus load: bitrate must be > 0");
  if (sync_period.count() <= 0) throw std::invalid_argument("bus load: SYNC period must be > 0");

  const double sync_bits = worst_case_frame_bits(0);
  const double pdo_bits = worst_case_frame_bits(6);  // RPDO1, TPDO1 and TPDO2 all carry 6 bytes
  const double heartbeat_bits = worst_case_frame_bits(1);
  const double per_axis_bits = 3 * pdo_bits;
  const double cycles_per_second = 1e6 / static_cast<double>(sync_period.count());

  BusLoad out;
  out.bits_per_cycle = sync_bits + per_axis_bits * static_cast<double>(drives.size());
  double heartbeat_bps = 0.0;
  for (const auto& d : drives) {
    if (d.heartbeat_producer_ms > 0) heartbeat_bps += heartbeat_bits * 1000.0 / d.heartbeat_producer_ms;
  }
  if (master_heartbeat_period.count() > 0)
    heartbeat_bps += heartbeat_bits * 1000.0 / static_cast<double>(master_heartbeat_period.count());
  out.bits_per_second = out.bits_per_cycle * cycles_per_second + heartbeat_bps;
  out.load = out.bits_per_second / bitrate;

  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "%.1f %% of %u bit/s: SYNC %.0f bit + %zu axis x (RPDO1 + TPDO1 + TPDO2 = %.0f bit, %.0f us) "
      "per %lld us cycle = %.0f bit/s; heartbeats %.0f bit/s; total %.0f bit/s (worst-case stuffing)",
      out.load * 100.0, static_cast<unsigned>(bitrate), sync_bits, drives.size(), per_axis_bits,
      per_axis_bits * 1e6 / bitrate, static_cast<long long>(sync_period.count()),
      out.bits_per_cycle * cycles_per_second, heartbeat_bps, out.bits_per_second);
  out.breakdown = buf;
  return out;
}

}  // namespace tendril::canopen
