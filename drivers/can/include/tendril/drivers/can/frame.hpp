// CAN frame and bus-state types shared by every bus implementation (SocketCAN, virtual).
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <initializer_list>
#include <string>

namespace tendril::can {

using Clock = std::chrono::steady_clock;

// A classic CAN 2.0 frame (11- or 29-bit id, up to 8 data bytes).
struct Frame {
  std::uint32_t id = 0;   // without flag bits
  bool extended = false;  // 29-bit identifier
  bool rtr = false;       // remote transmission request
  bool error = false;     // error frame reported by the controller (id holds CAN_ERR_* class bits)
  std::uint8_t len = 0;   // 0..8
  std::array<std::uint8_t, 8> data{};
  Clock::time_point timestamp{};  // receive time (or send time for loop-back copies)

  static Frame make(std::uint32_t id, std::initializer_list<std::uint8_t> bytes) {
    Frame f;
    f.id = id;
    f.len = static_cast<std::uint8_t>(bytes.size() > 8 ? 8 : bytes.size());
    std::size_t i = 0;
    for (auto b : bytes) {
      if (i >= 8) break;
      f.data[i++] = b;
    }
    return f;
  }
};

// Controller state as seen by the bus (ISO 11898 fault confinement).
enum class BusState : std::uint8_t { error_active, error_warning, error_passive, bus_off };

const char* to_string(BusState s) noexcept;

// Error-frame class bits carried in Frame::id when Frame::error is set (same values as Linux
// <linux/can/error.h>, so SocketCAN and the virtual bus report errors alike).
namespace error_class {
inline constexpr std::uint32_t tx_timeout = 0x001;
inline constexpr std::uint32_t lost_arbitration = 0x002;
inline constexpr std::uint32_t controller = 0x004;  // data[1]: warning / passive / overflow bits
inline constexpr std::uint32_t protocol = 0x008;    // data[2..3]: violation type and location
inline constexpr std::uint32_t transceiver = 0x010;
inline constexpr std::uint32_t no_ack = 0x020;
inline constexpr std::uint32_t bus_off = 0x040;
inline constexpr std::uint32_t bus_error = 0x080;
inline constexpr std::uint32_t restarted = 0x100;
}  // namespace error_class

// Outcome of a non-blocking send; never an exception in the real-time path.
enum class SendResult : std::uint8_t { ok, would_block, bus_off, too_long, closed, io_error };

const char* to_string(SendResult r) noexcept;

// Human-readable one-line dump in candump style: "123#DEADBEEF".
std::string format_frame(const Frame& f);

}  // namespace tendril::can
