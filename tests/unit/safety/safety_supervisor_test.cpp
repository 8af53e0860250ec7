#include "tendril/safety/safety_supervisor.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace tendril::safety {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

LimitSet srmc_limits() {
  return LimitSet({
      {"insertion", "mm", 0.0, 100.0, 1.0, 5.0, 20.0, 0.5},
      {"roll", "rad", -3.0, 3.0, 0.1, 1.5, 5.0, 0.2},
      {"proximal", "mm", -1.0, 1.0, 0.05, 0.5, 2.0, 0.1},
      {"distal", "mm", -1.0, 1.0, 0.05, 0.5, 2.0, 0.1},
  });
}

std::unique_ptr<SafetySupervisor> make(SupervisorOptions options = {}) {
  return std::make_unique<SafetySupervisor>(srmc_limits(), options);
}

std::vector<SafetyEvent> drain(SafetySupervisor& s) {
  std::vector<SafetyEvent> events;
  s.events().drain([&](const SafetyEvent& e) { events.push_back(e); });
  return events;
}

const std::vector<double> kHome{10.0, 0.0, 0.0, 0.0};

TEST(SafetySupervisor, StartsDisabledAndFollowsTheStateMachine) {
  auto s = make();
  EXPECT_EQ(s->state(), OperatingState::kDisabled);
  EXPECT_EQ(s->request(0.0, StateCommand::kPause), CommandResult::kRefusedInvalidTransition);
  EXPECT_EQ(s->request(0.0, StateCommand::kResume), CommandResult::kRefusedInvalidTransition);
  EXPECT_EQ(s->request(0.0, StateCommand::kDisable), CommandResult::kAlreadyInState);
  EXPECT_EQ(s->request(0.1, StateCommand::kEnable), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
  EXPECT_TRUE(s->motion_allowed());
  EXPECT_EQ(s->request(0.1, StateCommand::kEnable), CommandResult::kAlreadyInState);
  EXPECT_EQ(s->request(0.1, StateCommand::kResume), CommandResult::kAlreadyInState);
  EXPECT_EQ(s->request(0.2, StateCommand::kPause), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kPaused);
  EXPECT_FALSE(s->motion_allowed());
  EXPECT_EQ(s->request(0.2, StateCommand::kPause), CommandResult::kAlreadyInState);
  EXPECT_EQ(s->request(0.2, StateCommand::kEnable), CommandResult::kRefusedInvalidTransition);
  EXPECT_EQ(s->request(0.3, StateCommand::kResume), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
  EXPECT_EQ(s->request(0.4, StateCommand::kPause), CommandResult::kAccepted);
  EXPECT_EQ(s->request(0.5, StateCommand::kDisable), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kDisabled);

  const auto events = drain(*s);
  // 3 refusals + 5 transitions (no-change requests are not logged), in order, each with its states.
  ASSERT_EQ(events.size(), 8u);
  EXPECT_EQ(events[0].kind, EventKind::kRefused);
  EXPECT_STREQ(events[0].text, "pause refused: not allowed from the current state");
  EXPECT_EQ(events[1].kind, EventKind::kRefused);
  EXPECT_EQ(events[2].kind, EventKind::kTransition);
  EXPECT_EQ(events[2].from, OperatingState::kDisabled);
  EXPECT_EQ(events[2].to, OperatingState::kEnabled);
  EXPECT_STREQ(events[2].text, "enable: DISABLED -> ENABLED");
  EXPECT_EQ(events[4].kind, EventKind::kRefused);  // enable while PAUSED
  EXPECT_EQ(events.back().to, OperatingState::kDisabled);
  for (std::size_t i = 1; i < events.size(); ++i) EXPECT_GE(events[i].time, events[i - 1].time);
}

TEST(SafetySupervisor, FaultRefusesMotionCommandsUntilAcknowledged) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  s->fault(1.0, FaultCode::kDriveHeartbeatLost, 2, "node 3 silent for 300 ms");
  EXPECT_EQ(s->state(), OperatingState::kFault);
  EXPECT_EQ(s->fault_cause().code, FaultCode::kDriveHeartbeatLost);
  EXPECT_EQ(s->fault_cause().joint, 2);
  EXPECT_STREQ(s->fault_cause().text, "drive heartbeat lost on joint 'proximal': node 3 silent for 300 ms");
  EXPECT_EQ(s->request(1.1, StateCommand::kEnable), CommandResult::kRefusedInFault);
  EXPECT_EQ(s->request(1.1, StateCommand::kResume), CommandResult::kRefusedInFault);
  EXPECT_EQ(s->request(1.1, StateCommand::kPause), CommandResult::kRefusedInFault);
  EXPECT_EQ(s->request(1.2, StateCommand::kDisable), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kDisabled);
  EXPECT_EQ(s->fault_cause().code, FaultCode::kNone);
  // A persisting cause that is reported again faults again, from any state.
  s->fault(1.3, FaultCode::kBusOff, -1, nullptr);
  EXPECT_EQ(s->state(), OperatingState::kFault);
  // Repeated reports of the same cause are logged once.
  s->fault(1.4, FaultCode::kBusOff, -1, nullptr);
  s->fault(1.5, FaultCode::kBusOff, -1, nullptr);
  int bus_off_events = 0;
  for (const auto& e : drain(*s))
    bus_off_events += e.code == FaultCode::kBusOff && e.kind == EventKind::kFault;
  EXPECT_EQ(bus_off_events, 1);
}

TEST(SafetySupervisor, EstopLatchSurvivesEnableAttemptsUntilReset) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  s->estop(1.0);
  EXPECT_TRUE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kFault);
  EXPECT_FALSE(s->motion_allowed());
  for (auto cmd :
       {StateCommand::kEnable, StateCommand::kDisable, StateCommand::kResume, StateCommand::kEnable})
    EXPECT_EQ(s->request(1.1, cmd), CommandResult::kRefusedEstopLatched);
  s->tick(1.2, kHome, kHome);
  EXPECT_TRUE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kFault);
  EXPECT_EQ(s->reset_estop(2.0), CommandResult::kAccepted);
  EXPECT_FALSE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kDisabled);  // comes back DISABLED, not ENABLED
  EXPECT_EQ(s->reset_estop(2.1), CommandResult::kAlreadyInState);
  EXPECT_EQ(s->request(2.2, StateCommand::kEnable), CommandResult::kAccepted);

  const auto events = drain(*s);
  ASSERT_GE(events.size(), 7u);
  EXPECT_EQ(events[1].kind, EventKind::kEstop);
  EXPECT_EQ(events[1].from, OperatingState::kEnabled);
  EXPECT_EQ(events[2].kind, EventKind::kRefused);
  EXPECT_EQ(events[6].kind, EventKind::kEstopReset);
  EXPECT_EQ(events[6].to, OperatingState::kDisabled);
}

TEST(SafetySupervisor, EstopRequestedFromAnotherThreadIsVisibleAtOnceAndLoggedByTheOwner) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  drain(*s);
  s->request_estop();
  EXPECT_TRUE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kFault);
  const TickResult r = s->tick(0.5, kHome, kHome);
  EXPECT_FALSE(r.motion_allowed);
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, EventKind::kEstop);
  EXPECT_DOUBLE_EQ(events[0].time, 0.5);
}

// The race the e-stop-under-load test found: a press while a reset waits in the mailbox was taken as
// "already latched", then the reset cleared the latch, so a 200 e-stop was followed by a DISABLED,
// unlatched robot until the press's own command came through (or never, had the mailbox been full).
TEST(SafetySupervisor, APressAfterAResetWasAskedForKeepsTheLatch) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  s->request_estop();
  s->tick(0.1, kHome, kHome);
  ASSERT_TRUE(s->estop_latched());
  const std::uint64_t seen = s->estop_presses();  // the reset is asked for now
  s->request_estop();                             // pressed again before the reset is carried out
  s->tick(0.2, kHome, kHome);                     // the control thread takes the press: already latched
  EXPECT_EQ(s->reset_estop(0.3, seen), CommandResult::kRefusedEstopLatched);
  EXPECT_TRUE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kFault);
  const auto events = drain(*s);
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().kind, EventKind::kRefused);
  EXPECT_NE(std::string(events.back().text).find("pressed again"), std::string::npos) << events.back().text;
  // A reset asked for after every press clears the latch.
  EXPECT_EQ(s->reset_estop(0.4, s->estop_presses()), CommandResult::kAccepted);
  EXPECT_FALSE(s->estop_latched());
  EXPECT_EQ(s->state(), OperatingState::kDisabled);
}

TEST(SafetySupervisor, GoalChecksNameTheJoint) {
  auto s = make();
  EXPECT_FALSE(s->check_goal(kHome));
  Violation v = s->check_goal(std::vector<double>{1.0, 2.0});
  EXPECT_EQ(v.kind, ViolationKind::kWrongSize);
  EXPECT_EQ(s->describe(v), "expected 4 values (one per joint), got 2");
  v = s->check_goal(std::vector<double>{10.0, kNaN, 0.0, 0.0});
  EXPECT_EQ(v.kind, ViolationKind::kNotFinite);
  EXPECT_EQ(v.joint, 1);
  EXPECT_EQ(s->describe(v), "joint 'roll' value is not a finite number");
  v = s->check_goal(std::vector<double>{10.0, 0.0, 0.0, 1.5});
  EXPECT_EQ(v.kind, ViolationKind::kAboveUpper);
  EXPECT_EQ(v.joint, 3);
  EXPECT_EQ(s->describe(v), "joint 'distal' position 1.5 mm is above the upper limit 1 mm");
  v = s->check_goal(std::vector<double>{-2.0, 0.0, 0.0, 0.0});
  EXPECT_EQ(v.kind, ViolationKind::kBelowLower);
  EXPECT_EQ(v.joint, 0);
  EXPECT_FALSE(s->check_goal(std::vector<double>{100.0, 3.0, -1.0, 1.0}));  // hard limits are inclusive
}

TEST(SafetySupervisor, VelocityChecksNameTheJoint) {
  auto s = make();
  EXPECT_FALSE(s->check_velocity(std::vector<double>{5.0, -1.5, 0.5, 0.0}));
  Violation v = s->check_velocity(std::vector<double>{0.0, -3.2, 0.0, 0.0});
  EXPECT_EQ(v.kind, ViolationKind::kAboveMaxVelocity);
  EXPECT_EQ(v.joint, 1);
  EXPECT_EQ(s->describe(v), "joint 'roll' velocity 3.2 rad/s exceeds the limit 1.5 rad/s");
  EXPECT_EQ(
      s->check_velocity(std::vector<double>{0.0, 0.0, std::numeric_limits<double>::infinity(), 0.0}).joint,
      2);
  EXPECT_EQ(s->check_velocity(std::vector<double>{}).kind, ViolationKind::kWrongSize);
}

TEST(SafetySupervisor, ClampKeepsSetpointsInsideSoftLimits) {
  auto s = make();
  std::vector<double> q{-5.0, 2.95, 0.5, 0.0}, qd{-1.0, 2.0, 0.7, kNaN};
  const ClampResult r = s->clamp_setpoint(q, qd);
  EXPECT_EQ(q[0], 1.0);   // lower + margin
  EXPECT_EQ(qd[0], 0.0);  // no velocity further out
  EXPECT_EQ(q[1], 2.9);   // upper − margin
  EXPECT_EQ(qd[1], 0.0);
  EXPECT_EQ(q[2], 0.5);   // position fine
  EXPECT_EQ(qd[2], 0.5);  // velocity limited
  EXPECT_EQ(qd[3], 0.0);  // NaN velocity stopped
  EXPECT_EQ(r.clamped_joints, 4);
  EXPECT_EQ(r.first_joint, 0);
  EXPECT_FALSE(r.non_finite);
  std::vector<double> fine_q = kHome, fine_qd{1.0, 0.0, 0.0, 0.0};
  EXPECT_EQ(s->clamp_setpoint(fine_q, fine_qd).clamped_joints, 0);
  std::vector<double> bad_q{kNaN, 0, 0, 0}, bad_qd{1, 0, 0, 0};
  EXPECT_TRUE(s->clamp_setpoint(bad_q, bad_qd).non_finite);
  EXPECT_EQ(bad_qd[0], 0.0);
}

TEST(SafetySupervisor, ServoTimeoutHoldsUntilRefreshed) {
  auto s = make({.command_timeout = 0.150});
  s->request(0.0, StateCommand::kEnable);
  drain(*s);
  EXPECT_FALSE(s->tick(0.001, kHome, kHome).servo_live);  // no stream yet
  s->servo_command_received(0.010);
  double t = 0.010;
  for (; t < 0.159; t += 0.001) ASSERT_TRUE(s->tick(t, kHome, kHome).servo_live) << t;
  EXPECT_TRUE(s->tick(0.160, kHome, kHome).servo_live);   // exactly at the timeout: still live
  const TickResult held = s->tick(0.1611, kHome, kHome);  // past it: hold
  EXPECT_FALSE(held.servo_live);
  EXPECT_EQ(held.state, OperatingState::kEnabled);  // a hold, not a fault
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, EventKind::kHold);
  EXPECT_EQ(events[0].code, FaultCode::kCommandTimeout);
  EXPECT_STREQ(events[0].text, "servo_jv not refreshed for 151 ms (timeout 150 ms); holding");
  s->servo_command_received(0.2);
  EXPECT_TRUE(s->tick(0.201, kHome, kHome).servo_live);
  // Pausing drops the stream; it must be refreshed after resuming.
  s->request(0.25, StateCommand::kPause);
  s->request(0.26, StateCommand::kResume);
  EXPECT_FALSE(s->tick(0.261, kHome, kHome).servo_live);
}

TEST(SafetySupervisor, TrackingErrorFaultsWhileEnabledOnly) {
  auto s = make();
  const std::vector<double> off{10.0, 0.0, 0.25, 0.0};  // proximal 0.25 mm away, limit 0.1 mm
  EXPECT_EQ(s->tick(0.0, off, kHome).state, OperatingState::kDisabled);  // not following: no check
  s->request(0.1, StateCommand::kEnable);
  const std::vector<double> small{10.3, 0.1, 0.05, -0.05};
  EXPECT_EQ(s->tick(0.2, small, kHome).state, OperatingState::kEnabled);
  const TickResult r = s->tick(0.3, off, kHome);
  EXPECT_EQ(r.state, OperatingState::kFault);
  EXPECT_FALSE(r.motion_allowed);
  EXPECT_EQ(s->fault_cause().code, FaultCode::kTrackingError);
  EXPECT_EQ(s->fault_cause().joint, 2);
  EXPECT_STREQ(s->fault_cause().text, "joint 'proximal' tracking error 0.25 mm exceeds the limit 0.1 mm");
}

TEST(SafetySupervisor, InvalidMeasurementOrSetpointFaults) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  s->tick(0.1, std::vector<double>{10.0, kNaN, 0.0, 0.0}, kHome);
  EXPECT_EQ(s->fault_cause().code, FaultCode::kInvalidMeasurement);
  EXPECT_EQ(s->fault_cause().joint, 1);
  s->request(0.2, StateCommand::kDisable);
  s->request(0.3, StateCommand::kEnable);
  s->tick(0.4, kHome, std::vector<double>{10.0, 0.0});
  EXPECT_EQ(s->fault_cause().code, FaultCode::kInvalidSetpoint);
}

TEST(SafetySupervisor, LostControlTimeFaultsOnlyAMovingRobot) {
  auto s = make({.max_lost_control_time = 0.075});
  double t = 0.0;
  // DISABLED: a stall of any length is counted, never faulted.
  EXPECT_FALSE(s->report_cycle(t += 1.0, 0.500, false));
  EXPECT_FALSE(s->report_cycle(t += 1.0, 0.500, true));
  EXPECT_EQ(s->state(), OperatingState::kDisabled);
  // ENABLED at rest: the drives hold by themselves; counted, not faulted, however long.
  s->request(t, StateCommand::kEnable);
  for (int i = 0; i < 1000; ++i) EXPECT_FALSE(s->report_cycle(t += 0.002, 0.001, false));
  EXPECT_FALSE(s->report_cycle(t += 0.2, 0.200, false));
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
  EXPECT_EQ(s->lost_control().stalls_over_bound_at_rest, 1u);
  // PAUSED at rest: the same.
  s->request(t, StateCommand::kPause);
  EXPECT_FALSE(s->report_cycle(t += 0.2, 0.200, false));
  s->request(t, StateCommand::kResume);
  // Moving: sustained lateness and a gap up to the bound are tolerated ...
  for (int i = 0; i < 1000; ++i) EXPECT_FALSE(s->report_cycle(t += 0.003, 0.002, true));
  EXPECT_FALSE(s->report_cycle(t += 0.075, 0.075, true));
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
  // ... a longer one faults with the lost time in the cause.
  EXPECT_TRUE(s->report_cycle(t += 0.090, 0.090, true));
  EXPECT_EQ(s->state(), OperatingState::kFault);
  EXPECT_EQ(s->fault_cause().code, FaultCode::kLostControlTime);
  EXPECT_STREQ(s->fault_cause().text,
               "the control loop ran 90 ms late while moving (bound 75 ms, measured by its own clock): the "
               "computer was too busy, not a device going silent; quick stop");
  EXPECT_DOUBLE_EQ(s->lost_control().max_lost, 0.500);
  EXPECT_DOUBLE_EQ(s->lost_control().max_lost_moving, 0.090);
  EXPECT_EQ(s->lost_control().stalls_over_bound, 5u);
  EXPECT_EQ(s->lost_control().stalls_over_bound_at_rest, 2u);
  const auto events = drain(*s);
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().kind, EventKind::kFault);
  EXPECT_EQ(events.back().code, FaultCode::kLostControlTime);
  // A non-finite report is not a stall.
  s->request(t, StateCommand::kDisable);
  s->request(t, StateCommand::kEnable);
  EXPECT_FALSE(s->report_cycle(t, kNaN, true));
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
}

TEST(SafetySupervisor, LostControlBoundIsHalfTheShorterWatchdog) {
  EXPECT_DOUBLE_EQ(lost_control_bound(0.150, 0.250), 0.075);  // the SRMC: command timeout decides
  EXPECT_DOUBLE_EQ(lost_control_bound(0.200, 0.100), 0.050);  // a drive consumer time of 100 ms
  EXPECT_EQ(lost_control_bound(0.0, 0.1), 0.0);
  EXPECT_EQ(lost_control_bound(0.1, kNaN), 0.0);
}

TEST(SafetySupervisor, EventLogWrapsWithoutLosingOrderOrAllocating) {
  auto s = make();
  // 3 events per cycle × 200 cycles = 600 events > capacity 256.
  for (int i = 0; i < 200; ++i) {
    const double t = i;
    s->request(t, StateCommand::kEnable);
    s->request(t, StateCommand::kResume);  // already ENABLED: not logged
    s->request(t, StateCommand::kPause);
    s->request(t, StateCommand::kDisable);
  }
  EXPECT_EQ(s->events().pushed(), 600u);
  std::vector<SafetyEvent> newest(4);
  ASSERT_EQ(s->events().copy_newest_first(newest), 4u);
  EXPECT_EQ(newest[0].sequence, 599u);
  EXPECT_EQ(newest[0].to, OperatingState::kDisabled);
  EXPECT_EQ(newest[1].to, OperatingState::kPaused);
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), SafetyEventLog::kCapacity);
  for (std::size_t i = 1; i < events.size(); ++i) EXPECT_EQ(events[i].sequence, events[i - 1].sequence + 1);
  EXPECT_EQ(s->events().lost(), 600u - SafetyEventLog::kCapacity);
}

TEST(SafetySupervisor, BadConfigurationIsRejectedWithAMessage) {
  try {
    LimitSet({{"roll", "rad", 1.0, -1.0, 0.0, 1.0, 1.0, 1.0}});
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("joint 0 ('roll')"), std::string::npos) << e.what();
  }
  EXPECT_THROW(LimitSet({}), std::invalid_argument);
  EXPECT_THROW(LimitSet({{"a", "mm", 0.0, 1.0, 0.6, 1.0, 1.0, 1.0}}), std::invalid_argument);
  EXPECT_THROW(LimitSet({{"a", "mm", 0.0, 1.0, 0.0, 0.0, 1.0, 1.0}}), std::invalid_argument);
  EXPECT_THROW(SafetySupervisor(srmc_limits(), {.command_timeout = 0.0}), std::invalid_argument);
  EXPECT_THROW(SafetySupervisor(srmc_limits(), {.max_lost_control_time = 0.0}), std::invalid_argument);
  EXPECT_THROW(SafetySupervisor(srmc_limits(), {.max_lost_control_time = kNaN}), std::invalid_argument);
}

TEST(SafetyTypes, EveryEnumHasAName) {
  EXPECT_STREQ(to_string(OperatingState::kPaused), "PAUSED");
  EXPECT_STREQ(to_string(StateCommand::kResume), "resume");
  EXPECT_STREQ(to_string(FaultCode::kDriveEmergency), "drive emergency (EMCY)");
  EXPECT_STREQ(to_string(EventKind::kEstopReset), "estop_reset");
  EXPECT_STREQ(to_string(ViolationKind::kAboveMaxVelocity), "above the velocity limit");
  EXPECT_STRNE(to_string(CommandResult::kRefusedInFault), "unknown");
}

}  // namespace
}  // namespace tendril::safety

namespace tendril::safety {
namespace {

TEST(SafetySupervisorHold, SpringDeflectionHoldsWithoutLosingPowerAndLogsTheCause) {
  auto s = make();
  EXPECT_FALSE(s->hold(0.0, FaultCode::kSpringDeflection, 0, "1.6 mm over 1.5 mm"));  // DISABLED: nothing
  ASSERT_EQ(s->request(0.1, StateCommand::kEnable), CommandResult::kAccepted);
  drain(*s);
  EXPECT_TRUE(s->hold(0.2, FaultCode::kSpringDeflection, 1, "1.6 mm over 1.5 mm"));
  EXPECT_EQ(s->state(), OperatingState::kPaused);
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, EventKind::kHold);
  EXPECT_EQ(events[0].code, FaultCode::kSpringDeflection);
  EXPECT_NE(std::string(events[0].text).find("spring deflection"), std::string::npos) << events[0].text;
  // Held, not faulted: resume brings it back.
  EXPECT_FALSE(s->hold(0.3, FaultCode::kSpringDeflection, 1, nullptr));
  EXPECT_EQ(s->request(0.4, StateCommand::kResume), CommandResult::kAccepted);
  EXPECT_EQ(s->state(), OperatingState::kEnabled);
}

}  // namespace
}  // namespace tendril::safety

namespace tendril::safety {
namespace {

// Issue 12: the event log must say who pressed the e-stop.
TEST(SafetySupervisorEstop, TheEventNamesWhoPressedIt) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  drain(*s);
  s->estop(0.1, "session:2 (operator)");
  EXPECT_EQ(s->state(), OperatingState::kFault);
  EXPECT_STREQ(s->fault_cause().text, "e-stop pressed by session:2 (operator)");
  auto events = drain(*s);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, EventKind::kEstop);
  EXPECT_STREQ(events[0].text, "e-stop latched by session:2 (operator); motion stopped");
  // A second press while latched is logged with its own actor; the latch and cause stay.
  s->estop(0.2, "bench-script (viewer)");
  events = drain(*s);
  ASSERT_EQ(events.size(), 1u);
  EXPECT_STREQ(events[0].text, "e-stop pressed again by bench-script (viewer) (already latched)");
  EXPECT_STREQ(s->fault_cause().text, "e-stop pressed by session:2 (operator)");
}

TEST(SafetySupervisorEstop, AnAnnouncedPressIsNamedWhenItsCommandArrives) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  drain(*s);
  // The network thread latches at once; the control thread ticks before the command with the name.
  s->request_estop();
  s->tick(0.1, kHome, kHome);
  s->estop(0.101, "session:7 (operator)");
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), 2u);
  EXPECT_STREQ(events[0].text, "e-stop latched; motion stopped");
  EXPECT_STREQ(events[1].text, "e-stop pressed by session:7 (operator)");
  EXPECT_STREQ(s->fault_cause().text, "e-stop pressed by session:7 (operator)");
  // Taken with its name before any tick: one event.
  ASSERT_EQ(s->reset_estop(1.0), CommandResult::kAccepted);
  s->request(1.1, StateCommand::kEnable);
  drain(*s);
  s->request_estop();
  s->estop(1.2, "session:8 (operator)");
  s->tick(1.3, kHome, kHome);
  const auto once = drain(*s);
  ASSERT_EQ(once.size(), 1u);
  EXPECT_STREQ(once[0].text, "e-stop latched by session:8 (operator); motion stopped");
}

TEST(SafetySupervisorRecord, LogsWithoutChangingTheState) {
  auto s = make();
  s->request(0.0, StateCommand::kEnable);
  s->hold(0.1, FaultCode::kSpringDeflection, 2, "1.6 mm");
  drain(*s);
  s->record(0.2, EventKind::kRefused, FaultCode::kSpringDeflection, 2, "resume refused: spring deflected");
  s->record(0.3, EventKind::kRecovery, FaultCode::kSpringDeflection, -1, "springs relaxed");
  EXPECT_EQ(s->state(), OperatingState::kPaused);
  const auto events = drain(*s);
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0].kind, EventKind::kRefused);
  EXPECT_EQ(events[0].from, OperatingState::kPaused);
  EXPECT_EQ(events[0].to, OperatingState::kPaused);
  EXPECT_EQ(events[1].kind, EventKind::kRecovery);
  EXPECT_STREQ(to_string(EventKind::kRecovery), "recovery");
}

}  // namespace
}  // namespace tendril::safety
