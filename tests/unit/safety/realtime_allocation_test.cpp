// The supervisor's per-tick methods and the event log must not touch the heap.
#include <gtest/gtest.h>

#include <array>
#include <memory>

#include "allocation_counter.hpp"
#include "tendril/safety/safety_supervisor.hpp"

namespace tendril::safety {
namespace {

TEST(SafetyRealtime, SupervisorTickPathDoesNotAllocate) {
  auto s = std::make_unique<SafetySupervisor>(LimitSet({
      {"insertion", "mm", 0.0, 100.0, 1.0, 5.0, 20.0, 0.5},
      {"roll", "rad", -3.0, 3.0, 0.1, 1.5, 5.0, 0.2},
  }));
  std::array<double, 2> measured{10.0, 0.0}, setpoint{10.0, 0.0}, q{-1.0, 5.0}, qd{9.0, 9.0};
  std::array<SafetyEvent, 8> newest;

  const long before = tendril::testing::allocation_count.load();
  double t = 0.0;
  for (int round = 0; round < 100; ++round) {  // > 256 events: the log wraps
    s->request(t += 0.001, StateCommand::kEnable);
    s->servo_command_received(t);
    s->tick(t += 0.001, measured, setpoint);
    s->clamp_setpoint(q, qd);
    (void)s->check_goal(q);
    (void)s->check_velocity(qd);
    s->report_cycle(t, round % 2 == 0 ? 0.5 : 0.001, round % 4 == 0);
    s->tick(t += 0.5, measured, setpoint);  // servo timeout → hold event
    s->request(t, StateCommand::kPause);
    s->fault(t, FaultCode::kDriveEmergency, 1, "EMCY 0x2310 overcurrent");
    s->request(t, StateCommand::kEnable);  // refused in FAULT
    s->request(t, StateCommand::kDisable);
    s->estop(t);
    s->estop(t, "session:3 (operator)");
    s->reset_estop(t);
    s->request_estop();
    s->estop(t, "session:3 (operator)");
    s->reset_estop(t);
    s->record(t, EventKind::kRecovery, FaultCode::kSpringDeflection, -1, "springs relaxed");
  }
  s->events().copy_newest_first(newest);
  std::size_t drained = 0;
  s->events().drain([&](const SafetyEvent&) { ++drained; });
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  // The counter really sees allocations, so the check above can fail.
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_GT(s->events().pushed(), SafetyEventLog::kCapacity);
  EXPECT_EQ(drained, SafetyEventLog::kCapacity);
}

}  // namespace
}  // namespace tendril::safety
