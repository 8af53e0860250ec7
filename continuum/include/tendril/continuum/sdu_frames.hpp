// SDU samples and their CAN frames. The dissertation read its disks over I²C multiplexers into a Teensy and
// sent them over UDP at 4.26 Hz for 5 disks; tendril gives each disk its own CAN node (one microcontroller
// per SDU, the dissertation's own proposed speed-up) on classic CAN 2.0A at 1 Mbit/s, and reads all five at
// 100 Hz.
//
// Frame layout (11-bit ids, 8 data bytes each, little-endian), per disk i (0-based), 7 frames a sample:
//   id 0x680 + 8·i + 0   ToF: byte j = range of ToF slot j in mm (0–253); 254 = sensor error,
//                        255 = no target within the sensor's range
//   id 0x680 + 8·i + k   Hall, k = 1..6: four int16 values of 0.01 mT; values 4(k−1) … 4(k−1)+3 of
//                        the sequence B₀x B₀y B₀z B₁x … B₇z (slot, then axis x y z); −32768 = sensor error
// The ids lie in 0x680–0x6DF, which CiA 301's pre-defined connection set leaves free, so the disks
// share a bus with a CANopen master and its drives without a clash; their priority is below every PDO,
// so drive traffic wins arbitration. Nodes send a sample on every SYNC (or every n-th, transmission
// type n, so that they send at 100 Hz); the receiver does not need the SYNC: a sample is complete when
// the 7 frames of a disk have arrived within max_assembly_ns.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include "tendril/continuum/sdu_segment.hpp"
#include "tendril/drivers/can/frame.hpp"

namespace tendril::continuum {

inline constexpr std::uint32_t kSduFrameBaseId = 0x680;
inline constexpr std::uint32_t kSduIdsPerDisk = 8;
inline constexpr std::size_t kSduFramesPerSample = 7;
inline constexpr std::size_t kMaxSdusOnBus = 12;  // 0x680 + 12·8 = 0x6E0, the end of the free range
inline constexpr std::uint8_t kTofCodeSensorError = 254;
inline constexpr std::uint8_t kTofCodeNoTarget = 255;
inline constexpr std::int16_t kHallCodeSensorError = INT16_MIN;
inline constexpr double kHallLsbMilliTesla = 0.01;

enum class TofStatus : std::uint8_t { kValid, kNoTarget, kSensorError };
const char* to_string(TofStatus status) noexcept;

// One disk's readings as the control thread uses them. A simulator may fill it directly (doubles); the
// CAN path fills it from the frames. Nothing here is trusted: the supervisor checks every value.
struct SduSample {
  std::int64_t stamp_ns = 0;  // when the sample was complete (receive time of its last frame)
  bool received = false;      // false until the first complete sample
  std::array<double, kTofPerSdu> tof_mm{};
  std::array<TofStatus, kTofPerSdu> tof_status{};
  std::array<std::array<double, 3>, kHallPerSdu> hall_mT{};
  std::array<bool, kHallPerSdu> hall_ok{};
};

// The 7 frames of one disk's sample. Ranges are rounded to whole mm (the VL6180X's own resolution) and
// fields to 0.01 mT; an invalid or non-finite reading is sent as its error code.
std::array<can::Frame, kSduFramesPerSample> encode_sdu_sample(std::size_t disk,
                                                              const SduSample& sample) noexcept;

struct SduFrameRef {
  std::size_t disk = 0;
  std::size_t index = 0;  // 0 = ToF, 1..6 = Hall
};
// Which disk and frame an id carries, or nothing when the id is not an SDU frame of disks < disks.
std::optional<SduFrameRef> sdu_frame_ref(std::uint32_t id, std::size_t disks) noexcept;

struct SduAssemblerCounters {
  std::uint64_t frames = 0;      // SDU frames accepted
  std::uint64_t samples = 0;     // complete samples published
  std::uint64_t incomplete = 0;  // partial samples dropped (a frame lost, or too slow)
  std::uint64_t malformed = 0;   // an SDU id with the wrong length, RTR or extended id: ignored
};

// Reassembles samples from frames on the bus thread: no allocation, no locks, every input accepted.
class SduFrameAssembler {
 public:
  // Throws std::invalid_argument for 0 or more than kMaxSdusOnBus disks or a non-positive assembly time.
  explicit SduFrameAssembler(std::size_t disks, std::int64_t max_assembly_ns = 8'000'000);
  // True when the frame was an SDU frame (well formed or not) of one of this bus's disks.
  bool handle(const can::Frame& frame, std::int64_t now_ns) noexcept;
  // The newest complete sample of a disk (received = false before the first).
  const SduSample& latest(std::size_t disk) const noexcept { return latest_[disk < disks_ ? disk : 0]; }
  const SduAssemblerCounters& counters() const noexcept { return counters_; }
  std::size_t disks() const noexcept { return disks_; }

 private:
  struct Partial {
    std::array<can::Frame, kSduFramesPerSample> frames{};
    std::uint8_t mask = 0;
    std::int64_t first_ns = 0;
  };
  std::size_t disks_;
  std::int64_t max_assembly_ns_;
  std::array<Partial, kMaxSdusOnBus> partial_{};
  std::array<SduSample, kMaxSdusOnBus> latest_{};
  SduAssemblerCounters counters_{};
};

// Decodes a full set of 7 frames (index order) into a sample; values are finite by construction.
SduSample decode_sdu_frames(const std::array<can::Frame, kSduFramesPerSample>& frames,
                            std::int64_t stamp_ns) noexcept;

// Worst-case load of the SDU traffic on a classic CAN bus (worst-case bit stuffing, the same frame cost
// as the CANopen bus budget): disks × 7 eight-byte frames per sample at rate_hz, plus a SYNC per sample
// when the disks are triggered by one.
struct SduBusLoad {
  double load = 0.0;  // fraction of the bitrate
  double bits_per_second = 0.0;
  double bits_per_sample_period = 0.0;
  std::string breakdown;  // one line for a person
};
// Throws std::invalid_argument for a zero bitrate, a rate that is not positive and finite, or 0 or more
// than kMaxSdusOnBus disks.
SduBusLoad estimate_sdu_bus_load(std::uint32_t bitrate, double rate_hz, std::size_t disks,
                                 bool with_sync = true);

}  // namespace tendril::continuum
