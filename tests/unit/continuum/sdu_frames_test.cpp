// The SDU CAN frames: layout, round trip, reassembly under loss and garbage, and the bus load.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/drivers/canopen/bus_load.hpp"

namespace tendril::continuum {
namespace {

SduSample example() {
  SduSample s;
  s.received = true;
  for (std::size_t j = 0; j < kTofPerSdu; ++j) {
    s.tof_status[j] = TofStatus::kValid;
    s.tof_mm[j] = 10.0 * j + 3.4;
  }
  s.tof_status[5] = TofStatus::kNoTarget;
  s.tof_status[6] = TofStatus::kSensorError;
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    s.hall_ok[j] = true;
    s.hall_mT[j] = {-0.37 * j, 0.123 + j, 8.0 + 0.26 * j};
  }
  s.hall_ok[3] = false;
  return s;
}

TEST(SduFrames, LayoutIsSevenEightByteFramesInTheFreeIdRange) {
  const auto frames = encode_sdu_sample(4, example());
  for (std::size_t k = 0; k < kSduFramesPerSample; ++k) {
    EXPECT_EQ(frames[k].id, 0x680U + 4 * 8 + k);
    EXPECT_EQ(frames[k].len, 8);
    EXPECT_FALSE(frames[k].extended);
  }
  // ToF byte = mm, codes for no target and error.
  EXPECT_EQ(frames[0].data[1], 13);
  EXPECT_EQ(frames[0].data[5], kTofCodeNoTarget);
  EXPECT_EQ(frames[0].data[6], kTofCodeSensorError);
  // Hall: slot 0 z = 8.00 mT = 800 LSB, little-endian, third value of frame 1.
  EXPECT_EQ(frames[1].data[4] | (frames[1].data[5] << 8), 800);
  // The highest id stays inside CiA 301's free range 0x680-0x6DF for the largest bus.
  EXPECT_LE(encode_sdu_sample(kMaxSdusOnBus - 1, example())[6].id, 0x6DFU);
}

TEST(SduFrames, RoundTripKeepsEveryValueToItsResolution) {
  const SduSample in = example();
  const auto out = decode_sdu_frames(encode_sdu_sample(0, in), 42);
  EXPECT_EQ(out.stamp_ns, 42);
  for (std::size_t j = 0; j < kTofPerSdu; ++j) {
    EXPECT_EQ(out.tof_status[j], in.tof_status[j]) << j;
    if (in.tof_status[j] == TofStatus::kValid) {
      EXPECT_NEAR(out.tof_mm[j], in.tof_mm[j], 0.5);
    }
  }
  for (std::size_t j = 0; j < kHallPerSdu; ++j) {
    EXPECT_EQ(out.hall_ok[j], in.hall_ok[j]) << j;
    if (!in.hall_ok[j]) continue;
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(out.hall_mT[j][a], in.hall_mT[j][a], 0.005 + 1e-12);
  }
}

TEST(SduFrames, BadValuesTravelAsErrorCodesNotAsNumbers) {
  SduSample s = example();
  s.tof_mm[0] = std::nan("");
  s.tof_mm[1] = -4.0;
  s.tof_mm[2] = 900.0;  // beyond the byte: no target, never a wrapped number
  s.hall_mT[0][1] = std::numeric_limits<double>::infinity();
  s.hall_mT[1][2] = 1e6;  // saturates, never the error code or a wrap
  const auto out = decode_sdu_frames(encode_sdu_sample(0, s), 1);
  EXPECT_EQ(out.tof_status[0], TofStatus::kSensorError);
  EXPECT_EQ(out.tof_status[1], TofStatus::kSensorError);
  EXPECT_EQ(out.tof_status[2], TofStatus::kNoTarget);
  EXPECT_FALSE(out.hall_ok[0]);
  EXPECT_TRUE(out.hall_ok[1]);
  EXPECT_NEAR(out.hall_mT[1][2], 327.67, 1e-9);
}

TEST(SduFrames, AssemblerPublishesOnlyWholeSamples) {
  SduFrameAssembler a(5);
  const auto frames = encode_sdu_sample(2, example());
  for (std::size_t k = 0; k + 1 < kSduFramesPerSample; ++k) EXPECT_TRUE(a.handle(frames[k], 1000 + k));
  EXPECT_FALSE(a.latest(2).received);
  EXPECT_TRUE(a.handle(frames[6], 2000));
  EXPECT_TRUE(a.latest(2).received);
  EXPECT_EQ(a.latest(2).stamp_ns, 2000);
  EXPECT_EQ(a.counters().samples, 1U);
  // Another node's frame, an SDU beyond this bus's five, and an error frame are not ours.
  EXPECT_FALSE(a.handle(can::Frame::make(0x181, {1, 2}), 3000));
  EXPECT_FALSE(a.handle(encode_sdu_sample(5, example())[0], 3000));
  can::Frame err = frames[0];
  err.error = true;
  EXPECT_FALSE(a.handle(err, 3000));
}

TEST(SduFrames, ALostFrameDropsTheSampleAndNeverMixesTwo) {
  SduFrameAssembler a(1);
  SduSample first = example(), second = example();
  second.tof_mm[0] = 99.0;
  const auto f1 = encode_sdu_sample(0, first), f2 = encode_sdu_sample(0, second);
  for (std::size_t k = 0; k < kSduFramesPerSample; ++k)
    if (k != 3) a.handle(f1[k], 1'000'000);  // frame 3 lost
  for (std::size_t k = 0; k < kSduFramesPerSample; ++k) a.handle(f2[k], 11'000'000);
  EXPECT_EQ(a.counters().incomplete, 1U);
  EXPECT_EQ(a.counters().samples, 1U);
  EXPECT_EQ(a.latest(0).tof_mm[0], 99.0);
  // A partial sample older than the assembly time is dropped, even when the next frame is a new index.
  SduFrameAssembler b(1, 5'000'000);
  b.handle(f1[0], 0);
  for (std::size_t k = 1; k < kSduFramesPerSample; ++k) b.handle(f2[k], 9'000'000);
  EXPECT_EQ(b.counters().incomplete, 1U);
  EXPECT_FALSE(b.latest(0).received);
}

TEST(SduFrames, MalformedFramesAreCountedAndIgnored) {
  SduFrameAssembler a(1);
  auto f = encode_sdu_sample(0, example());
  can::Frame short_frame = f[0];
  short_frame.len = 7;
  can::Frame rtr = f[1];
  rtr.rtr = true;
  EXPECT_TRUE(a.handle(short_frame, 0));
  EXPECT_TRUE(a.handle(rtr, 0));
  EXPECT_EQ(a.counters().malformed, 2U);
  EXPECT_EQ(a.counters().frames, 0U);
  EXPECT_THROW(SduFrameAssembler(0), std::invalid_argument);
  EXPECT_THROW(SduFrameAssembler(kMaxSdusOnBus + 1), std::invalid_argument);
}

TEST(SduFrames, FiveDisksAt100HzFitAClassicMegabitBus) {
  const auto load = estimate_sdu_bus_load(1'000'000, 100.0, 5);
  // 8-byte frame, worst-case stuffing: 47 + 64 + ⌊97/4⌋ = 135 bit; SYNC 55 bit.
  EXPECT_EQ(canopen::worst_case_frame_bits(8), 135U);
  EXPECT_DOUBLE_EQ(load.bits_per_sample_period, 5 * 7 * 135 + 55);
  EXPECT_NEAR(load.load, 0.478, 1e-9);
  EXPECT_LT(load.load, 0.70);  // the server's default bus ceiling
  std::printf("SDU bus load: %s\n", load.breakdown.c_str());
  // The dissertation's 4.26 Hz would use 2 %; at 200 Hz five disks would not fit under 70 %.
  EXPECT_GT(estimate_sdu_bus_load(1'000'000, 200.0, 5).load, 0.70);
  std::printf("SDU bus load at the dissertation's 4.26 Hz: %s\n",
              estimate_sdu_bus_load(1'000'000, 4.26, 5).breakdown.c_str());
  // Sharing can0 with three CiA 402 axes at the SRMC's 2.5 ms SYNC would not fit: the SDUs get a bus.
  const auto drives =
      canopen::estimate_bus_load(1'000'000, std::chrono::microseconds(2500),
                                 std::vector<canopen::DriveSetup>(3), std::chrono::milliseconds(100));
  std::printf("with 3 CiA 402 axes at 400 Hz on the same bus: %.1f %%\n", 100.0 * (drives.load + load.load));
  EXPECT_GT(drives.load + load.load, 0.70);
  EXPECT_THROW(estimate_sdu_bus_load(0, 100.0, 5), std::invalid_argument);
  EXPECT_THROW(estimate_sdu_bus_load(1'000'000, std::nan(""), 5), std::invalid_argument);
}

}  // namespace
}  // namespace tendril::continuum
