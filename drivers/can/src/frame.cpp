#include "tendril/drivers/can/frame.hpp"

#include <cstdio>

namespace tendril::can {

const char* to_string(BusState s) noexcept {
  switch (s) {
    case BusState::error_active:
      return "error_active";
    case BusState::error_warning:
      return "error_warning";
    case BusState::error_passive:
      return "error_passive";
    case BusState::bus_off:
      return "bus_off";
  }
  return "unknown";
}

const char* to_string(SendResult r) noexcept {
  switch (r) {
    case SendResult::ok:
      return "ok";
    case SendResult::would_block:
      return "would_block";
    case SendResult::bus_off:
      return "bus_off";
    case SendResult::too_long:
      return "too_long";
    case SendResult::closed:
      return "closed";
    case SendResult::io_error:
      return "io_error";
  }
  return "unknown";
}

std::string format_frame(const Frame& f) {
  // candump -L style: 3 hex digits for 11-bit ids, 8 for 29-bit ids and error frames.
  char buf[64];
  int n = 0;
  if (f.extended || f.error) {
    n = std::snprintf(buf, sizeof buf, "%08X#", static_cast<unsigned>(f.id & 0x1FFF'FFFFu));
  } else {
    n = std::snprintf(buf, sizeof buf, "%03X#", static_cast<unsigned>(f.id & 0x7FFu));
  }
  std::string out(buf, static_cast<std::size_t>(n));
  if (f.rtr) {
    out += 'R';
    if (f.len > 0) out += std::to_string(f.len > 8 ? 8 : f.len);
    return out;
  }
  const std::size_t len = f.len > 8 ? 8 : f.len;
  for (std::size_t i = 0; i < len; ++i) {
    std::snprintf(buf, sizeof buf, "%02X", f.data[i]);
    out += buf;
  }
  if (f.error) out += " (error frame)";
  return out;
}

}  // namespace tendril::can
