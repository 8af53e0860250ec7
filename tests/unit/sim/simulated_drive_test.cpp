// SimulatedCia402Drive driven with hand-built frames on a VirtualBus, in stepped time.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <set>

#include "drive_harness.hpp"

namespace tendril::sim::test {
namespace {

using co::Cia402State;
namespace abort_code = co::sdo_abort;

constexpr std::uint32_t kBootId = co::cob::heartbeat + DriveHarness::kNode;
constexpr std::uint32_t kTpdo1 = co::cob::tpdo1 + DriveHarness::kNode;
constexpr std::uint32_t kTpdo2 = co::cob::tpdo2 + DriveHarness::kNode;

std::uint16_t state_bits(std::uint16_t statusword) { return statusword & 0x6F; }

TEST(SimulatedDrive, SendsBootUpOnPowerOnThenIsPreOperational) {
  DriveHarness h;
  EXPECT_TRUE(h.received.empty());
  h.tick();
  auto boot = h.take_id(kBootId);
  ASSERT_EQ(boot.size(), 1u);
  EXPECT_EQ(boot[0].len, 1);
  EXPECT_EQ(boot[0].data[0], 0x00);
  EXPECT_EQ(h.drive.nmt_state(), co::NmtState::pre_operational);
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  h.run(0.5);
  EXPECT_TRUE(h.take_id(kBootId).empty()) << "heartbeat producer is off by default (0x1017 = 0)";
}

TEST(SimulatedDrive, HeartbeatProducerFollows0x1017) {
  DriveHarness h;
  h.tick();
  h.take();
  ASSERT_FALSE(h.write(co::od::producer_heartbeat_time, 0, 10, 2).aborted);
  h.run(0.1);
  auto beats = h.take_id(kBootId);
  EXPECT_GE(beats.size(), 9u);
  EXPECT_LE(beats.size(), 11u);
  for (const auto& b : beats) EXPECT_EQ(b.data[0], static_cast<std::uint8_t>(co::NmtState::pre_operational));
  h.nmt(co::NmtCommand::start);
  h.run(0.02);
  beats = h.take_id(kBootId);
  ASSERT_FALSE(beats.empty());
  EXPECT_EQ(beats.back().data[0], static_cast<std::uint8_t>(co::NmtState::operational));
}

TEST(SimulatedDrive, ResetNodeAndResetCommunicationBootAgainWithDefaults) {
  DriveHarness h;
  h.tick();
  ASSERT_FALSE(h.write(co::od::producer_heartbeat_time, 0, 50, 2).aborted);
  ASSERT_FALSE(h.write(co::od::following_error_window, 0, 1234, 4).aborted);
  h.take();
  h.nmt(co::NmtCommand::reset_communication);
  h.tick();
  ASSERT_EQ(h.take_id(kBootId).size(), 1u);
  EXPECT_EQ(h.read(co::od::producer_heartbeat_time, 0).value, 0) << "communication area back to default";
  EXPECT_EQ(h.read(co::od::following_error_window, 0).value, 1234) << "application area kept";
  h.nmt(co::NmtCommand::reset_node);
  h.tick();
  ASSERT_EQ(h.take_id(kBootId).size(), 1u);
  EXPECT_NE(h.read(co::od::following_error_window, 0).value, 1234) << "reset node restores everything";
  // Addressed to another node: ignored.
  h.nmt(co::NmtCommand::reset_node, 9);
  h.tick();
  EXPECT_TRUE(h.take_id(kBootId).empty());
}

TEST(SimulatedDrive, SdoExpeditedReadsAndWrites) {
  DriveHarness h;
  h.tick();
  EXPECT_EQ(h.read(co::od::device_type, 0).value, 0x00020192);
  EXPECT_EQ(h.read(co::od::identity, 0).value, 4);
  EXPECT_EQ(h.read(co::od::identity, 2).value, 0x54534431);
  EXPECT_EQ(h.read(co::od::modes_of_operation_display, 0).value, 8);
  EXPECT_EQ(h.read(co::od::abort_connection_option, 0).value, 3);
  auto wrote = h.write(co::od::consumer_heartbeat_time, 1, (0x7Fu << 16) | 100u, 4);
  EXPECT_FALSE(wrote.aborted);
  EXPECT_EQ(h.read(co::od::consumer_heartbeat_time, 1).value, (0x7F << 16) | 100);
  EXPECT_FALSE(h.write(co::od::interpolation_time_period, 1, 2, 1).aborted);
  EXPECT_EQ(h.read(co::od::interpolation_time_period, 1).value, 2);
  // Position actual is live: it tracks the simulated encoder.
  EXPECT_EQ(static_cast<std::int32_t>(h.read(co::od::position_actual_value, 0).value),
            h.drive.position_counts());
}

TEST(SimulatedDrive, SdoAbortsForEveryRefusal) {
  DriveHarness h;
  h.tick();
  EXPECT_EQ(h.read(0x2345, 0).abort_code, abort_code::no_object);
  EXPECT_EQ(h.read(co::od::identity, 9).abort_code, abort_code::no_subindex);
  EXPECT_EQ(h.write(co::od::statusword, 0, 0x1234, 2).abort_code, abort_code::read_only);
  EXPECT_EQ(h.write(co::od::device_type, 0, 1, 4).abort_code, abort_code::read_only);
  EXPECT_EQ(h.write(co::od::controlword, 0, 6, 4).abort_code, abort_code::length_mismatch);
  EXPECT_EQ(h.write(co::od::target_position, 0, 6, 2).abort_code, abort_code::length_mismatch);
  EXPECT_EQ(h.write(co::od::modes_of_operation, 0, 3, 1).abort_code, abort_code::value_range);
  EXPECT_EQ(h.write(co::od::abort_connection_option, 0, 7, 2).abort_code, abort_code::value_range);
  EXPECT_EQ(h.write(co::od::tpdo_mapping, 0, 9, 1).abort_code, abort_code::value_range);
  EXPECT_EQ(h.read(co::od::modes_of_operation, 0).value, 8) << "a refused write changes nothing";

  // Toggle bit error during a segmented upload.
  std::array<std::uint8_t, 8> init{0x40, 0x08, 0x10, 0x00};
  auto r = h.sdo_exchange(init);
  ASSERT_EQ(r.data[0], 0x41);
  std::array<std::uint8_t, 8> wrong_toggle{0x70};
  r = h.sdo_exchange(wrong_toggle);
  EXPECT_EQ(r.data[0], 0x80);
  EXPECT_EQ(co::get_u32(&r.data[4]), abort_code::toggle_bit);
  // A segment with no transfer in progress, and a block transfer, are invalid commands.
  r = h.sdo_exchange({0x60});
  EXPECT_EQ(co::get_u32(&r.data[4]), abort_code::invalid_command);
  r = h.sdo_exchange({0xA0, 0x00, 0x10, 0x00});
  EXPECT_EQ(co::get_u32(&r.data[4]), abort_code::invalid_command);
}

TEST(SimulatedDrive, SegmentedUploadAndDownload) {
  DriveHarness h;
  h.tick();
  auto name = h.read(0x1008, 0);
  ASSERT_FALSE(name.aborted);
  EXPECT_EQ(std::string(name.bytes.begin(), name.bytes.end()), "tendril SIMULATED CiA 402 drive");
  const std::string label = "proximal bend drive, carriage 2";
  ASSERT_FALSE(h.write_segmented(0x2000, 0, label).aborted);
  auto back = h.read(0x2000, 0);
  EXPECT_EQ(std::string(back.bytes.begin(), back.bytes.end()), label);
  // Segmented download of a number is fine when the length matches, refused when not.
  std::string four("\x10\x27\x00\x00", 4);
  ASSERT_FALSE(h.write_segmented(co::od::following_error_window, 0, four).aborted);
  EXPECT_EQ(h.read(co::od::following_error_window, 0).value, 10000);
  EXPECT_EQ(h.write_segmented(co::od::following_error_window, 0, "12345").abort_code,
            abort_code::length_mismatch);
  EXPECT_EQ(h.write_segmented(0x2000, 0, std::string(65, 'x')).abort_code, abort_code::length_too_high);
}

TEST(SimulatedDrive, PdosOnlyInOperational) {
  DriveHarness h;
  h.tick();
  h.sync();
  h.run(0.01);
  EXPECT_TRUE(h.take_id(kTpdo1).empty());
  h.nmt(co::NmtCommand::start);
  h.sync();
  auto t1 = h.take_id(kTpdo1);
  auto t2 = h.take_id(kTpdo2);
  ASSERT_EQ(t1.size(), 1u);
  ASSERT_EQ(t2.size(), 1u);
  EXPECT_EQ(t1[0].len, 6);
  EXPECT_EQ(state_bits(co::get_u16(&t1[0].data[0])), 0x40) << "switch on disabled";
  EXPECT_EQ(static_cast<std::int32_t>(co::get_u32(&t1[0].data[2])), h.drive.position_counts());
  EXPECT_EQ(t2[0].len, 6);
  h.nmt(co::NmtCommand::stop);
  h.sync();
  EXPECT_TRUE(h.take_id(kTpdo1).empty());
  // NMT stopped: no SDO service either.
  h.deliver(can::Frame::make(co::cob::sdo_rx + DriveHarness::kNode, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0}));
  EXPECT_TRUE(h.take_id(co::cob::sdo_tx + DriveHarness::kNode).empty());
}

TEST(SimulatedDrive, SdoRemappedTpdoChangesTheWireLayout) {
  DriveHarness h;
  h.tick();
  // Mapping entries are locked while sub0 != 0.
  EXPECT_EQ(h.write(co::od::tpdo_mapping, 1, 0x60640020, 4).abort_code, abort_code::unsupported_access);
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 0, 0, 1).aborted);
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 1, 0x60640020, 4).aborted);  // position first
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 2, 0x60610008, 4).aborted);  // then mode display
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 3, 0x10170010, 4).aborted);
  EXPECT_EQ(h.write(co::od::tpdo_mapping, 0, 3, 1).abort_code, abort_code::cannot_map)
      << "0x1017 is not mappable";
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 3, 0x60640020, 4).aborted);
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 4, 0x60640020, 4).aborted);
  EXPECT_EQ(h.write(co::od::tpdo_mapping, 0, 4, 1).abort_code, abort_code::map_too_long);
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 3, 0x60400010, 4).aborted);
  ASSERT_FALSE(h.write(co::od::tpdo_mapping, 0, 3, 1).aborted);
  // Move the COB-ID: only through "invalid".
  EXPECT_EQ(h.write(co::od::tpdo_communication, 1, 0x1E5, 4).abort_code, abort_code::value_range);
  ASSERT_FALSE(h.write(co::od::tpdo_communication, 1, 0x800001E5u, 4).aborted);
  ASSERT_FALSE(h.write(co::od::tpdo_communication, 1, 0x1E5, 4).aborted);
  h.nmt(co::NmtCommand::start);
  h.sync();
  EXPECT_TRUE(h.take_id(kTpdo1).empty());
  auto t = h.take_id(0x1E5);
  ASSERT_EQ(t.size(), 1u);
  ASSERT_EQ(t[0].len, 7);
  EXPECT_EQ(static_cast<std::int32_t>(co::get_u32(&t[0].data[0])), h.drive.position_counts());
  EXPECT_EQ(t[0].data[4], 8);
  EXPECT_EQ(co::get_u16(&t[0].data[5]), 0) << "controlword mirrored";
  // Transmission type 2: every second SYNC.
  ASSERT_FALSE(h.write(co::od::tpdo_communication, 2, 2, 1).aborted);
  for (int i = 0; i < 6; ++i) h.sync();
  EXPECT_EQ(h.take_id(0x1E5).size(), 3u);
}

TEST(SimulatedDrive, SdoRemappedRpdoChangesWhatTheDriveParses) {
  DriveHarness h;
  h.enable();
  // RPDO1 becomes: target position first, then controlword.
  ASSERT_FALSE(h.write(co::od::rpdo_mapping, 0, 0, 1).aborted);
  ASSERT_FALSE(h.write(co::od::rpdo_mapping, 1, 0x607A0020, 4).aborted);
  ASSERT_FALSE(h.write(co::od::rpdo_mapping, 2, 0x60400010, 4).aborted);
  EXPECT_EQ(h.write(co::od::rpdo_mapping, 3, 0x60410010, 4).aborted, false);
  EXPECT_EQ(h.write(co::od::rpdo_mapping, 0, 3, 1).abort_code, abort_code::cannot_map)
      << "statusword is read-only";
  ASSERT_FALSE(h.write(co::od::rpdo_mapping, 0, 2, 1).aborted);
  can::Frame f;
  f.id = co::cob::rpdo1 + DriveHarness::kNode;
  f.len = 6;
  co::put_u32(&f.data[0], static_cast<std::uint32_t>(h.drive.position_counts()));
  co::put_u16(&f.data[4], 0x0002);  // quick stop
  h.send(f);
  h.sync();
  EXPECT_EQ(h.drive.state(), Cia402State::quick_stop_active);
}

TEST(SimulatedDrive, Cia402EnableSequenceAndStateMachine) {
  DriveHarness h;
  h.run(0.01);
  h.nmt(co::NmtCommand::start);
  const auto hold = h.drive.position_counts();
  h.cycle(0x0007, hold);  // switch on from SWITCH ON DISABLED: not allowed
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  h.cycle(0x0006, hold);
  EXPECT_EQ(h.drive.state(), Cia402State::ready_to_switch_on);
  ASSERT_TRUE(h.last_tpdo1());
  EXPECT_EQ(state_bits(h.last_tpdo1()->first), 0x21);
  h.cycle(0x0007, hold);
  EXPECT_EQ(h.drive.state(), Cia402State::switched_on);
  EXPECT_EQ(state_bits(h.last_tpdo1()->first), 0x23);
  h.cycle(0x000F, hold);
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  EXPECT_EQ(state_bits(h.last_tpdo1()->first), 0x27);
  EXPECT_TRUE(h.last_tpdo1()->first & co::statusword_bit::remote);
  h.cycle(0x0007, hold);  // disable operation
  EXPECT_EQ(h.drive.state(), Cia402State::switched_on);
  h.cycle(0x000F, hold);
  h.cycle(0x0006, hold);  // shutdown from OPERATION ENABLED
  EXPECT_EQ(h.drive.state(), Cia402State::ready_to_switch_on);
  h.cycle(0x000F, hold);  // ready -> enable: transitions 3 + 4
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  h.cycle(0x0000, hold);  // disable voltage
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  EXPECT_EQ(state_bits(h.last_tpdo1()->first), 0x40);
}

TEST(SimulatedDrive, CspMoveReachesTargetWithBoundedFollowingError) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  const double start = h.drive.position_counts();
  const double goal = start + 10.0 * cpu;  // 10 mm in 1 s, smooth (cosine) profile, 1 kHz cycle
  double max_error = 0;
  for (int i = 0; i <= 1000; ++i) {
    const double s = 0.5 - 0.5 * std::cos(std::numbers::pi * i / 1000.0);
    const auto target = static_cast<std::int32_t>(std::lround(start + s * (goal - start)));
    h.cycle(0x000F, target);
    max_error = std::max(max_error, std::abs(h.drive.demand_position_counts() - h.drive.position_counts()));
  }
  for (int i = 0; i < 300; ++i) h.cycle(0x000F, static_cast<std::int32_t>(std::lround(goal)));
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  EXPECT_LT(max_error / cpu, 0.05) << "following error (mm) during the move";
  auto tp = h.last_tpdo1();
  ASSERT_TRUE(tp);
  EXPECT_NEAR(tp->second, goal, 0.005 * cpu) << "settles within 5 um";
  EXPECT_TRUE(tp->first & co::statusword_bit::target_reached);
  EXPECT_NEAR(h.drive.truth().position, goal / cpu, 0.005);
  EXPECT_FALSE(tp->first & co::statusword_bit::following_error);
  // TPDO2 carries velocity (counts/s) and torque (per mille): at rest both near zero.
  auto t2 = h.take_id(kTpdo2);
  ASSERT_FALSE(t2.empty());
  EXPECT_LT(std::abs(static_cast<std::int32_t>(co::get_u32(&t2.back().data[0]))), 0.5 * cpu);
}

TEST(SimulatedDrive, CspInterpolatesBetweenSyncs) {
  DriveHarness h;
  h.enable();
  ASSERT_FALSE(h.write(co::od::interpolation_time_period, 1, 10, 1).aborted);  // 10 ms
  const auto start = h.drive.position_counts();
  h.rpdo1(0x000F, start + 1000);
  h.sync();
  h.tick(0.005);
  EXPECT_NEAR(h.drive.demand_position_counts(), start + 500, 1.0) << "halfway through the period";
  h.tick(0.005);
  EXPECT_NEAR(h.drive.demand_position_counts(), start + 1000, 1.0);
  h.tick(0.005);
  EXPECT_NEAR(h.drive.demand_position_counts(), start + 1000, 1.0) << "holds the target after the period";
}

TEST(SimulatedDrive, TargetBeyondLimitIsClampedWithWarningAndOneEmcy) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  ASSERT_FALSE(
      h.write(co::od::software_position_limit, 2, static_cast<std::uint32_t>(std::lround(0.1 * cpu)), 4)
          .aborted);
  h.take();
  for (int i = 0; i < 500; ++i)
    h.cycle(0x000F, static_cast<std::int32_t>(std::lround(0.2 * cpu * i / 499.0)));
  auto frames = h.take();
  auto codes = emcy_codes(frames);
  ASSERT_EQ(std::count(codes.begin(), codes.end(), co::emcy_code::position_limit), 1);
  std::uint16_t sw = 0;
  for (const auto& f : frames)
    if (f.id == kTpdo1) sw = co::get_u16(&f.data[0]);
  EXPECT_TRUE(sw & co::statusword_bit::warning);
  EXPECT_TRUE(sw & co::statusword_bit::internal_limit);
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  EXPECT_NEAR(h.drive.truth().position, 0.1, 0.01) << "held at the limit";
}

TEST(SimulatedDrive, QuickStopDeceleratesAndHolds) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  double target = h.drive.position_counts();
  const double v = 10.0 * cpu;  // 10 mm/s, after a ramp up
  for (int i = 0; i < 500; ++i) {
    target += v * 0.001 * std::min(1.0, i / 100.0);
    h.cycle(0x000F, static_cast<std::int32_t>(std::lround(target)));
  }
  EXPECT_NEAR(h.drive.truth().velocity, 10.0, 0.5);
  const double at_stop_command = h.drive.truth().position;
  h.cycle(0x0002, static_cast<std::int32_t>(std::lround(target)));
  EXPECT_EQ(h.drive.state(), Cia402State::quick_stop_active);
  double previous_speed = h.drive.truth().velocity;
  for (int i = 0; i < 40; ++i) {
    h.tick();
    EXPECT_LE(h.drive.truth().velocity, previous_speed + 0.2) << "decelerating";
    previous_speed = h.drive.truth().velocity;
  }
  h.run(0.5);
  EXPECT_EQ(h.drive.state(), Cia402State::quick_stop_active) << "0x605A = 6: stay in QUICK STOP ACTIVE";
  EXPECT_NEAR(h.drive.truth().velocity, 0.0, 0.05);
  // Stopping distance v^2 / 2a at the quick-stop deceleration (200 mm/s^2): 0.25 mm.
  const double travelled = h.drive.truth().position - at_stop_command;
  EXPECT_NEAR(travelled, 0.25, 0.1);
  const double held = h.drive.truth().position;
  h.run(0.5);
  EXPECT_NEAR(h.drive.truth().position, held, 0.001) << "holds position";
  h.sync();
  EXPECT_TRUE(h.last_tpdo1()->first & co::statusword_bit::target_reached);
  EXPECT_EQ(state_bits(h.last_tpdo1()->first), 0x07);
}

TEST(SimulatedDrive, QuickStopOption2DisablesAfterStopping) {
  DriveHarness h;
  h.enable();
  ASSERT_FALSE(h.write(co::od::quick_stop_option_code, 0, 2, 2).aborted);
  EXPECT_EQ(h.write(co::od::quick_stop_option_code, 0, 4, 2).abort_code, abort_code::value_range);
  h.cycle(0x0002, h.drive.position_counts());
  h.run(0.1);
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
}

TEST(SimulatedDrive, MasterHeartbeatLossQuickStopsThenFaultsWithEmcy8130) {
  DriveHarness h;
  h.tick();
  ASSERT_FALSE(h.write(co::od::consumer_heartbeat_time, 1, (0x7Fu << 16) | 100u, 4).aborted);
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  double target = h.drive.position_counts();
  const auto master_heartbeat = can::Frame::make(co::cob::heartbeat + 0x7F, {0x05});
  for (int i = 0; i < 400; ++i) {
    if (i % 20 == 0) h.send(master_heartbeat);
    target += 10.0 * cpu * 0.001 * std::min(1.0, i / 100.0);
    h.cycle(0x000F, static_cast<std::int32_t>(std::lround(target)));
  }
  ASSERT_EQ(h.drive.state(), Cia402State::operation_enabled);
  EXPECT_TRUE(emcy_codes(h.take()).empty());
  // The master dies: no heartbeat, no SYNC, no RPDO.
  bool saw_reaction = false;
  for (int i = 0; i < 150; ++i) {
    h.tick();
    if (h.drive.state() == Cia402State::fault_reaction_active) saw_reaction = true;
  }
  EXPECT_TRUE(saw_reaction) << "quick-stop ramp (fault reaction) before FAULT";
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
  auto codes = emcy_codes(h.take());
  ASSERT_EQ(codes.size(), 1u);
  EXPECT_EQ(codes[0], co::emcy_code::heartbeat_lost);
  EXPECT_EQ(h.read(co::od::error_code, 0).value, co::emcy_code::heartbeat_lost);
  EXPECT_TRUE(h.read(co::od::error_register, 0).value & 0x10) << "communication error bit";
  h.run(0.2);
  EXPECT_NEAR(h.drive.truth().velocity, 0.0, 0.01) << "motor stopped";
}

TEST(SimulatedDrive, HeartbeatConsumerWaitsForTheFirstHeartbeat) {
  DriveHarness h;
  h.tick();
  ASSERT_FALSE(h.write(co::od::consumer_heartbeat_time, 1, (0x7Fu << 16) | 50u, 4).aborted);
  h.enable();
  h.run(0.5);
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled) << "monitoring starts at the first heartbeat";
  // Another node's heartbeat does not feed the consumer.
  h.send(can::Frame::make(co::cob::heartbeat + 0x7F, {0x05}));
  for (int i = 0; i < 100; ++i) {
    if (i % 10 == 0) h.send(can::Frame::make(co::cob::heartbeat + 0x10, {0x05}));
    h.tick();
  }
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
}

TEST(SimulatedDrive, FaultResetActsOnlyOnRisingEdge) {
  DriveHarness h;
  h.enable();
  const auto hold = h.drive.position_counts();
  h.cycle(0x008F, hold);  // bit 7 already high before the fault: no transition outside FAULT
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  h.drive.inject_fault(co::emcy_code::over_temperature);
  h.run(0.1);
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
  auto codes = emcy_codes(h.take());
  ASSERT_FALSE(codes.empty());
  EXPECT_EQ(codes[0], co::emcy_code::over_temperature);
  for (int i = 0; i < 5; ++i) h.cycle(0x0080, hold);  // level, no edge
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
  h.cycle(0x0000, hold);
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
  h.cycle(0x0080, hold);  // rising edge
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  codes = emcy_codes(h.take());
  ASSERT_FALSE(codes.empty());
  EXPECT_EQ(codes.back(), 0x0000) << "error reset EMCY";
  EXPECT_EQ(h.read(co::od::error_code, 0).value, 0);
  EXPECT_EQ(h.read(co::od::error_register, 0).value, 0);
}

TEST(SimulatedDrive, FollowingErrorFaultsWithEmcy8611) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  // A 5 mm step in one 1 ms interpolation period: the servo cannot follow.
  h.cycle(0x000F, static_cast<std::int32_t>(h.drive.position_counts() + std::lround(5.0 * cpu)));
  h.run(0.02);
  EXPECT_EQ(h.drive.state(), Cia402State::fault_reaction_active)
      << "ramping down at the quick-stop deceleration";
  h.run(1.0);
  EXPECT_EQ(h.drive.state(), Cia402State::fault);
  auto codes = emcy_codes(h.take());
  ASSERT_FALSE(codes.empty());
  EXPECT_EQ(codes[0], co::emcy_code::following_error);
}

TEST(SimulatedDrive, SilentDriveSendsNothing) {
  DriveHarness h;
  h.tick();
  ASSERT_FALSE(h.write(co::od::producer_heartbeat_time, 0, 10, 2).aborted);
  h.nmt(co::NmtCommand::start);
  h.take();
  h.drive.set_silent(true);
  for (int i = 0; i < 200; ++i) {
    h.sync();
    h.tick();
  }
  h.deliver(can::Frame::make(co::cob::sdo_rx + DriveHarness::kNode, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0}));
  h.drive.inject_fault(co::emcy_code::generic);
  h.tick();
  EXPECT_TRUE(h.take().empty());
  EXPECT_GT(h.drive.counters().frames_suppressed, 400u);
  h.drive.set_silent(false);
  h.run(0.02);
  EXPECT_FALSE(h.take_id(kBootId).empty()) << "answers again once no longer silent";
}

TEST(SimulatedDrive, PowerCycleRebootsWithDefaultsAndKeepsTheLoadWhereItIs) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  double target = h.drive.position_counts();
  for (int i = 0; i < 300; ++i) {
    target += 2.0 * cpu * 0.001;
    h.cycle(0x000F, static_cast<std::int32_t>(std::lround(target)));
  }
  ASSERT_FALSE(h.write(co::od::producer_heartbeat_time, 0, 10, 2).aborted);
  h.run(0.2);
  const double where = h.drive.truth().position;
  h.take();
  h.drive.power_cycle();
  h.tick();
  auto boot = h.take_id(kBootId);
  ASSERT_EQ(boot.size(), 1u);
  EXPECT_EQ(boot[0].data[0], 0);
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  EXPECT_EQ(h.read(co::od::producer_heartbeat_time, 0).value, 0);
  EXPECT_NEAR(h.drive.truth().position, where, 0.01);
  EXPECT_NEAR(h.drive.position_counts() / cpu, where, 0.01) << "absolute encoder";
}

TEST(SimulatedDrive, PowerOffCoastsSilentlyAndPowerOnBoots) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  double target = h.drive.position_counts();
  for (int i = 0; i < 300; ++i) {
    target += 10.0 * cpu * 0.001 * std::min(1.0, i / 100.0);
    h.cycle(0x000F, static_cast<std::int32_t>(std::lround(target)));
  }
  ASSERT_GT(h.drive.truth().velocity, 5.0);
  h.take();
  h.drive.set_powered(false);
  const double at_power_loss = h.drive.truth().position;
  for (int i = 0; i < 500; ++i) h.cycle(0x000F, static_cast<std::int32_t>(std::lround(target)));
  EXPECT_TRUE(h.take().empty()) << "an unpowered node sends nothing";
  EXPECT_EQ(h.drive.truth().velocity, 0.0) << "coasted to rest on friction";
  EXPECT_GT(h.drive.truth().position, at_power_loss) << "but not instantly";
  h.drive.set_powered(true);
  h.tick();
  ASSERT_EQ(h.take_id(kBootId).size(), 1u);
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
}

TEST(SimulatedDrive, CyclicSynchronousVelocity) {
  DriveHarness h;
  h.enable();
  const double cpu = h.drive.parameters().counts_per_unit();
  ASSERT_FALSE(h.write(co::od::modes_of_operation, 0, 9, 1).aborted);
  EXPECT_EQ(h.read(co::od::modes_of_operation_display, 0).value, 9);
  ASSERT_FALSE(
      h.write(co::od::target_velocity, 0, static_cast<std::uint32_t>(std::lround(4.0 * cpu)), 4).aborted);
  for (int i = 0; i < 300; ++i) h.cycle(0x000F, 0);  // 0x607A is ignored in CSV
  EXPECT_NEAR(h.drive.truth().velocity, 4.0, 0.1);
  // 0x607F caps the commanded velocity (20 mm/s for a bend drive).
  ASSERT_FALSE(
      h.write(co::od::target_velocity, 0, static_cast<std::uint32_t>(std::lround(100.0 * cpu)), 4).aborted);
  for (int i = 0; i < 300; ++i) h.cycle(0x000F, 0);
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  EXPECT_NEAR(h.drive.truth().velocity, 20.0, 0.5);
}

TEST(SimulatedDrive, HeartbeatLossWithOption2DisablesVoltage) {
  DriveHarness h;
  h.tick();
  ASSERT_FALSE(h.write(co::od::consumer_heartbeat_time, 1, (0x7Fu << 16) | 50u, 4).aborted);
  ASSERT_FALSE(h.write(co::od::abort_connection_option, 0, 2, 2).aborted);
  h.enable();
  h.send(can::Frame::make(co::cob::heartbeat + 0x7F, {0x05}));
  h.take();
  h.run(0.1);
  EXPECT_EQ(h.drive.state(), Cia402State::switch_on_disabled);
  auto codes = emcy_codes(h.take());
  ASSERT_EQ(codes.size(), 1u);
  EXPECT_EQ(codes[0], co::emcy_code::heartbeat_lost);
  // A heartbeat re-arms the consumer; another loss reports again.
  h.send(can::Frame::make(co::cob::heartbeat + 0x7F, {0x05}));
  h.run(0.1);
  EXPECT_EQ(emcy_codes(h.take()).size(), 1u);
}

TEST(SimulatedDrive, ShortRpdoIsRejectedWithEmcy) {
  DriveHarness h;
  h.enable();
  h.take();
  h.deliver(can::Frame::make(co::cob::rpdo1 + DriveHarness::kNode, {0x02, 0x00}));
  h.sync();
  EXPECT_EQ(h.drive.state(), Cia402State::operation_enabled);
  auto codes = emcy_codes(h.take());
  ASSERT_EQ(codes.size(), 1u);
  EXPECT_EQ(codes[0], 0x8210);
}

TEST(SimulatedDrive, RejectsImpossibleParameters) {
  can::VirtualBus bus("b");
  auto ep = bus.attach("n");
  auto p = DriveParameters::srmc_bend("bad");
  p.gear_ratio = 0;
  EXPECT_THROW(SimulatedCia402Drive(3, *ep, p), SimulationSetupError);
  EXPECT_THROW(SimulatedCia402Drive(0, *ep, DriveParameters::srmc_bend("x")), SimulationSetupError);
  p = DriveParameters::srmc_bend("bad");
  p.coulomb_friction = p.max_torque;
  EXPECT_THROW(SimulatedCia402Drive(3, *ep, p), SimulationSetupError);
}

TEST(SimulatedDrive, EncoderNoiseIsSeededAndReproducible) {
  auto params = DriveParameters::srmc_bend("noisy");
  params.encoder_noise_counts = 3.0;
  DriveHarness a(params), b(params);
  std::vector<std::int32_t> pa, pb;
  for (int i = 0; i < 50; ++i) {
    a.tick();
    b.tick();
    pa.push_back(a.drive.position_counts());
    pb.push_back(b.drive.position_counts());
  }
  EXPECT_EQ(pa, pb);
  EXPECT_GT(std::set<std::int32_t>(pa.begin(), pa.end()).size(), 2u) << "noise visible at rest";
}

}  // namespace
}  // namespace tendril::sim::test
