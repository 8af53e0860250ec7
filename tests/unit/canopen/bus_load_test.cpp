#include <gtest/gtest.h>

#include "tendril/drivers/canopen/bus_load.hpp"

namespace tendril::canopen {
namespace {

using namespace std::chrono_literals;

std::vector<DriveSetup> axes(std::size_t n) {
  std::vector<DriveSetup> d(n);
  for (std::size_t i = 0; i < n; ++i) d[i].node_id = static_cast<std::uint8_t>(i + 1);
  return d;
}

TEST(BusLoad, WorstCaseFrameBits) {
  EXPECT_EQ(worst_case_frame_bits(0), 55u);         // 47 + 0 + floor(33/4) = 8
  EXPECT_EQ(worst_case_frame_bits(1), 65u);         // 55 + floor(41/4) = 10
  EXPECT_EQ(worst_case_frame_bits(6), 115u);        // 95 + floor(81/4) = 20
  EXPECT_EQ(worst_case_frame_bits(8), 135u);        // 111 + floor(97/4) = 24
  EXPECT_EQ(worst_case_frame_bits(8, true), 160u);  // 131 + floor(117/4) = 29
}

TEST(BusLoad, OneAxisCostsAbout345MicrosecondsPerCycleAtOneMegabit) {
  // RPDO1 + TPDO1 + TPDO2, 6 bytes each: 3 x 115 bit = 345 us at 1 Mbit/s (a ~210 us estimate
  // counts RPDO + TPDO only, without worst-case stuffing).
  const auto load = estimate_bus_load(1'000'000, 1000us, axes(1), 0ms);
  EXPECT_DOUBLE_EQ(load.bits_per_cycle, 55.0 + 345.0);
  EXPECT_NEAR(load.load, 0.40325, 1e-9);  // + one drive heartbeat: 65 bit every 20 ms
  EXPECT_NEAR(load.bits_per_second, 400'000.0 + 65.0 * 50, 1e-6);
}

TEST(BusLoad, FourAxesAtOneKilohertzExceedSeventyPercent) {
  const auto load = estimate_bus_load(1'000'000, 1000us, axes(4), 20ms);
  EXPECT_GT(load.load, 0.70);
  EXPECT_NEAR(load.load, (55 + 4 * 345) / 1000.0 + 5 * 65 * 50 / 1e6, 1e-9);
  EXPECT_NE(load.breakdown.find("4 axis"), std::string::npos) << load.breakdown;
  EXPECT_NE(load.breakdown.find("1000000 bit/s"), std::string::npos) << load.breakdown;
}

TEST(BusLoad, HalvingTheRateHalvesTheCyclicPart) {
  // 4 axes at 500 Hz: (55 + 1380) bit / 2 ms = 71.75 % + heartbeats 1.6 %: still over 70 % with
  // TPDO2 every SYNC; 3 axes at 500 Hz and 4 axes at 250 Hz are under it.
  const auto four_500 = estimate_bus_load(1'000'000, 2000us, axes(4), 20ms);
  EXPECT_NEAR(four_500.load, 0.7175 + 0.01625, 1e-9);
  const auto three_500 = estimate_bus_load(1'000'000, 2000us, axes(3), 20ms);
  EXPECT_LT(three_500.load, 0.70);
  const auto four_250 = estimate_bus_load(1'000'000, 4000us, axes(4), 20ms);
  EXPECT_LT(four_250.load, 0.70);
  const auto four_500_at_500k = estimate_bus_load(500'000, 2000us, axes(4), 20ms);
  EXPECT_NEAR(four_500_at_500k.load, 2 * four_500.load, 1e-9);
}

TEST(BusLoad, RejectsNonsense) {
  EXPECT_THROW(estimate_bus_load(0, 1000us, axes(1), 20ms), std::invalid_argument);
  EXPECT_THROW(estimate_bus_load(1'000'000, 0us, axes(1), 20ms), std::invalid_argument);
}

}  // namespace
}  // namespace tendril::canopen
