#include <gtest/gtest.h>

#include <thread>

#include "tendril/drivers/can/virtual_bus.hpp"

namespace tendril::can {
namespace {

using namespace std::chrono_literals;

TEST(VirtualBus, EveryOtherEndpointReceivesInOrderButNotTheSender) {
  VirtualBus bus("vbus", 500'000);
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  auto c = bus.attach("c");
  const auto before = Clock::now();
  ASSERT_EQ(a->send(Frame::make(0x101, {1})), SendResult::ok);
  ASSERT_EQ(a->send(Frame::make(0x102, {2, 3})), SendResult::ok);
  for (auto* ep : {b.get(), c.get()}) {
    EXPECT_EQ(ep->pending(), 2u);
    auto f1 = ep->receive(0ns);
    auto f2 = ep->receive(0ns);
    ASSERT_TRUE(f1 && f2);
    EXPECT_EQ(f1->id, 0x101u);
    EXPECT_EQ(f2->id, 0x102u);
    EXPECT_EQ(f2->len, 2);
    EXPECT_EQ(f2->data[1], 3);
    EXPECT_GE(f1->timestamp, before);
    EXPECT_LE(f1->timestamp, f2->timestamp);
    EXPECT_FALSE(ep->receive(0ns));
  }
  EXPECT_FALSE(a->receive(0ns));  // no loop-back
  EXPECT_EQ(a->statistics().frames_sent, 2u);
  EXPECT_EQ(b->statistics().frames_received, 2u);
  EXPECT_EQ(a->bitrate(), 500'000u);
  EXPECT_EQ(b->name(), "vbus/b");
}

TEST(VirtualBus, ReceiveTimesOutWhenNothingArrives) {
  VirtualBus bus("vbus");
  auto a = bus.attach("a");
  const auto t0 = Clock::now();
  EXPECT_FALSE(a->receive(20ms));
  EXPECT_GE(Clock::now() - t0, 20ms);  // it waited (lower bound only; no upper bound on a busy host)
}

TEST(VirtualBus, ReceiveWakesUpWhenAFrameIsSentFromAnotherThread) {
  VirtualBus bus("vbus");
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  std::thread sender([&] {
    std::this_thread::sleep_for(10ms);
    a->send(Frame::make(0x7FF, {0xAA}));
  });
  auto f = b->receive(10s);
  sender.join();
  ASSERT_TRUE(f);
  EXPECT_EQ(f->id, 0x7FFu);
}

TEST(VirtualBus, FullQueueDropsTheOldestAndCountsOverflow) {
  VirtualBus bus("vbus", 1'000'000, 3);
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  for (std::uint8_t i = 0; i < 5; ++i) a->send(Frame::make(0x100 + i, {i}));
  EXPECT_EQ(b->pending(), 3u);
  EXPECT_EQ(b->statistics().receive_overflows, 2u);
  EXPECT_EQ(b->receive(0ns)->id, 0x102u);  // the two oldest went
  EXPECT_EQ(b->receive(0ns)->id, 0x103u);
  EXPECT_EQ(b->receive(0ns)->id, 0x104u);
}

TEST(VirtualBus, RejectsOverlongFrames) {
  VirtualBus bus("vbus");
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  Frame f = Frame::make(0x1, {1});
  f.len = 9;
  EXPECT_EQ(a->send(f), SendResult::too_long);
  EXPECT_EQ(a->statistics().send_failures, 1u);
  EXPECT_EQ(b->pending(), 0u);
}

TEST(VirtualBus, BusOffInjectionFailsSendsAndReportsErrorFrames) {
  VirtualBus bus("vbus");
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  bus.set_bus_off("a", true);
  EXPECT_EQ(a->state(), BusState::bus_off);
  EXPECT_EQ(a->send(Frame::make(0x1, {1})), SendResult::bus_off);
  EXPECT_EQ(b->pending(), 0u);
  b->send(Frame::make(0x2, {2}));  // a bus-off controller hears nothing
  auto err = a->receive(0ns);
  ASSERT_TRUE(err);
  EXPECT_TRUE(err->error);
  EXPECT_EQ(err->id & error_class::bus_off, error_class::bus_off);
  EXPECT_FALSE(a->receive(0ns));
  auto stats = a->statistics();
  EXPECT_EQ(stats.bus_off_events, 1u);
  EXPECT_EQ(stats.error_frames, 1u);
  EXPECT_EQ(stats.send_failures, 1u);

  bus.set_bus_off("a", false);
  EXPECT_EQ(a->state(), BusState::error_active);
  auto restarted = a->receive(0ns);
  ASSERT_TRUE(restarted);
  EXPECT_TRUE(restarted->error);
  EXPECT_EQ(restarted->id, error_class::restarted);
  EXPECT_EQ(a->send(Frame::make(0x3, {3})), SendResult::ok);
  EXPECT_EQ(b->receive(0ns)->id, 0x3u);
  EXPECT_THROW(bus.set_bus_off("nobody", true), std::invalid_argument);
}

TEST(VirtualBus, DetachedEndpointsStopReceivingAndNamesAreUnique) {
  VirtualBus bus("vbus");
  auto a = bus.attach("a");
  auto b = bus.attach("b");
  EXPECT_THROW(bus.attach("a"), std::invalid_argument);
  b.reset();
  EXPECT_EQ(a->send(Frame::make(0x1, {})), SendResult::ok);  // nobody listening is fine
  auto b2 = bus.attach("b");
  EXPECT_EQ(b2->pending(), 0u);
}

}  // namespace
}  // namespace tendril::can
