// The control-loop timing policy end to end (safety::SupervisorOptions, README "Control-loop
// timing"), over the virtual bus in stepped time with the SIMULATED SRMC: stalls of the control
// thread and of the whole machine while DISABLED, while ENABLED at rest, and while moving, below and
// past the lost-control bound (75 ms for the SRMC: half its 150 ms command timeout).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <string>

#include "json_api.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

using namespace std::chrono_literals;
using Stall = RobotRuntime::Stall;

const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";

class LoopTimingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto config = load_robot_config(kSrmc);
    config.settings["catheter"]["simulation"].erase("vessel");  // free space: no wall contact in these moves
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    runtime =
        std::make_unique<RobotRuntime>(std::vector<RobotConfig>{std::move(config)}, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(50);
  }
  void TearDown() override { runtime->stop(); }

  void steps(int n) {
    for (int i = 0; i < n; ++i) runtime->step();
  }
  template <typename Pred>
  bool step_until(Pred pred, int max_steps) {
    for (int i = 0; i < max_steps; ++i) {
      if (pred()) return true;
      runtime->step();
    }
    return pred();
  }
  nlohmann::json op() { return api->operating_state("srmc").body; }
  double setpoint(std::size_t j) { return api->setpoint_js("srmc").body["position"][j].get<double>(); }
  void enable() {
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
  }
  // Faults and holds logged since start (the log is newest first).
  std::vector<std::string> faults_and_holds() {
    std::vector<std::string> out;
    for (const auto& e : api->faults())
      if (e["kind"] == "fault" || e["kind"] == "hold") out.push_back(e["message"].get<std::string>());
    return out;
  }
  // Starts a 10 -> 60 mm insertion (one quintic peaking at the 10 mm/s limit: 1.875 * 50 / 10 =
  // 9.4 s) and lets it run for 2 s.
  void start_moving() {
    ASSERT_EQ(api->move_jp("srmc", {{"goal", {60.0, 0.0, 0.0, 0.0}}}).status, 202);
    steps(2000);
    ASSERT_TRUE(op()["is_busy"].get<bool>());
    ASSERT_GT(setpoint(0), 12.0);
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(LoopTimingTest, TheBoundIsHalfTheCommandTimeout) {
  // srmc.json: command_timeout_ms 150, master_heartbeat_timeout_ms (the drives' consumer) 250.
  EXPECT_DOUBLE_EQ(op()["loop_timing"]["max_lost_control_ms"].get<double>(), 75.0);
}

TEST_F(LoopTimingTest, StallsWhileDisabledAreCountedOnly) {
  for (const auto what : {Stall::control_thread, Stall::whole_process}) {
    runtime->stall(25ms, what);
    steps(20);
  }
  runtime->stall(500ms, Stall::control_thread);
  steps(20);
  EXPECT_EQ(op()["state"], "DISABLED");
  EXPECT_TRUE(faults_and_holds().empty()) << faults_and_holds()[0];
  EXPECT_NEAR(op()["loop_timing"]["lost_max_ms"].get<double>(), 500.0, 1e-6);
  EXPECT_EQ(op()["loop_timing"]["stalls_over_bound_at_rest"], 0);  // DISABLED: nothing to protect
}

TEST_F(LoopTimingTest, StallsWhileEnabledAndHoldingNeitherFaultNorHold) {
  enable();
  steps(200);
  const double held = setpoint(0);
  // 25 ms of each kind; then longer than the bound (at rest nothing depends on the loop) and longer
  // than the spring sensors' 100 ms staleness bound, for the whole machine.
  for (const auto what : {Stall::control_thread, Stall::whole_process}) {
    runtime->stall(25ms, what);
    steps(50);
  }
  runtime->stall(200ms, Stall::control_thread);
  steps(50);
  runtime->stall(150ms, Stall::whole_process);
  steps(200);
  const auto s = op();
  EXPECT_EQ(s["state"], "ENABLED") << s.dump();
  EXPECT_TRUE(s["hold_reason"].is_null()) << s.dump();
  EXPECT_TRUE(s["spring_deflection_mm"].is_array()) << "the spring sensors stay fresh: " << s.dump();
  EXPECT_TRUE(faults_and_holds().empty()) << faults_and_holds()[0];
  EXPECT_EQ(s["loop_timing"]["stalls_over_bound_at_rest"], 2);
  EXPECT_DOUBLE_EQ(setpoint(0), held);
  // And it still moves when asked.
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {held + 1.0, 0.0, 0.0, 0.0}}}).status, 202);
  steps(1);  // the command reaches the control cycle; until then the robot is not busy yet
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 2000));
  EXPECT_NEAR(setpoint(0), held + 1.0, 1e-6);
}

TEST_F(LoopTimingTest, AStallBelowTheBoundWhileMovingResumesWithoutAJump) {
  enable();
  start_moving();
  for (const auto what : {Stall::control_thread, Stall::whole_process}) {
    const double before = setpoint(0);
    runtime->stall(25ms, what);
    runtime->step();
    // The trajectory waits for the lost 25 ms: one period's progress (10 mm/s: 0.01 mm), not 0.25 mm.
    EXPECT_LE(std::abs(setpoint(0) - before), 0.0101);
    EXPECT_EQ(op()["state"], "ENABLED");
    steps(100);
  }
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 12000));
  EXPECT_NEAR(setpoint(0), 60.0, 1e-6);
  EXPECT_TRUE(faults_and_holds().empty()) << faults_and_holds()[0];
  EXPECT_NEAR(op()["loop_timing"]["lost_max_moving_ms"].get<double>(), 25.0, 1e-6);
}

TEST_F(LoopTimingTest, AStallPastTheBoundWhileMovingStopsTheRobotWithItsCause) {
  for (const auto what : {Stall::control_thread, Stall::whole_process}) {
    SCOPED_TRACE(what == Stall::control_thread ? "control thread" : "whole process");
    enable();
    start_moving();
    const double before = setpoint(0);
    runtime->stall(100ms, what);
    runtime->step();
    auto s = op();
    ASSERT_EQ(s["state"], "FAULT") << s.dump();
    EXPECT_EQ(s["fault"]["code"], "control time lost while moving");
    const std::string expected =
        "the control loop ran 100 ms late while moving (bound 75 ms, measured by its own clock): the "
        "computer was too busy, not a device going silent; quick stop";
    EXPECT_EQ(s["fault"]["message"], expected);
    ASSERT_FALSE(faults_and_holds().empty());
    EXPECT_EQ(faults_and_holds()[0], expected);
    // No catch-up jump: the setpoint stays where the drive is.
    EXPECT_LE(setpoint(0), before + 0.0101);
    // The drives quick-stop and the insertion comes to rest.
    auto* insertion = runtime->simulated_drive("srmc", "insertion");
    ASSERT_TRUE(step_until(
        [&] {
          return insertion->state() == canopen::Cia402State::quick_stop_active ||
                 insertion->state() == canopen::Cia402State::switch_on_disabled;
        },
        20));
    steps(500);
    EXPECT_NEAR(insertion->truth().velocity, 0.0, 1e-3);
    // Acknowledge for the next round.
    ASSERT_EQ(api->state_command("srmc", {{"command", "disable"}}).status, 200);
    steps(200);
    ASSERT_EQ(op()["state"], "DISABLED");
  }
}

}  // namespace
}  // namespace tendril::server
