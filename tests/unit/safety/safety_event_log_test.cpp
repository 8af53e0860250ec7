#include "tendril/safety/safety_event_log.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <cstring>
#include <thread>
#include <vector>

namespace tendril::safety {
namespace {

SafetyEvent make_event(int i) {
  SafetyEvent e;
  e.time = i * 0.001;
  e.kind = EventKind::kFault;
  e.code = FaultCode::kLostControlTime;
  e.joint = i % 7;
  std::snprintf(e.text, sizeof(e.text), "event %d", i);
  return e;
}

TEST(SafetyEventLog, DrainsInOrderAndOnlyOnce) {
  SafetyEventLog log;
  for (int i = 0; i < 10; ++i) EXPECT_EQ(log.push(make_event(i)), static_cast<std::uint64_t>(i));
  std::vector<SafetyEvent> got;
  EXPECT_EQ(log.drain([&](const SafetyEvent& e) { got.push_back(e); }), 10u);
  ASSERT_EQ(got.size(), 10u);
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(got[i].sequence, static_cast<std::uint64_t>(i));
    EXPECT_DOUBLE_EQ(got[i].time, i * 0.001);
    EXPECT_EQ(got[i].joint, i % 7);
    char expected[16];
    std::snprintf(expected, sizeof(expected), "event %d", i);
    EXPECT_STREQ(got[i].text, expected);
  }
  EXPECT_EQ(log.drain([&](const SafetyEvent&) { FAIL() << "nothing new"; }), 0u);
  log.push(make_event(10));
  EXPECT_EQ(log.drain([&](const SafetyEvent& e) { EXPECT_EQ(e.sequence, 10u); }), 1u);
  EXPECT_EQ(log.lost(), 0u);
}

TEST(SafetyEventLog, WrapAroundKeepsTheNewestAndCountsTheLost) {
  SafetyEventLog log;
  const int total = static_cast<int>(SafetyEventLog::kCapacity) * 3 + 17;
  for (int i = 0; i < total; ++i) log.push(make_event(i));
  std::vector<std::uint64_t> seqs;
  EXPECT_EQ(log.drain([&](const SafetyEvent& e) { seqs.push_back(e.sequence); }), SafetyEventLog::kCapacity);
  ASSERT_EQ(seqs.size(), SafetyEventLog::kCapacity);
  EXPECT_EQ(seqs.front(), static_cast<std::uint64_t>(total) - SafetyEventLog::kCapacity);
  EXPECT_EQ(seqs.back(), static_cast<std::uint64_t>(total - 1));
  for (std::size_t i = 1; i < seqs.size(); ++i) EXPECT_EQ(seqs[i], seqs[i - 1] + 1);
  EXPECT_EQ(log.lost(), static_cast<std::uint64_t>(total) - SafetyEventLog::kCapacity);
}

TEST(SafetyEventLog, CopyNewestFirstDoesNotConsume) {
  SafetyEventLog log;
  for (int i = 0; i < 5; ++i) log.push(make_event(i));
  std::vector<SafetyEvent> out(3);
  ASSERT_EQ(log.copy_newest_first(out), 3u);
  EXPECT_EQ(out[0].sequence, 4u);
  EXPECT_EQ(out[1].sequence, 3u);
  EXPECT_EQ(out[2].sequence, 2u);
  std::vector<SafetyEvent> all(100);
  EXPECT_EQ(log.copy_newest_first(all), 5u);
  EXPECT_EQ(log.drain([](const SafetyEvent&) {}), 5u);  // still there for the drainer
}

TEST(SafetyEventLog, ConcurrentProducerAndConsumerSeeConsistentEvents) {
  SafetyEventLog log;
  constexpr int kEvents = 200000;
  std::atomic<bool> done{false};
  std::uint64_t delivered = 0, last = 0;
  bool ordered = true, consistent = true;
  std::thread consumer([&] {
    auto check = [&](const SafetyEvent& e) {
      if (delivered > 0 && e.sequence <= last) ordered = false;
      last = e.sequence;
      char expected[96];
      std::snprintf(expected, sizeof(expected), "event %d", static_cast<int>(e.sequence));
      if (std::strcmp(expected, e.text) != 0 || e.joint != static_cast<int>(e.sequence % 7))
        consistent = false;
      ++delivered;
    };
    while (!done.load()) log.drain(check);
    log.drain(check);
  });
  for (int i = 0; i < kEvents; ++i) log.push(make_event(i));
  done.store(true);
  consumer.join();
  EXPECT_TRUE(ordered);
  EXPECT_TRUE(consistent);  // no torn events
  EXPECT_EQ(delivered + log.lost(), static_cast<std::uint64_t>(kEvents));
  EXPECT_EQ(last, static_cast<std::uint64_t>(kEvents - 1));
}

}  // namespace
}  // namespace tendril::safety
