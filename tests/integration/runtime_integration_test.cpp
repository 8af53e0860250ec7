// End-to-end control over the virtual CAN bus in stepped simulated time: RobotRuntime (control
// loop, safety) -> CanopenMaster -> VirtualBus -> simulated CiA 402 drives and back.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "json_api.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";

class RuntimeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    auto config = load_robot_config(kSrmc);
    config.settings["catheter"]["simulation"].erase(
        "vessel");  // free space: these bends would touch the wall
    runtime = std::make_unique<RobotRuntime>(std::vector<RobotConfig>{config}, o, builtin_robot_types());
    api = json_api(*runtime);
    tap = runtime->tap_bus("can0");
    ASSERT_NE(tap, nullptr);
    runtime->start();
    steps(10);  // first SYNC cycles: feedback from every drive
    drain_tap();
  }
  void TearDown() override { runtime->stop(); }

  void steps(int n) {
    for (int i = 0; i < n; ++i) runtime->step();
  }
  // Steps until pred() holds; fails after max_steps simulated milliseconds.
  template <typename Pred>
  bool step_until(Pred pred, int max_steps) {
    for (int i = 0; i < max_steps; ++i) {
      if (pred()) return true;
      runtime->step();
    }
    return pred();
  }
  void drain_tap() {
    while (tap->receive(std::chrono::nanoseconds(0))) {
    }
  }
  std::string state() { return api->operating_state("srmc").body["state"].get<std::string>(); }
  std::vector<double> measured() {
    return api->measured_js("srmc").body["position"].get<std::vector<double>>();
  }
  void enable() {
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return api->operating_state("srmc").body["drives_ready"].get<bool>(); }, 2000))
        << api->operating_state("srmc").body.dump();
  }
  bool at(const std::vector<double>& goal, double tol) {
    auto q = measured();
    for (std::size_t i = 0; i < goal.size(); ++i)
      if (std::abs(q[i] - goal[i]) > tol) return false;
    return true;
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  std::unique_ptr<can::Bus> tap;
};

TEST_F(RuntimeTest, MovesToAGoalAndBackOverTheVirtualBus) {
  const auto start = measured();
  EXPECT_NEAR(start[0], 10.0, 1e-3);  // initial_position of insertion in srmc.json
  enable();
  EXPECT_EQ(state(), "ENABLED");
  const std::vector<double> goal{25.0, 0.6, 3.0, -2.0};
  auto r = api->move_jp("srmc", {{"goal", goal}});
  ASSERT_EQ(r.status, 202) << r.message;
  const double duration = r.body["duration_s"].get<double>();
  EXPECT_GT(duration, 0.5);  // 15 mm at 10 mm/s cannot be faster than 1.5 s
  EXPECT_TRUE(step_until([&] { return at(goal, 0.01); }, static_cast<int>(duration * 1000) + 1000))
      << api->measured_js("srmc").body.dump();
  // The simulated loads really moved (ground truth, not the master's view).
  EXPECT_NEAR(runtime->simulated_drive("srmc", "proximal_bend")->truth().position, 3.0, 0.01);
  ASSERT_EQ(api->move_jp("srmc", {{"goal", start}}).status, 202);
  EXPECT_TRUE(step_until([&] { return at(start, 0.01); }, 5000));
  EXPECT_EQ(state(), "ENABLED");
}

TEST_F(RuntimeTest, AGoalSentWhileTheDrivesAreEnablingStartsWhenTheyAre) {
  ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
  steps(1);
  ASSERT_FALSE(api->operating_state("srmc").body["drives_ready"].get<bool>());
  const std::vector<double> goal{15.0, 0.0, 1.0, 0.0};
  ASSERT_EQ(api->move_jp("srmc", {{"goal", goal}}).status, 202);
  EXPECT_TRUE(step_until([&] { return at(goal, 0.01); }, 5000)) << api->measured_js("srmc").body.dump();
  EXPECT_EQ(state(), "ENABLED");
}

TEST_F(RuntimeTest, SetpointNeverJumpsWhenANewGoalArrivesMidMotion) {
  enable();
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {30.0, 0.0, 0.0, 0.0}}}).status, 202);
  steps(400);
  double previous = api->setpoint_js("srmc").body["position"][0].get<double>();
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {12.0, 0.0, 0.0, 0.0}}}).status, 202);
  double max_step = 0;
  for (int i = 0; i < 3000; ++i) {
    runtime->step();
    const double now = api->setpoint_js("srmc").body["position"][0].get<double>();
    max_step = std::max(max_step, std::abs(now - previous));
    previous = now;
  }
  // 10 mm/s limit -> at most 0.01 mm per 1 ms tick (plus rounding).
  EXPECT_LE(max_step, 0.0101);
  EXPECT_NEAR(previous, 12.0, 1e-6);
}

TEST_F(RuntimeTest, EstopCommandsQuickStopOnEveryDriveWithinTwoTicks) {
  enable();
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {40.0, 1.0, 4.0, 2.0}}}).status, 202);
  steps(300);
  drain_tap();
  const auto tick_before = runtime->control_ticks();
  ASSERT_EQ(api->estop().status, 200);
  std::set<int> quick_stopped;
  std::uint64_t ticks_needed = 0;
  for (int i = 0; i < 2 && quick_stopped.size() < 4; ++i) {
    runtime->step();
    ticks_needed = runtime->control_ticks() - tick_before;
    while (auto f = tap->receive(std::chrono::nanoseconds(0))) {
      if (f->id > 0x200 && f->id <= 0x27F && f->len >= 2) {
        const auto cw = canopen::get_u16(f->data.data());
        // Quick stop: bit 2 cleared with bit 1 set (CiA 402 controlword 0bxxxx x01x).
        if ((cw & 0x0006) == 0x0002) quick_stopped.insert(static_cast<int>(f->id - 0x200));
      }
    }
  }
  EXPECT_EQ(quick_stopped.size(), 4u) << "quick stop reached only " << quick_stopped.size() << " drives";
  EXPECT_LE(ticks_needed, 2u);
  EXPECT_TRUE(step_until(
      [&] {
        return runtime->simulated_drive("srmc", "insertion")->state() ==
                   canopen::Cia402State::quick_stop_active ||
               runtime->simulated_drive("srmc", "insertion")->truth().velocity == 0.0;
      },
      500));
  steps(500);
  const auto frozen = measured();
  // Nothing moves until reset and enable.
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {20.0, 0.0, 0.0, 0.0}}}).status, 409);
  EXPECT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 409);
  steps(500);
  EXPECT_TRUE(at(frozen, 1e-3));
  EXPECT_EQ(api->operating_state("srmc").body["estop"], true);
  ASSERT_EQ(api->estop_reset().status, 200);
  steps(5);
  EXPECT_EQ(state(), "DISABLED");
  enable();
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {20.0, 0.0, 0.0, 0.0}}}).status, 202);
}

TEST_F(RuntimeTest, ServoVelocityStopsWhenNotRefreshedWithinTheCommandTimeout) {
  enable();
  const std::vector<double> v{2.0, 0.0, 0.0, 0.0};
  ASSERT_EQ(api->servo_jv("srmc", {{"velocity", v}}).status, 200);
  steps(100);
  const double moving = api->setpoint_js("srmc").body["position"][0].get<double>();
  EXPECT_GT(moving, 10.1);
  // No refresh: the stream times out at 150 ms and the setpoint holds.
  steps(200);
  const double held = api->setpoint_js("srmc").body["position"][0].get<double>();
  steps(500);
  EXPECT_DOUBLE_EQ(api->setpoint_js("srmc").body["position"][0].get<double>(), held);
  EXPECT_LT(held, 10.0 + 2.0 * 0.160);
  EXPECT_EQ(state(), "ENABLED");
}

TEST_F(RuntimeTest, OperatorLostStopsServoAtOnceAndDoesNotResume) {
  enable();
  ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {0.0, 0.0, 1.0, 0.0}}}).status, 200);
  steps(50);
  api->operator_lost("srmc");
  steps(2);
  const double held = api->setpoint_js("srmc").body["position"][2].get<double>();
  steps(1000);
  EXPECT_DOUBLE_EQ(api->setpoint_js("srmc").body["position"][2].get<double>(), held);
  EXPECT_LT(held, 1.0 * 0.060);
}

TEST_F(RuntimeTest, AWarningFromOutsideTheLoopIsLoggedWithoutAStateChange) {
  auto goal = measured();
  goal[2] += 1.0;
  enable();
  ASSERT_EQ(api->move_jp("srmc", {{"goal", goal}}).status, 202);
  steps(20);
  const std::string text(150, 'x');  // longer than an event holds: cut, not refused
  EXPECT_TRUE(
      runtime->report_warning("srmc", safety::FaultCode::kSensorStale, "imaging: no AP image for 1.2 s"));
  EXPECT_TRUE(runtime->report_warning("srmc", safety::FaultCode::kSensorStale, text));
  EXPECT_FALSE(runtime->report_warning("nobody", safety::FaultCode::kSensorStale, "lost"));
  steps(5);
  EXPECT_EQ(state(), "ENABLED") << "a warning changes no state";
  std::uint64_t total = 0;
  const auto events = runtime->events_since(0, total);
  int warnings = 0;
  for (const auto& e : events) {
    if (e.kind != "warning") continue;
    ++warnings;
    EXPECT_EQ(e.robot, "srmc");
    if (warnings == 1) EXPECT_EQ(e.message, "imaging: no AP image for 1.2 s");
    if (warnings == 2) EXPECT_EQ(e.message, std::string(95, 'x'));
  }
  EXPECT_EQ(warnings, 2);
  EXPECT_TRUE(step_until([&] { return at(goal, 0.01); }, 3000)) << "the move went on";
}

TEST_F(RuntimeTest, DriveHeartbeatLossFaultsTheRobotWithTheCause) {
  enable();
  runtime->simulated_drive("srmc", "roll")->set_silent(true);
  // Consumer time is 250 ms in srmc.json: the fault comes after it, not before.
  steps(200);
  EXPECT_EQ(state(), "ENABLED");
  EXPECT_TRUE(step_until([&] { return state() == "FAULT"; }, 200));
  const auto faults = api->faults();
  ASSERT_FALSE(faults.empty());
  EXPECT_EQ(faults[0]["code"], "drive heartbeat lost") << faults.dump();
  EXPECT_EQ(faults[0]["joint"], "roll");
  // The text says which device went silent, for how long, and that the loop kept time: a broken
  // device, not a busy computer.
  EXPECT_EQ(faults[0]["message"],
            "drive heartbeat lost on joint 'roll': drive 'roll' sent no heartbeat for over 250 ms (its bus's "
            "drive_heartbeat_timeout_ms): the device went silent; the control loop kept time (0 ms late this "
            "cycle)");
  // The other drives are quick-stopped: nothing is left moving.
  EXPECT_TRUE(step_until(
      [&] {
        return runtime->simulated_drive("srmc", "insertion")->state() ==
               canopen::Cia402State::quick_stop_active;
      },
      100));
}

TEST_F(RuntimeTest, DriveEmergencyFaultsTheRobot) {
  enable();
  runtime->simulated_drive("srmc", "distal_bend")->inject_fault(canopen::emcy_code::over_temperature);
  EXPECT_TRUE(step_until([&] { return state() == "FAULT"; }, 50));
  const auto faults = api->faults();
  ASSERT_FALSE(faults.empty());
  EXPECT_EQ(faults[0]["joint"], "distal_bend");
  EXPECT_NE(faults[0]["message"].get<std::string>().find("0x4210"), std::string::npos) << faults.dump();
  // Acknowledge with disable: the drive fault is reset, then the robot can be enabled again.
  ASSERT_EQ(api->state_command("srmc", {{"command", "disable"}}).status, 200);
  steps(50);
  EXPECT_EQ(state(), "DISABLED");
  enable();
  EXPECT_EQ(state(), "ENABLED");
}

TEST_F(RuntimeTest, ADriveThatResetsFaultsTheRobot) {
  enable();
  runtime->simulated_drive("srmc", "insertion")->power_cycle();
  EXPECT_TRUE(step_until([&] { return state() == "FAULT"; }, 50));
  const auto faults = api->faults();
  ASSERT_FALSE(faults.empty());
  EXPECT_EQ(faults[0]["joint"], "insertion") << faults.dump();
  EXPECT_NE(faults[0]["message"].get<std::string>().find("left NMT operational"), std::string::npos)
      << faults.dump();
}

TEST_F(RuntimeTest, BadRequestsChangeNothing) {
  enable();
  const auto before = api->setpoint_js("srmc").body["position"];
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {1.0, 2.0}}}).status, 422);
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {200.0, 0.0, 0.0, 0.0}}}).status, 422);
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {10.0, 0.0, -7.0, 0.0}}}).status, 422);  // q3 >= -6 mm
  EXPECT_EQ(api->move_jp("srmc", {{"goal", "x"}}).status, 400);
  EXPECT_EQ(api->move_jp("srmc", nlohmann::json::object()).status, 400);
  EXPECT_EQ(api->servo_jv("srmc", {{"velocity", {50.0, 0.0, 0.0, 0.0}}}).status, 422);
  EXPECT_EQ(api->move_jp("nope", {{"goal", {1.0}}}).status, 404);
  EXPECT_EQ(api->state_command("srmc", {{"command", "dance"}}).status, 400);
  EXPECT_EQ(api->mode("srmc", {{"mode", "warp"}}).status, 422);
  steps(100);
  EXPECT_EQ(api->setpoint_js("srmc").body["position"], before);
  EXPECT_EQ(state(), "ENABLED");
}

TEST_F(RuntimeTest, StopDisablesTheDrives) {
  enable();
  EXPECT_FALSE(runtime->drives_disabled());
  runtime->stop();
  std::vector<std::string> still_on;
  EXPECT_TRUE(runtime->drives_disabled(&still_on)) << still_on.size();
  for (const char* joint : {"insertion", "roll", "proximal_bend", "distal_bend"}) {
    const auto s = runtime->simulated_drive("srmc", joint)->state();
    EXPECT_TRUE(s == canopen::Cia402State::switch_on_disabled ||
                s == canopen::Cia402State::ready_to_switch_on)
        << joint << ": " << canopen::to_string(s);
  }
}

TEST_F(RuntimeTest, StreamsTopicsOnlyWhenTheyChange) {
  std::uint64_t version = 0;
  auto msg = api->topic_message("/srmc/operating_state", 0, version);
  ASSERT_TRUE(msg.has_value());
  std::uint64_t again = 0;
  EXPECT_FALSE(api->topic_message("/srmc/operating_state", version, again).has_value());
  auto scene = api->topic_message("/srmc/scene", 0, again);
  ASSERT_TRUE(scene.has_value());
  EXPECT_GE((*scene)["entities"][0]["lines"][0]["points"].size(), 10u);
  EXPECT_FALSE(api->topic_message("/nope/scene", 0, again).has_value());
}

// The WebSocket gives a slow reader only a topic's newest message: the events topic repeats the
// recent events so that a reader that missed a message still sees every event.
TEST_F(RuntimeTest, EventsTopicRepeatsRecentEventsForAReaderThatMissedAMessage) {
  std::uint64_t first = 0;
  const auto before = api->topic_message("/safety/events", 0, first);
  enable();  // DISABLED -> ENABLED: one transition event
  steps(10);
  std::uint64_t second = 0;
  const auto one = api->topic_message("/safety/events", first, second);
  ASSERT_TRUE(one.has_value());
  ASSERT_GT(second, first);
  EXPECT_EQ(api->state_command("srmc", {{"command", "pause"}}).status, 200);
  steps(10);
  // A reader that got `before` but never `one`: the newest message alone must hold both events.
  std::uint64_t third = 0;
  const auto two = api->topic_message("/safety/events", second, third);
  ASSERT_TRUE(two.has_value());
  EXPECT_GT(third, second);
  const auto& fresh = (*two)["events"];
  const auto& recent = (*two)["recent"];
  ASSERT_FALSE(fresh.empty());
  EXPECT_EQ(fresh.back()["to"], "PAUSED") << two->dump();
  ASSERT_GE(recent.size(), fresh.size() + (*one)["events"].size()) << two->dump();
  // Oldest first, ending with the same newest event as `events`.
  EXPECT_EQ(recent.back(), fresh.back());
  bool has_enable = false;
  for (const auto& e : recent) has_enable = has_enable || e["to"] == "ENABLED";
  EXPECT_TRUE(has_enable) << two->dump();
  for (std::size_t i = 1; i < recent.size(); ++i)
    EXPECT_LE(recent[i - 1]["time"].get<double>(), recent[i]["time"].get<double>());
}

}  // namespace
}  // namespace tendril::server
