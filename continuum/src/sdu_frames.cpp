#include "tendril/continuum/sdu_frames.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tendril/drivers/canopen/bus_load.hpp"

namespace tendril::continuum {

const char* to_string(TofStatus status) noexcept {
  switch (status) {
    case TofStatus::kValid:
      return "valid";
    case TofStatus::kNoTarget:
      return "no target";
    case TofStatus::kSensorError:
      return "sensor error";
  }
  return "unknown";
}

namespace {

std::uint8_t tof_code(double mm, TofStatus status) noexcept {
  if (status == TofStatus::kNoTarget) return kTofCodeNoTarget;
  if (status != TofStatus::kValid || !std::isfinite(mm) || mm < 0.0) return kTofCodeSensorError;
  const double r = std::round(mm);
  return r > 253.0 ? kTofCodeNoTarget : static_cast<std::uint8_t>(r);
}

std::int16_t hall_code(double mT, bool ok) noexcept {
  if (!ok || !std::isfinite(mT)) return kHallCodeSensorError;
  const double lsb = std::round(mT / kHallLsbMilliTesla);
  // A field beyond the wire's span saturates one code short of the error code.
  if (lsb <= -32767.0) return -32767;
  if (lsb >= 32767.0) return 32767;
  return static_cast<std::int16_t>(lsb);
}

}  // namespace

std::array<can::Frame, kSduFramesPerSample> encode_sdu_sample(std::size_t disk,
                                                              const SduSample& sample) noexcept {
  std::array<can::Frame, kSduFramesPerSample> frames{};
  for (std::size_t k = 0; k < kSduFramesPerSample; ++k) {
    frames[k].id =
        kSduFrameBaseId + static_cast<std::uint32_t>(disk) * kSduIdsPerDisk + static_cast<std::uint32_t>(k);
    frames[k].len = 8;
  }
  for (std::size_t j = 0; j < kTofPerSdu; ++j)
    frames[0].data[j] = tof_code(sample.tof_mm[j], sample.tof_status[j]);
  for (std::size_t v = 0; v < 3 * kHallPerSdu; ++v) {
    const std::size_t slot = v / 3;
    const auto code =
        static_cast<std::uint16_t>(hall_code(sample.hall_mT[slot][v % 3], sample.hall_ok[slot]));
    auto& f = frames[1 + v / 4];
    f.data[2 * (v % 4)] = static_cast<std::uint8_t>(code & 0xFFU);
    f.data[2 * (v % 4) + 1] = static_cast<std::uint8_t>(code >> 8);
  }
  return frames;
}

std::optional<SduFrameRef> sdu_frame_ref(std::uint32_t id, std::size_t disks) noexcept {
  if (id < kSduFrameBaseId) return std::nullopt;
  const std::uint32_t offset = id - kSduFrameBaseId;
  const std::size_t disk = offset / kSduIdsPerDisk;
  const std::size_t index = offset % kSduIdsPerDisk;
  if (disk >= disks || disk >= kMaxSdusOnBus || index >= kSduFramesPerSample) return std::nullopt;
  return SduFrameRef{disk, index};
}

SduSample decode_sdu_frames(const std::array<can::Frame, kSduFramesPerSample>& frames,
                            std::int64_t stamp_ns) noexcept {
  SduSample s;
  s.stamp_ns = stamp_ns;
  s.received = true;
  for (std::size_t j = 0; j < kTofPerSdu; ++j) {
    const std::uint8_t code = frames[0].data[j];
    if (code == kTofCodeNoTarget) {
      s.tof_status[j] = TofStatus::kNoTarget;
      s.tof_mm[j] = 0.0;
    } else if (code == kTofCodeSensorError) {
      s.tof_status[j] = TofStatus::kSensorError;
      s.tof_mm[j] = 0.0;
    } else {
      s.tof_status[j] = TofStatus::kValid;
      s.tof_mm[j] = code;
    }
  }
  s.hall_ok.fill(true);
  for (std::size_t v = 0; v < 3 * kHallPerSdu; ++v) {
    const auto& f = frames[1 + v / 4];
    const auto raw = static_cast<std::int16_t>(
        static_cast<std::uint16_t>(f.data[2 * (v % 4)] | (f.data[2 * (v % 4) + 1] << 8)));
    const std::size_t slot = v / 3;
    if (raw == kHallCodeSensorError) {
      s.hall_ok[slot] = false;
      s.hall_mT[slot][v % 3] = 0.0;
    } else {
      s.hall_mT[slot][v % 3] = raw * kHallLsbMilliTesla;
    }
  }
  for (std::size_t slot = 0; slot < kHallPerSdu; ++slot) {
    if (!s.hall_ok[slot])
      s.hall_mT[slot] = {0.0, 0.0, 0.0};  // one bad axis makes the sensor's reading unusable
  }
  return s;
}

SduFrameAssembler::SduFrameAssembler(std::size_t disks, std::int64_t max_assembly_ns)
    : disks_(disks), max_assembly_ns_(max_assembly_ns) {
  if (disks == 0 || disks > kMaxSdusOnBus)
    throw std::invalid_argument("SDU frame assembler: disks must be 1.." + std::to_string(kMaxSdusOnBus) +
                                ", got " + std::to_string(disks));
  if (max_assembly_ns <= 0) throw std::invalid_argument("SDU frame assembler: max_assembly_ns must be > 0");
}

bool SduFrameAssembler::handle(const can::Frame& frame, std::int64_t now_ns) noexcept {
  if (frame.error) return false;
  const auto ref = sdu_frame_ref(frame.id, disks_);
  if (!ref) return false;
  if (frame.extended || frame.rtr || frame.len != 8) {
    ++counters_.malformed;
    return true;
  }
  ++counters_.frames;
  Partial& p = partial_[ref->disk];
  const auto bit = static_cast<std::uint8_t>(1U << ref->index);
  // A frame already held, or a partial sample that waited too long, means a new sample has begun:
  // the old one lost a frame and is dropped whole, never mixed with the new one.
  if (p.mask != 0 && ((p.mask & bit) != 0 || now_ns - p.first_ns > max_assembly_ns_)) {
    ++counters_.incomplete;
    p.mask = 0;
  }
  if (p.mask == 0) p.first_ns = now_ns;
  p.frames[ref->index] = frame;
  p.mask = static_cast<std::uint8_t>(p.mask | bit);
  if (p.mask == (1U << kSduFramesPerSample) - 1U) {
    latest_[ref->disk] = decode_sdu_frames(p.frames, now_ns);
    ++counters_.samples;
    p.mask = 0;
  }
  return true;
}

SduBusLoad estimate_sdu_bus_load(std::uint32_t bitrate, double rate_hz, std::size_t disks, bool with_sync) {
  if (bitrate == 0) throw std::invalid_argument("SDU bus load: bitrate must be > 0");
  if (!std::isfinite(rate_hz) || rate_hz <= 0.0)
    throw std::invalid_argument("SDU bus load: rate must be > 0 Hz");
  if (disks == 0 || disks > kMaxSdusOnBus)
    throw std::invalid_argument("SDU bus load: disks must be 1.." + std::to_string(kMaxSdusOnBus));
  const double frame_bits = canopen::worst_case_frame_bits(8);
  const double sync_bits = with_sync ? canopen::worst_case_frame_bits(0) : 0.0;
  SduBusLoad out;
  out.bits_per_sample_period = static_cast<double>(disks * kSduFramesPerSample) * frame_bits + sync_bits;
  out.bits_per_second = out.bits_per_sample_period * rate_hz;
  out.load = out.bits_per_second / bitrate;
  char buf[320];
  std::snprintf(
      buf, sizeof buf,
      "%.1f %% of %u bit/s: %zu SDU x 7 frames x %.0f bit%s = %.0f bit per sample, at %.1f Hz = %.0f bit/s "
      "(worst-case stuffing; one sample period's frames take %.0f us of the %.0f us period)",
      out.load * 100.0, static_cast<unsigned>(bitrate), disks, frame_bits, with_sync ? " + SYNC" : "",
      out.bits_per_sample_period, rate_hz, out.bits_per_second, out.bits_per_sample_period * 1e6 / bitrate,
      1e6 / rate_hz);
  out.breakdown = buf;
  return out;
}

}  // namespace tendril::continuum
