// Fuzz target: CAN frames from the bus into the sensing disk units' frame assembler (Abah 2022, ch. 3,
// continuum/), and what it publishes into the SDU safety supervisor. Input bytes: id (2, LE, 11 bit),
// flags, len, data (8), then a time step in ms; repeated. Anything on the bus must either be ignored or
// decode to finite values inside the wire's span; a published sample must re-encode to the bytes it came
// from; and the supervisor must answer a finite speed limit within [0, v_max] for whatever it is given.
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_safety.hpp"

using namespace tendril;
using namespace tendril::continuum;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const SduSegmentModel model;
  static const auto poses = disk_poses(model, {});
  SduFrameAssembler assembler(kSdusPerSegment);
  SduSupervisorParameters params;
  params.unbias_samples = 1;  // reach the contact and drift paths with short inputs
  static SduSupervisor* supervisor = nullptr;
  delete supervisor;  // one per input, kept static so the event log's 40 KB is not on the stack
  supervisor = new SduSupervisor(model, kSdusPerSegment, params);
  std::array<SduSample, kSdusPerSegment> samples{};
  std::int64_t now = 1;
  std::uint64_t published = 0;
  for (std::size_t at = 0; at + 13 <= size; at += 13) {
    can::Frame f;
    f.id = static_cast<std::uint32_t>(data[at] | (data[at + 1] << 8)) & 0x7FFU;
    f.rtr = (data[at + 2] & 1U) != 0;
    f.error = (data[at + 2] & 2U) != 0;
    f.extended = (data[at + 2] & 4U) != 0;
    f.len = static_cast<std::uint8_t>(data[at + 3] % 9);
    for (std::size_t i = 0; i < 8; ++i) f.data[i] = data[at + 4 + i];
    now += static_cast<std::int64_t>(data[at + 12]) * 1'000'000;
    const auto before = assembler.counters().samples;
    const bool ours = assembler.handle(f, now);
    if (ours != (!f.error && sdu_frame_ref(f.id, kSdusPerSegment).has_value())) std::abort();
    if (assembler.counters().samples != before) {
      const auto ref = sdu_frame_ref(f.id, kSdusPerSegment);
      if (!ref) std::abort();
      const SduSample& s = assembler.latest(ref->disk);
      if (!s.received || s.stamp_ns != now) std::abort();
      for (std::size_t j = 0; j < kTofPerSdu; ++j)
        if (!std::isfinite(s.tof_mm[j]) || s.tof_mm[j] < 0.0 || s.tof_mm[j] > 253.0) std::abort();
      for (std::size_t j = 0; j < kHallPerSdu; ++j)
        for (double b : s.hall_mT[j])
          if (!std::isfinite(b) || std::abs(b) > 327.67 + 1e-9) std::abort();
      // The frame just handled is the sample's last: its bytes come back from the decoded sample
      // (the ToF frame always; a Hall frame when its sensors reported no error).
      const auto again = encode_sdu_sample(ref->disk, s);
      if (ref->index == 0) {
        for (std::size_t i = 0; i < 8; ++i)
          if (again[0].data[i] != f.data[i]) std::abort();
      }
      ++published;
    }
    if (published > assembler.counters().frames / kSduFramesPerSample) std::abort();
    for (std::size_t i = 0; i < kSdusPerSegment; ++i) samples[i] = assembler.latest(i);
    const auto& d = supervisor->step(now, poses, samples);
    if (!std::isfinite(d.speed_limit_mm_s) || d.speed_limit_mm_s < 0.0 ||
        d.speed_limit_mm_s > params.proximity.v_max_mm_s)
      std::abort();
    const auto v = apply_sdu_safety(d, params, Eigen::Vector3d(30.0, -40.0, 5.0));
    if (!v.allFinite() || v.norm() > params.proximity.v_max_mm_s + 1e-9) std::abort();
  }
  return 0;
}
