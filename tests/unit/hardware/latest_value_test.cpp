// hardware::LatestValue: the newest complete store for every reader, whatever the writer is doing —
// in particular a reader never waits for a writer stopped half way through a store (a preempted
// normal-priority writer under a real-time reader on the same CPU).
#include "tendril/drivers/hardware/latest_value.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <thread>
#include <vector>

namespace tendril::hardware {

// A store stopped between its halves, as a preemption would stop it.
template <typename T>
struct LatestValueTestAccess {
  static int begin_store(LatestValue<T>& v, const T& value) { return v.begin_store(value); }
  static void end_store(LatestValue<T>& v, int next) { v.end_store(next); }
};

namespace {

struct Sample {
  std::array<std::uint64_t, 64> word{};  // every word the same: a torn read shows as two values
};

Sample sample(std::uint64_t k) {
  Sample s;
  s.word.fill(k);
  return s;
}

using Access = LatestValueTestAccess<Sample>;

TEST(LatestValue, ReadsTheLastStoreAndCountsStores) {
  LatestValue<Sample> v;
  EXPECT_EQ(v.version(), 0u);
  EXPECT_EQ(v.load().word[0], 0u);  // before any store: zero bytes
  v.store(sample(7));
  v.store(sample(8));
  EXPECT_EQ(v.load().word[63], 8u);
  EXPECT_EQ(v.version(), 2u);
}

TEST(LatestValue, AReaderDoesNotWaitForAStoreStoppedHalfWay) {
  LatestValue<Sample> v;
  v.store(sample(1));
  const int pending = Access::begin_store(v, sample(2));  // the writer is preempted here
  // With one seqlock buffer this read spun until the writer ran again (here: never).
  EXPECT_EQ(v.load().word[0], 1u);
  EXPECT_EQ(v.version(), 1u);
  Access::end_store(v, pending);
  EXPECT_EQ(v.load().word[0], 2u);
  EXPECT_EQ(v.version(), 2u);
}

TEST(LatestValue, AStoppedStoreAfterManyLeavesTheNewestCompleteOne) {
  LatestValue<Sample> v;
  for (std::uint64_t k = 1; k <= 5; ++k) v.store(sample(k));
  // The sixth store rewrites the buffer the fourth one filled; readers keep the fifth.
  const int pending = Access::begin_store(v, sample(6));
  const Sample s = v.load();
  EXPECT_EQ(s.word[0], 5u);
  EXPECT_EQ(s.word[63], 5u);
  Access::end_store(v, pending);
  EXPECT_EQ(v.load().word[0], 6u);
}

TEST(LatestValue, ConcurrentReadersSeeWholeValuesInOrder) {
  LatestValue<Sample> v;
  std::atomic<bool> stop{false};
  std::atomic<int> torn{0}, backwards{0};
  std::atomic<std::uint64_t> reads{0};
  std::vector<std::thread> readers;
  for (int r = 0; r < 2; ++r) {
    readers.emplace_back([&] {
      std::uint64_t last = 0;
      while (!stop.load()) {
        const Sample s = v.load();
        for (const auto w : s.word)
          if (w != s.word[0]) ++torn;
        if (s.word[0] < last) ++backwards;
        last = s.word[0];
        ++reads;
      }
    });
  }
  std::uint64_t k = 0;
  while (k < 200'000 || reads.load() < 1000) v.store(sample(++k));
  stop = true;
  for (auto& t : readers) t.join();
  EXPECT_EQ(torn.load(), 0);
  EXPECT_EQ(backwards.load(), 0);
  EXPECT_EQ(v.load().word[0], k);
  EXPECT_EQ(v.version(), k);
}

}  // namespace
}  // namespace tendril::hardware
