// The sdu_continuum robot type (server/src/robots/sdu_continuum) end to end through the runtime and the
// JSON API with config/robots/sdu_continuum.json, in stepped simulated time at 1 kHz: the SIMULATED
// drives and disk nodes on the virtual CAN bus, the disks' frames reassembled on the bus side, the
// safety path (proximity speed law with the dissertation's 50 / 0.25 mm/s, stop on contact in the cycle that
// sees it), each sensor fault's defined state, and the ToF map.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "allocation_counter.hpp"
#include "json_api.hpp"
#include "sdu_continuum/sdu_robot.hpp"
#include "tendril/safety/safety_supervisor.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;
namespace cont = tendril::continuum;

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";

// The dissertation's (3.4) with its numbers and tendril's d_max of 130 mm.
double law(double d_e) { return d_e < 130.0 ? d_e / 130.0 * (50.0 - 0.25) + 0.25 : 50.0; }

class SduContinuumTest : public ::testing::Test {
 protected:
  void start(RobotConfig rc) {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    std::vector<RobotConfig> robots;
    robots.push_back(std::move(rc));
    runtime = std::make_unique<RobotRuntime>(std::move(robots), o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
  }
  static RobotConfig config() { return load_robot_config(kConfig / "sdu_continuum.json"); }
  void TearDown() override {
    if (runtime) runtime->stop();
  }
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
  json op() { return api->operating_state("sdu").body; }
  SduContinuum& sdu() { return dynamic_cast<SduContinuum&>(*runtime->plugin("sdu")); }
  SduSimulation& sim() { return *sdu().simulation(); }
  // Waits for the Hall baseline (the robot holds until it is taken), then enables.
  void unbias_and_enable() {
    ASSERT_TRUE(step_until([&] { return sdu().snapshot().state == cont::SduSafetyState::kClear; }, 3000))
        << op()["continuum"]["supervisor"].dump();
    ASSERT_EQ(api->state_command("sdu", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
    ASSERT_EQ(op()["state"], "ENABLED");
  }
  std::vector<double> measured() {
    return api->measured_js("sdu").body["position"].get<std::vector<double>>();
  }
  std::vector<double> setpoint() {
    return api->setpoint_js("sdu").body["position"].get<std::vector<double>>();
  }
  bool logged(const std::string& needle) {
    for (const auto& e : api->faults())
      if (e.value("message", std::string()).find(needle) != std::string::npos) return true;
    return false;
  }
  // The fastest sensor window's travel between two joint vectors (mm).
  double window_travel(const std::vector<double>& a, const std::vector<double>& b) {
    const auto& m = sdu().settings().model;
    const auto pa = cont::disk_poses(m, segment_configuration(a));
    const auto pb = cont::disk_poses(m, segment_configuration(b));
    double d = 0.0;
    for (std::size_t i = 0; i < kSdus; ++i)
      for (std::size_t j = 0; j < cont::kTofPerSdu; ++j) {
        const Eigen::Vector3d w = cont::tof_sensor_in_disk(m, j).translation();
        d = std::max(d, (pb[i] * w - pa[i] * w).norm());
      }
    return d;
  }
  // Maps with the stage rolled from `from` to `to` (move_jp), the mapper polled every 10 ms.
  void roll_and_map(double from, double to) {
    for (double goal : {from, to}) {
      auto q = setpoint();
      q[kStageRoll] = goal;
      ASSERT_EQ(api->move_jp("sdu", {{"goal", q}}).status, 202);
      steps(2);
      for (int k = 0; k < 600 && op()["is_busy"].get<bool>(); ++k) {
        steps(10);
        sdu().mapper().poll(runtime->time());
      }
    }
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(SduContinuumTest, DescribesTheSegmentItsDisksAndTopics) {
  start(config());
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 1u);
  const auto& r = robots[0];
  EXPECT_EQ(r["kind"], "sdu_continuum");
  EXPECT_EQ(r["modes"], json({"joint", "guidance", "tip"}));
  const auto& c = r["continuum"];
  ASSERT_EQ(c["disks"].size(), 5u);
  EXPECT_EQ(c["disks"][4]["arc_mm"], 370.0);
  EXPECT_EQ(c["disks"][0]["slots"], 8);
  EXPECT_EQ(c["hri_modes"], json({"off", "contactless", "contact"}));
  EXPECT_EQ(c["speed"]["max_mm_s"], 50.0);
  EXPECT_EQ(c["speed"]["min_mm_s"], 0.25);
  EXPECT_EQ(c["speed"]["d_max_mm"], 130.0);
  EXPECT_TRUE(c["simulated"].get<bool>());
  // Five disks × 7 frames at 100 Hz on a 1 Mbit/s bus (worst-case stuffing), beside the three drives.
  const double load = c["bus"]["sdu_load"].get<double>();
  std::printf("SDU bus load: %s\n", c["bus"]["breakdown"].get<std::string>().c_str());
  EXPECT_GT(load, 0.45);
  EXPECT_LT(load, 0.50);
  const auto topics = api->topics();
  for (const char* t : {"/sdu/continuum", "/sdu/operating_state"})
    EXPECT_NE(std::find(topics.begin(), topics.end(), t), topics.end()) << t;
  const auto names = sdu().mapper().topics();
  ASSERT_EQ(names.size(), 2u);
  EXPECT_EQ(names[0].topic, "/sdu/map");
  EXPECT_EQ(names[0].schema_name, "foxglove.PointCloud");
  EXPECT_EQ(names[1].topic, "/sdu/planes");
  EXPECT_EQ(names[1].schema_name, "foxglove.SceneUpdate");
}

TEST_F(SduContinuumTest, HoldsUntilTheHallBaselineIsTakenThenReadsEveryDiskAt100Hz) {
  start(config());
  // Enabled at once: the supervisor is still unbiasing, so the robot holds with that cause.
  ASSERT_EQ(api->state_command("sdu", {{"command", "enable"}}).status, 200);
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 2000)) << op().dump();
  EXPECT_NE(op()["hold"].dump().find("unbiasing"), std::string::npos) << op()["hold"].dump();
  ASSERT_TRUE(step_until([&] { return sdu().snapshot().state == cont::SduSafetyState::kClear; }, 3000));
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
  steps(5);
  EXPECT_EQ(op()["state"], "ENABLED");
  // 100 Hz per disk, none lost: one second gives 100 samples of each of the five.
  const auto before = sdu().samples().samples;
  steps(1000);
  const auto after = sdu().samples();
  EXPECT_NEAR(static_cast<double>(after.samples - before), 500.0, 5.0);
  EXPECT_EQ(after.incomplete, 0u);
  EXPECT_EQ(after.malformed, 0u);
  const auto c = op()["continuum"];
  EXPECT_EQ(c["supervisor"]["state"], "normal");
  for (const auto& d : c["disks"]) {
    EXPECT_TRUE(d["fresh"].get<bool>());
    EXPECT_EQ(d["ranges_mm"].size(), 8u);
    EXPECT_TRUE(d["fault"].is_null());
  }
  // The wall at x = 200 mm: 121 mm from the sleeve, seen by every disk's slot 0 (less its tilt).
  EXPECT_NEAR(c["disks"][0]["ranges_mm"][0].get<double>(), 121.0, 3.0);
  EXPECT_NEAR(c["speed_limit_mm_s"].get<double>(), law(c["nearest_mm"].get<double>()), 1e-9);
}

// The scenario of issue 16: the SIMULATED arm approaches while the operator bends the segment towards
// it; the speed limit follows the law, then the touch stops the robot in the control cycle that sees it.
TEST_F(SduContinuumTest, ArmApproachesRobotSlowsPerTheLawThenStopsOnTouchWithinOneCycle) {
  start(config());
  unbias_and_enable();
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", 20.0}}).status,
      202);
  double min_limit = 1e9, min_kept = 1.0, last_speed = 0.0, speed_at_contact = 0.0;
  int limited_ticks = 0;
  std::uint64_t contact_tick = 0;
  double true_touch_t = -1.0, contact_t = -1.0;
  std::vector<double> q_touch, q_hold;
  bool done = false;
  for (int ms = 0; ms < 20000 && !done; ms += 20) {
    // The operator bends towards the arm (bending plane −y) at 0.1 rad/s, refreshed every 20 ms.
    const auto r = api->servo_jv("sdu", {{"velocity", {0.0, 0.1, 0.0}}});
    if (r.status != 200) break;  // held: the stream is refused
    for (int k = 0; k < 20; ++k) {
      runtime->step();
      const auto s = sdu().snapshot();
      if (true_touch_t < 0.0 && sim().true_max_force() >= 0.5) {
        true_touch_t = runtime->time();
        q_touch = measured();
      }
      if (s.contact) {
        contact_tick = s.tick;
        speed_at_contact = last_speed;
        contact_t = runtime->time();
        // The same cycle: the robot is held (PAUSED) and the setpoint did not move.
        EXPECT_EQ(op()["state"], "PAUSED");
        EXPECT_EQ(s.step_kept, 1.0);
        q_hold = setpoint();
        done = true;
        break;
      }
      last_speed = s.surface_speed_mm_s;
      if (s.state == cont::SduSafetyState::kClear) {
        // The published limit is the law's value at the nearest effective distance, and the fastest
        // window moved no faster.
        EXPECT_NEAR(s.speed_limit_mm_s, law(s.nearest_mm), 1e-9);
        EXPECT_LE(s.surface_speed_mm_s, s.speed_limit_mm_s + 1e-6);
        min_limit = std::min(min_limit, s.speed_limit_mm_s);
        min_kept = std::min(min_kept, s.step_kept);
        if (s.step_kept < 1.0) ++limited_ticks;
      }
    }
  }
  ASSERT_TRUE(done) << op()["continuum"].dump();
  ASSERT_GT(contact_tick, 0u);
  EXPECT_LT(min_limit, 5.0);    // the law took the limit down near the arm
  EXPECT_GT(limited_ticks, 0);  // and the filter cut the operator's steps
  EXPECT_LT(min_kept, 1.0);
  const auto c = op()["continuum"];
  EXPECT_TRUE(c["contact"].get<bool>());
  EXPECT_EQ(c["contact_disk"], 4);  // the top disk meets the arm first
  EXPECT_EQ(c["supervisor"]["state"], "stopped_contact");
  EXPECT_TRUE(logged("contact on SDU 4")) << api->faults().dump();
  // The setpoint stays where the hold put it; the drives come to rest.
  const auto q_stop_cmd = setpoint();
  // Standstill: every joint's measured speed under 1e-4 rad/s (0.008 mm/s at the sleeve).
  const double t_hold = runtime->time();
  ASSERT_TRUE(step_until(
      [&] {
        const auto v = api->measured_js("sdu").body["velocity"].get<std::vector<double>>();
        return std::all_of(v.begin(), v.end(), [](double x) { return std::abs(x) < 1e-4; });
      },
      500));
  const double standstill_s = runtime->time() - t_hold;
  steps(500);
  EXPECT_EQ(setpoint(), q_stop_cmd);
  EXPECT_EQ(q_stop_cmd, q_hold);
  const auto q_rest = measured();
  const auto q_at_detect = q_hold;
  const double after_detect = window_travel(q_at_detect, q_rest);
  const double after_touch = q_touch.empty() ? 0.0 : window_travel(q_touch, q_rest);
  std::printf(
      "stop on touch: detected %.1f ms after the true force reached 0.5 N; the robot held in that control "
      "cycle; stopping distance %.3f mm after detection, %.3f mm after the true touch; slowest limit "
      "before the touch %.2f mm/s, commanded window speed in the cycle before %.3f mm/s; joints at rest "
      "%.0f ms after the hold\n",
      (contact_t - true_touch_t) * 1e3, after_detect, after_touch, min_limit, speed_at_contact,
      standstill_s * 1e3);
  EXPECT_LT(contact_t - true_touch_t, 0.012);  // one 100 Hz sample and one control cycle
  EXPECT_LT(after_detect, 0.5);
  // Resume is refused while the arm presses, with the cause.
  const auto resume = api->state_command("sdu", {{"command", "resume"}});
  EXPECT_EQ(resume.status, 409);
  EXPECT_NE(resume.message.find("contact"), std::string::npos) << resume.message;
  // The arm goes away: the contact clears and resume works.
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "retreat"}, {"speed_mm_s", 50.0}}).status,
      202);
  ASSERT_TRUE(step_until([&] { return !sdu().snapshot().contact; }, 3000));
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
}

// The stop itself at speed: with the proximity law made inert (d_max 1 mm, so the robot meets the arm at
// the operator's full speed, as it would an object no ToF window sees), the touch still holds the robot in
// the control cycle that receives the sample; what it travels after is the sample period's and the drives'.
TEST_F(SduContinuumTest, StopOnTouchAtFullSpeedWithTheLawMadeInert) {
  auto rc = config();
  rc.settings["continuum"]["safety"]["d_max_mm"] = 1.0;
  start(std::move(rc));
  unbias_and_enable();
  // A Hall window (not a ToF window, which would read 0 when covered and slow the robot) faces the arm:
  // the stage turned by 22.5°, the bending plane turned back so that the segment still bends to −y.
  ASSERT_EQ(api->move_jp("sdu", {{"goal", {0.392699, 0.2, -1.570796 - 0.392699}}}).status, 202);
  steps(2);
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 10000));
  // The arm stands in the bending path (its centre at y −230 mm); the operator bends at 0.2 rad/s.
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", 200.0}}).status,
      202);
  steps(500);
  ASSERT_EQ(api->robot_command("sdu", "simulation_scene", {{"action", "stop"}}).status, 202);
  steps(5);
  ASSERT_EQ(op()["state"], "ENABLED") << op()["continuum"]["supervisor"].dump();
  double speed_before = 0.0, t_contact = -1.0, t_true = -1.0, t_touch = -1.0;
  std::vector<double> q_detect, q_touch;
  for (int ms = 0; ms < 10000 && t_contact < 0.0; ms += 20) {
    if (api->servo_jv("sdu", {{"velocity", {0.0, 0.2, 0.0}}}).status != 200) break;
    for (int k = 0; k < 20; ++k) {
      const double before = sdu().snapshot().surface_speed_mm_s;
      runtime->step();
      if (t_true < 0.0 && sim().true_max_force() >= 0.5) t_true = runtime->time();
      if (t_touch < 0.0 && sim().true_max_force() > 0.0) {
        t_touch = runtime->time();
        q_touch = measured();
      }
      if (sdu().snapshot().contact) {
        EXPECT_EQ(op()["state"], "PAUSED");  // in this very cycle
        t_contact = runtime->time();
        speed_before = before;
        q_detect = measured();
        break;
      }
    }
  }
  ASSERT_GT(t_contact, 0.0) << op()["state"] << " " << op()["continuum"]["supervisor"].dump() << " q "
                            << setpoint()[1];
  EXPECT_GT(speed_before, 20.0);  // it met the arm fast
  const auto q_cmd = setpoint();
  steps(500);
  EXPECT_EQ(setpoint(), q_cmd);
  const auto q_rest = measured();
  const double travel = window_travel(q_detect, q_rest);
  const double from_touch = window_travel(q_touch, q_rest);
  std::printf(
      "stop on touch at speed (law inert): window speed %.1f mm/s in the cycle before; detected %.1f ms "
      "after "
      "the simulated sample first showed 0.5 N and %.1f ms after the first sample with any force; held in "
      "that control cycle; the measured windows travelled %.2f mm after the hold (the drives' lag behind the "
      "setpoint) and %.2f mm after the first sample with any force\n",
      speed_before, (t_contact - t_true) * 1e3, (t_contact - t_touch) * 1e3, travel, from_touch);
  EXPECT_LT(travel, 2.0);
}

TEST_F(SduContinuumTest, TheLawCapsMoveJpTooAndEveryModeGoesThroughIt) {
  start(config());
  unbias_and_enable();
  // The arm stands 40 mm from the top disk's sleeve; a move_jp of the stage roll then runs at the law's
  // speed for that distance, slower than its own 0.5 rad/s (40 mm/s at the rim).
  auto rc = sdu().settings().simulation.arm;
  ASSERT_TRUE(rc.has_value());
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", 100.0}}).status,
      202);
  ASSERT_TRUE(step_until([&] { return sdu().snapshot().nearest_mm < 45.0; }, 5000));
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "retreat"}, {"speed_mm_s", 1e-3}}).status,
      202);  // practically stands
  const auto q0 = setpoint();
  auto goal = q0;
  goal[kStageRoll] = 0.2;
  ASSERT_EQ(api->move_jp("sdu", {{"goal", goal}}).status, 202);
  int limited = 0;
  for (int k = 0; k < 1000; ++k) {
    runtime->step();
    const auto s = sdu().snapshot();
    ASSERT_LE(s.surface_speed_mm_s, s.speed_limit_mm_s + 1e-6);
    if (s.step_kept < 1.0) ++limited;
  }
  EXPECT_GT(limited, 100);
  // The move is slowed, not cut: it still ends at its goal.
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 60000));
  EXPECT_NEAR(setpoint()[kStageRoll], 0.2, 1e-6);
}

TEST_F(SduContinuumTest, ASilentDiskHoldsTheRobotWithItsCauseAndTheMapSurvives) {
  start(config());
  unbias_and_enable();
  roll_and_map(0.4, -0.4);
  const auto mapped = sdu().mapper().status().points;
  ASSERT_GT(mapped, 20u);
  sim().set_silent(2, true);
  // Stale after 30 ms (three samples): held in that cycle.
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 60))
      << op()["continuum"]["supervisor"].dump();
  const auto c = op()["continuum"];
  EXPECT_EQ(c["supervisor"]["state"], "holding_fault");
  EXPECT_NE(c["supervisor"]["reason"].get<std::string>().find("SDU 2 silent"), std::string::npos);
  EXPECT_FALSE(c["disks"][2]["fresh"].get<bool>());
  EXPECT_TRUE(c["disks"][2]["fault"].is_string());
  EXPECT_TRUE(logged("SDU 2")) << api->faults().dump();
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 409);
  // Servo commands do not move it; the map keeps every point.
  api->servo_jv("sdu", {{"velocity", {0.2, 0.0, 0.0}}});
  const auto held = setpoint();
  steps(100);
  sdu().mapper().poll(runtime->time());
  EXPECT_EQ(setpoint(), held);
  EXPECT_GE(sdu().mapper().status().points, mapped);
  sim().set_silent(2, false);
  steps(50);
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
}

TEST_F(SduContinuumTest, ANonFiniteOrOutOfRangeToFReadingSlowsToTheSafeSpeed) {
  start(config());
  unbias_and_enable();
  for (double bad : {std::numeric_limits<double>::quiet_NaN(), 300.0}) {
    sim().set_tof_fault(1, 3, bad);
    ASSERT_TRUE(step_until([&] { return sdu().snapshot().state == cont::SduSafetyState::kSlowed; }, 50));
    const auto c = op()["continuum"];
    EXPECT_EQ(c["supervisor"]["state"], "slowed");
    EXPECT_NE(c["supervisor"]["reason"].get<std::string>().find("SDU 1 ToF 3"), std::string::npos);
    EXPECT_EQ(c["speed_limit_mm_s"], 0.25);
    EXPECT_EQ(op()["state"], "ENABLED");  // slowed, not held
    // The operator's stream moves the windows at 0.25 mm/s at most.
    const auto before = measured();
    for (int i = 0; i < 10; ++i) {
      ASSERT_EQ(api->servo_jv("sdu", {{"velocity", {0.3, 0.0, 0.0}}}).status, 200);
      for (int k = 0; k < 20; ++k) {
        runtime->step();
        EXPECT_LE(sdu().snapshot().surface_speed_mm_s, 0.25 + 1e-9);
      }
    }
    const auto after = measured();
    EXPECT_LT(window_travel(before, after), 0.25 * 0.2 + 0.05)
        << before[0] << " " << before[1] << " " << before[2] << " -> " << after[0] << " " << after[1] << " "
        << after[2] << " setpoint " << setpoint()[0];
    EXPECT_TRUE(logged("SDU 1 ToF 3")) << api->faults().dump();
    steps(200);  // the stream times out (150 ms) before the fault clears: nothing moves on at full speed
    sim().set_tof_fault(1, -1, 0.0);
    ASSERT_TRUE(step_until([&] { return sdu().snapshot().state == cont::SduSafetyState::kClear; }, 50));
  }
}

TEST_F(SduContinuumTest, AnUnusableHallReadingHolds) {
  start(config());
  unbias_and_enable();
  sim().set_hall_fault(3, 6);
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 50));
  EXPECT_NE(op()["continuum"]["supervisor"]["reason"].get<std::string>().find("SDU 3 Hall 6"),
            std::string::npos);
  sim().set_hall_fault(3, -1);
  steps(30);
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
}

TEST_F(SduContinuumTest, ADriftingHallBaselineHoldsUntilUnbiasedAgain) {
  start(config());
  unbias_and_enable();
  roll_and_map(0.3, 0.0);
  const auto mapped = sdu().mapper().status().points;
  sim().set_hall_drift(1, -0.02);  // the field sinks: a contact there would be missed
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 8000))
      << op()["continuum"]["supervisor"].dump();
  const auto c = op()["continuum"];
  EXPECT_EQ(c["supervisor"]["state"], "holding_fault");
  EXPECT_NE(c["supervisor"]["reason"].get<std::string>().find("baseline drifted"), std::string::npos);
  EXPECT_TRUE(logged("baseline drifted")) << api->faults().dump();
  const auto resume = api->state_command("sdu", {{"command", "resume"}});
  EXPECT_EQ(resume.status, 409);
  EXPECT_NE(resume.message.find("unbias"), std::string::npos) << resume.message;
  sdu().mapper().poll(runtime->time());
  EXPECT_GE(sdu().mapper().status().points, mapped);
  // The drift stops (the simulated offset goes back with it) and the operator re-zeroes.
  sim().set_hall_drift(1, 0.0);
  ASSERT_EQ(api->robot_command("sdu", "unbias", json::object()).status, 202);
  ASSERT_TRUE(step_until([&] { return sdu().snapshot().state == cont::SduSafetyState::kClear; }, 3000));
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
}

TEST_F(SduContinuumTest, AnEmptyMapIsAClearErrorAndAMappedWallGivesItsPlane) {
  start(config());
  // Nothing mapped yet: a clear error, nothing else changes.
  const auto empty = api->robot_command("sdu", "map", {{"action", "extract"}});
  EXPECT_EQ(empty.status, 409);
  EXPECT_EQ(empty.code, "map_empty");
  EXPECT_NE(empty.message.find("no points"), std::string::npos) << empty.message;
  EXPECT_EQ(op()["continuum"]["map"]["points"], 0);
  unbias_and_enable();
  const double t0 = runtime->time();
  roll_and_map(0.8, -0.8);
  const auto status = sdu().mapper().status();
  std::printf("mapped %zu voxels (%llu points in) in %.1f s of simulated time\n", status.points,
              static_cast<unsigned long long>(status.points_in), runtime->time() - t0);
  ASSERT_GT(status.points, 30u);
  const auto r = api->robot_command("sdu", "map", {{"action", "extract"}});
  ASSERT_EQ(r.status, 200) << r.message;
  ASSERT_GE(r.body["planes"].size(), 1u);
  // The wall x = 200 mm, normal −x (either sign).
  const auto& p = r.body["planes"][0];
  const double nx = p["normal"][0].get<double>();
  EXPECT_NEAR(std::abs(nx), 1.0, 0.02);
  EXPECT_NEAR(p["offset_mm"].get<double>() * (nx > 0 ? 1.0 : -1.0), 200.0, 5.0);
  EXPECT_FALSE(r.body["bracing"]["reason"].get<std::string>().empty());
  // Both topics carry messages now.
  for (const char* topic : {"/sdu/map", "/sdu/planes"}) {
    const auto m = sdu().mapper().latest(topic, 0);
    ASSERT_TRUE(m.has_value()) << topic;
    const auto j = json::parse(*m->payload);
    if (std::string(topic) == "/sdu/map") {
      EXPECT_EQ(j["frame_id"], "sdu_base");
      EXPECT_EQ(j["point_stride"], 12);
    } else {
      EXPECT_GE(j["entities"].size(), 1u);
    }
  }
  // Clear forgets it; extracting again is the clear error.
  EXPECT_EQ(api->robot_command("sdu", "map", {{"action", "clear"}}).status, 200);
  EXPECT_EQ(api->robot_command("sdu", "map", {{"action", "extract"}}).code, "map_empty");
}

// The ways out of a contact hold: the no-slip roll about the contact (Abah 2022, eq. 3.6) and the
// contact-based guidance yielding to the push, each at most the retreat speed of 5 mm/s; then resume.
TEST_F(SduContinuumTest, ContactHoldWaysOutRollAndContactGuidanceBackAway) {
  start(config());
  unbias_and_enable();
  ASSERT_EQ(api->mode("sdu", {{"mode", "guidance"}}).status, 200);
  // The arm walks into the resting segment (its end point is 6 mm inside the top disk's sleeve).
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", 50.0}}).status,
      202);
  ASSERT_TRUE(step_until([&] { return sdu().snapshot().contact; }, 10000)) << op()["continuum"].dump();
  steps(2);
  EXPECT_EQ(op()["state"], "PAUSED");
  EXPECT_EQ(op()["continuum"]["contact_disk"], 4);
  EXPECT_NE(op()["hold"]["message"].get<std::string>().find("contact on SDU 4"), std::string::npos);
  const auto& m = sdu().settings().model;
  auto centre = [&](const std::vector<double>& q) -> Eigen::Vector3d {
    return cont::disk_pose(m, segment_configuration(q), 4).translation();
  };
  // The roll: a stream; the disk's centre moves at most 5 mm/s while the robot stays held.
  const auto q0 = setpoint();
  double fastest = 0.0;
  for (int i = 0; i < 25 && sdu().snapshot().contact; ++i) {
    ASSERT_EQ(api->robot_command("sdu", "roll", {{"rate_rad_s", 0.2}}).status, 202);
    for (int k = 0; k < 20; ++k) {
      const auto a = setpoint();
      runtime->step();
      fastest = std::max(fastest, (centre(setpoint()) - centre(a)).norm() * 1000.0);
    }
  }
  const double rolled = (centre(setpoint()) - centre(q0)).norm();
  EXPECT_GT(rolled, 0.1) << "the roll moved the disk";
  std::printf(
      "no-slip roll: the top disk's centre moved %.2f mm, at most %.2f mm/s, while held on the contact\n",
      rolled, fastest);
  EXPECT_LE(fastest, 5.0 * 1.05);
  EXPECT_EQ(op()["state"], "PAUSED");
  steps(300);  // the roll stream ends
  // Contact-based guidance yields to the push: only straight away from the contact, ≤ 5 mm/s.
  ASSERT_EQ(api->robot_command("sdu", "hri_mode", {{"mode", "contact"}}).status, 202);
  const double y0 = centre(setpoint()).y();
  ASSERT_TRUE(step_until([&] { return !sdu().snapshot().contact; }, 10000)) << op()["continuum"].dump();
  EXPECT_GT(centre(setpoint()).y(), y0) << "backed away from the arm at −y";
  std::printf("contact guidance backed the top disk %.2f mm away from the push until the contact cleared\n",
              centre(setpoint()).y() - y0);
  ASSERT_EQ(api->robot_command("sdu", "hri_mode", {{"mode", "off"}}).status, 202);
  steps(20);
  EXPECT_EQ(api->state_command("sdu", {{"command", "resume"}}).status, 200);
}

TEST_F(SduContinuumTest, ServoCvMovesTheTipInTipModeThroughTheSameSafetyPath) {
  start(config());
  unbias_and_enable();
  const json twist = {{"linear", {10.0, 0.0, 0.0}}, {"angular", {0, 0, 0}}};
  EXPECT_EQ(api->servo_cv("sdu", twist).status, 409);  // joint mode
  ASSERT_EQ(api->mode("sdu", {{"mode", "tip"}}).status, 200);
  steps(2);
  EXPECT_GE(api->servo_cv("sdu", {{"linear", {0, 0, 0}}, {"angular", {0.1, 0, 0}}}).status, 400);
  EXPECT_GE(
      api->move_cp("sdu", {{"goal", {{"position", {0, 0, 300}}, {"orientation", {0, 0, 0, 1}}}}}).status,
      400);
  const auto& m = sdu().settings().model;
  const Eigen::Vector3d p0 = cont::disk_pose(m, segment_configuration(setpoint()), 4).translation();
  // 10 mm/s along +x (towards the wall, 121 mm from the sleeve: the law allows 46 mm/s there) for 1 s.
  for (int i = 0; i < 50; ++i) {
    ASSERT_EQ(api->servo_cv("sdu", twist).status, 200);
    for (int k = 0; k < 20; ++k) {
      runtime->step();
      EXPECT_LE(sdu().snapshot().surface_speed_mm_s, sdu().snapshot().speed_limit_mm_s + 1e-6);
    }
  }
  const Eigen::Vector3d p1 = cont::disk_pose(m, segment_configuration(setpoint()), 4).translation();
  std::printf("servo_cv 10 mm/s along x for 1 s moved the tip by (%.2f, %.2f, %.2f) mm\n", p1.x() - p0.x(),
              p1.y() - p0.y(), p1.z() - p0.z());
  EXPECT_NEAR(p1.x() - p0.x(), 10.0, 1.5);
  EXPECT_NEAR(p1.y() - p0.y(), 0.0, 1.5);
  // The stream ends: the tip stays.
  steps(400);
  const auto held = setpoint();
  steps(200);
  EXPECT_EQ(setpoint(), held);
}

// A context for calling the controller directly (the runtime is stepped, so nothing else runs meanwhile).
class DirectContext final : public ControlContext {
 public:
  bool servo_live() const noexcept override { return false; }
  std::span<const double> servo_velocity() const noexcept override { return {}; }
  void stop_servo() noexcept override {}
  bool hold(safety::FaultCode code, int joint, const char* detail) noexcept override {
    (void)code;
    (void)joint;
    (void)detail;
    ++holds;
    return true;
  }
  safety::FaultCode hold_cause() const noexcept override { return safety::FaultCode::kNone; }
  void setpoint_moved() noexcept override {}
  int holds = 0;
};

// The control thread's part never allocates: sense (the supervisor, the event forwarding, the hold),
// control in guidance and tip mode, the filter, while_held and publish, across state changes.
TEST_F(SduContinuumTest, TheControlThreadsPartNeverAllocates) {
  auto rc = config();
  std::vector<safety::JointLimit> joints;
  for (const auto& j : rc.joints) joints.push_back(j.limit);
  safety::SafetySupervisor supervisor{safety::LimitSet(joints)};
  start(std::move(rc));
  steps(800);  // unbiased, the disks report
  auto& controller = sdu().controller();
  std::array<double, 3> q{0.0, 0.2, -1.570796}, qd{}, effort{}, q_des = q, qd_des{};
  safety::OperatingLimits limits;
  for (std::size_t j = 0; j < 3; ++j) {
    limits.lower[j] = -10;
    limits.upper[j] = 10;
    limits.max_velocity[j] = 0.5;
  }
  limits.servo_timeout_s = 0.15;
  DirectContext ctx;
  ctx.n = 3;
  ctx.q = q;
  ctx.qd = qd;
  ctx.effort = effort;
  ctx.q_des = q_des;
  ctx.qd_des = qd_des;
  ctx.limits = &limits;
  ctx.supervisor = &supervisor;
  ctx.state = safety::OperatingState::kEnabled;
  ctx.drives_ready = true;
  PluginCommand hri;
  hri.id = static_cast<std::uint16_t>(SduCommand::hri_mode);
  hri.values[0] = 1;
  PluginCommand cv;
  cv.id = static_cast<std::uint16_t>(SduCommand::servo_cv);
  cv.count = 3;
  cv.values = {5.0, 0.0, 0.0};
  sim().set_tof_fault(2, 4, std::numeric_limits<double>::quiet_NaN());  // a state change on the way
  const long before = tendril::testing::allocation_count.load();
  for (int k = 0; k < 300; ++k) {
    if (k == 150) sim().set_silent(1, true);  // and a hold (silent disk) later
    runtime->step();  // new samples arrive (the runtime's own step is not what is counted: see below)
    const long outside = tendril::testing::allocation_count.load();
    ctx.t = runtime->time();
    ctx.now_ns = sdu().snapshot().now_ns + 1;  // the runtime's clock, which stamps the samples
    ctx.mode = k < 100 ? kGuidanceMode : kTipMode;
    controller.apply(ctx, k < 100 ? hri : cv);
    const std::array<double, 3> before_step = q_des;
    controller.sense(ctx);
    controller.control(ctx);
    controller.limit_step(ctx, before_step);
    ctx.state = safety::OperatingState::kPaused;
    controller.while_held(ctx);
    ctx.state = safety::OperatingState::kEnabled;
    char why[96];
    controller.hold_cleared(ctx, why, sizeof why);
    controller.publish(ctx);
    EXPECT_EQ(tendril::testing::allocation_count.load(), outside) << "cycle " << k;
  }
  (void)before;
  EXPECT_GT(ctx.holds, 0);                // the silent disk held it
  ::operator delete(::operator new(16));  // the counter sees allocations, so the check above can fail
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
}

TEST_F(SduContinuumTest, ASecondSduRobotOnTheSameBusIsRefused) {
  auto first = config();
  auto second = config();
  second.name = "sdu2";
  for (std::size_t j = 0; j < second.joints.size(); ++j)
    second.joints[j].drive->node_id = 4 + static_cast<int>(j);
  RuntimeOptions o;
  o.stepped = true;
  o.control_rate_hz = 1000;
  try {
    RobotRuntime rt({first, second}, o, builtin_robot_types());
    FAIL() << "two SDU robots on one bus were accepted";
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("continuum.disks.bus"), std::string::npos) << what;
    EXPECT_NE(what.find("would clash"), std::string::npos) << what;
  }
  // The refusal left nothing behind: one SDU robot still starts.
  start(config());
  EXPECT_EQ(api->robots().size(), 1u);
}

TEST_F(SduContinuumTest, CommandsRefuseBadBodies) {
  start(config());
  EXPECT_EQ(api->robot_command("sdu", "hri_mode", {{"mode", "fast"}}).status, 400);
  EXPECT_EQ(api->robot_command("sdu", "hri_mode", json::object()).status, 400);
  EXPECT_EQ(api->robot_command("sdu", "map", {{"action", "draw"}}).status, 400);
  EXPECT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", -1}}).status,
      400);
  EXPECT_EQ(api->robot_command("sdu", "roll", {{"rate_rad_s", 0.1}}).status, 409);  // no contact
  EXPECT_EQ(api->robot_command("sdu", "hri_mode", {{"mode", "contactless"}}).status, 202);
  steps(3);
  EXPECT_EQ(op()["continuum"]["hri_mode"], "contactless");
}

TEST_F(SduContinuumTest, ContactlessGuidanceMovesTheTopDiskAwayFromAHand) {
  start(config());
  unbias_and_enable();
  ASSERT_EQ(api->mode("sdu", {{"mode", "guidance"}}).status, 200);
  ASSERT_EQ(api->robot_command("sdu", "hri_mode", {{"mode", "contactless"}}).status, 202);
  steps(5);
  // The arm comes near the top disk's −y side: its right window (slot 6, 270°) at stage roll 0.
  ASSERT_EQ(
      api->robot_command("sdu", "simulation_scene", {{"action", "approach"}, {"speed_mm_s", 30.0}}).status,
      202);
  ASSERT_TRUE(step_until([&] { return std::abs(sdu().snapshot().guidance_mm_s) > 1.0; }, 5000))
      << op()["continuum"].dump();
  const auto before = measured();
  steps(500);
  const auto& m = sdu().settings().model;
  const double y0 = cont::disk_pose(m, segment_configuration(before), 4).translation().y();
  const double y1 = cont::disk_pose(m, segment_configuration(measured()), 4).translation().y();
  EXPECT_GT(y1, y0) << "the top disk should move away from the arm at −y";
}

}  // namespace
}  // namespace tendril::server
