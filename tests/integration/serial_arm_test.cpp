// The serial_arm robot type (server/src/robots/serial_arm) end to end through the runtime and the JSON
// API, with config/robots/ur5_arm.json: the SIMULATED UR5 at the joint interface, its force sensor and
// tissue, stepped simulated time at 1 kHz (nothing here reads a clock). Joint mode (move_jp), the
// Cartesian mode (servo_cv, move_cp, servo_cp), measured_cf on the simulated contact, the arm's hard
// limits (F_max with retraction, a silent force sensor, the workspace box), the e-stop, refused goals,
// and the catheter and the arm in one runtime.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "json_api.hpp"
#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";
constexpr double kStartFlangeZ = 250.226;  // mm: the file's start pose (probe down), UR5 forward kinematics

Eigen::Vector3d vec3(const json& j) { return {j[0].get<double>(), j[1].get<double>(), j[2].get<double>()}; }
Eigen::Quaterniond quat(const json& j) {
  return {j[3].get<double>(), j[0].get<double>(), j[1].get<double>(), j[2].get<double>()};
}

class SerialArmTest : public ::testing::Test {
 protected:
  // `surface_mm`: the tissue's height (base z), or NaN for the file's.
  void start(std::vector<RobotConfig> robots) {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    runtime = std::make_unique<RobotRuntime>(std::move(robots), o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(20);
  }
  static RobotConfig arm_config() { return load_robot_config(kConfig / "ur5_arm.json"); }
  void SetUp() override {}
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
  json op(const std::string& robot = "ur5") { return api->operating_state(robot).body; }
  SerialArm& arm() { return dynamic_cast<SerialArm&>(*runtime->plugin("ur5")); }
  void enable(const std::string& robot = "ur5") {
    ASSERT_EQ(api->state_command(robot, {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(step_until(
        [&] { return op(robot)["drives_ready"].get<bool>() && !op(robot)["is_busy"].get<bool>(); }, 3000))
        << op(robot).dump();
  }
  void cartesian_mode() {
    const auto r = api->mode("ur5", {{"mode", "cartesian"}});
    ASSERT_EQ(r.status, 200) << r.message;
    steps(2);
    ASSERT_EQ(op()["mode"], "cartesian");
  }
  std::vector<double> measured() {
    return api->measured_js("ur5").body["position"].get<std::vector<double>>();
  }
  json pose() { return api->measured_cp("ur5").body; }
  json goal_from(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
    return {{"goal", {{"position", {p.x(), p.y(), p.z()}}, {"orientation", {q.x(), q.y(), q.z(), q.w()}}}}};
  }
  // Streams servo_cv every 20 ms for `seconds`.
  void stream_twist(const Eigen::Vector3d& linear, double seconds) {
    for (int ms = 0; ms < seconds * 1000; ms += 20) {
      const auto r =
          api->servo_cv("ur5", {{"linear", {linear.x(), linear.y(), linear.z()}}, {"angular", {0, 0, 0}}});
      ASSERT_EQ(r.status, 200) << r.message;
      steps(20);
    }
  }
  // Moves the tool with move_cp to `p` (the current orientation) and waits for the move to end.
  void move_to(const Eigen::Vector3d& p) {
    const auto r = api->move_cp("ur5", goal_from(p, quat(pose()["orientation"])));
    ASSERT_EQ(r.status, 202) << r.message;
    const int budget = static_cast<int>((r.body["duration_s"].get<double>() + 6.0) * 1000);
    steps(2);  // the control thread takes the command
    ASSERT_EQ(op()["arm"]["motion"], "move_cp");
    ASSERT_TRUE(step_until([&] { return op()["arm"]["motion"] == "none"; }, budget)) << op().dump();
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(SerialArmTest, DescribesASixJointArmInRadiansWithCartesianCommands) {
  start({arm_config()});
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 1u);
  const auto& r = robots[0];
  EXPECT_EQ(r["kind"], "serial_arm");
  EXPECT_TRUE(r["cartesian"].get<bool>());
  ASSERT_EQ(r["joints"].size(), 6u);
  for (const auto& j : r["joints"]) EXPECT_EQ(j["unit"], "rad");
  EXPECT_EQ(r["modes"], json({"joint", "cartesian"}));  // no plans for an arm: no path_following
  EXPECT_EQ(r["arm"]["model"], "ur5");
  EXPECT_TRUE(r["arm"]["simulated"].get<bool>());
  // The start pose: probe straight down at the UR5's published geometry.
  const auto p = pose();
  EXPECT_NEAR(p["position"][0].get<double>(), -609.938, 0.05);
  EXPECT_NEAR(p["position"][1].get<double>(), -109.15, 0.05);
  EXPECT_NEAR(p["position"][2].get<double>(), kStartFlangeZ, 0.05);
  const Eigen::Vector3d tool_z = quat(p["orientation"]).toRotationMatrix().col(2);
  EXPECT_NEAR(tool_z.z(), -1.0, 1e-4);
}

TEST_F(SerialArmTest, JointMoveReachesItsGoal) {
  start({arm_config()});
  enable();
  auto goal = measured();
  goal[0] += 0.5;  // shoulder pan
  goal[2] -= 0.2;  // elbow
  goal[5] += 0.3;  // wrist 3
  const auto r = api->move_jp("ur5", {{"goal", goal}});
  ASSERT_EQ(r.status, 202) << r.message;
  const double duration = r.body["duration_s"].get<double>();
  // The quintic of the largest step, 0.5 rad within 1 rad/s and 2 rad/s²: the acceleration decides,
  // √(5.774·0.5/2) = 1.20 s (the speed: 1.875·0.5/1 = 0.94 s).
  EXPECT_NEAR(duration, 1.20, 0.02);
  steps(static_cast<int>(duration * 1000) + 500);
  const auto q = measured();
  for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(q[i], goal[i], 2e-3) << "joint " << i;
  EXPECT_FALSE(op()["is_busy"].get<bool>());
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(SerialArmTest, ServoCvMovesTheToolAtTheStreamedVelocity) {
  start({arm_config()});
  enable();
  cartesian_mode();
  const Eigen::Vector3d start_position = vec3(pose()["position"]);
  const Eigen::Quaterniond start_orientation = quat(pose()["orientation"]);
  stream_twist({0.0, 20.0, 0.0}, 1.0);
  const auto cv = api->measured_cv("ur5").body;
  EXPECT_NEAR(cv["linear"][1].get<double>(), 20.0, 1.0) << cv.dump();
  EXPECT_NEAR(cv["linear"][0].get<double>(), 0.0, 1.0);
  EXPECT_NEAR(cv["linear"][2].get<double>(), 0.0, 1.0);
  stream_twist({0.0, 20.0, 0.0}, 1.0);
  const Eigen::Vector3d moved = vec3(pose()["position"]) - start_position;
  // 2 s at 20 mm/s, less the start-up (the arm's 20 ms drive and one-period latency).
  EXPECT_NEAR(moved.y(), 40.0, 1.5) << moved.transpose();
  EXPECT_NEAR(moved.x(), 0.0, 0.5);
  EXPECT_NEAR(moved.z(), 0.0, 0.5);
  EXPECT_LT(quat(pose()["orientation"]).angularDistance(start_orientation), 0.002);
  // The stream stops: after the command timeout (150 ms) the motion ends, as a servo_jv stream's does
  // (logged as a hold; the arm stays ENABLED), and the tool stands still.
  const Eigen::Vector3d last = vec3(pose()["position"]);
  steps(800);
  EXPECT_EQ(op()["arm"]["motion"], "none");
  EXPECT_FALSE(op()["is_busy"].get<bool>());
  bool logged = false;
  for (const auto& e : api->faults())
    logged = logged || (e["kind"] == "hold" && e["code"] == "servo command timeout");
  EXPECT_TRUE(logged) << api->faults().dump();
  const Eigen::Vector3d held = vec3(pose()["position"]);
  EXPECT_NEAR(held.y() - last.y(), 20.0 * 0.150, 0.5);  // the stream's last 150 ms, then nothing
  steps(500);
  EXPECT_LT((vec3(pose()["position"]) - held).norm(), 0.02);
}

TEST_F(SerialArmTest, ServoCvIsCappedAtTheArticlesSpeed) {
  start({arm_config()});
  enable();
  cartesian_mode();
  stream_twist({0.0, 0.0, 200.0}, 1.0);  // four times V_d
  const auto cv = api->measured_cv("ur5").body;
  EXPECT_NEAR(vec3(cv["linear"]).norm(), 50.0, 1.5) << cv.dump();
  EXPECT_TRUE(op()["arm"]["twist_limited"].get<bool>());
}

TEST_F(SerialArmTest, MoveCpReachesThePoseWithinTolerance) {
  start({arm_config()});
  enable();
  cartesian_mode();
  const Eigen::Vector3d p0 = vec3(pose()["position"]);
  const Eigen::Quaterniond q0 = quat(pose()["orientation"]);
  const Eigen::Vector3d target = p0 + Eigen::Vector3d(30.0, -40.0, 50.0);
  const Eigen::Quaterniond orientation = (Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()) * q0).normalized();
  const auto r = api->move_cp("ur5", goal_from(target, orientation));
  ASSERT_EQ(r.status, 202) << r.message;
  const double duration = r.body["duration_s"].get<double>();
  // One quintic for 70.7 mm at ≤ 50 mm/s and 100 mm/s² and 0.1 rad at ≤ 0.1 rad/s and 0.2 rad/s²: the
  // linear speed decides, 1.875·70.71/50 = 2.652 s (the others: √(5.774·70.71/100) = 2.02 s,
  // 1.875·0.1/0.1 = 1.875 s, √(5.774·0.1/0.2) = 1.70 s).
  EXPECT_NEAR(duration, 2.652, 0.01);
  steps(static_cast<int>(duration * 1000) / 2);
  EXPECT_EQ(op()["arm"]["motion"], "move_cp");
  EXPECT_TRUE(op()["is_busy"].get<bool>());
  ASSERT_TRUE(step_until([&] { return op()["arm"]["motion"] == "none"; }, 8000)) << op().dump();
  steps(300);  // the joints settle on the setpoint
  const auto p = pose();
  EXPECT_LT((vec3(p["position"]) - target).norm(), 1.0) << vec3(p["position"]).transpose();
  EXPECT_LT(quat(p["orientation"]).angularDistance(orientation), 0.01);
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(SerialArmTest, ServoCpFollowsANearGoalAndRefusesAFarOne) {
  start({arm_config()});
  enable();
  cartesian_mode();
  const Eigen::Vector3d p0 = vec3(pose()["position"]);
  const Eigen::Quaterniond q0 = quat(pose()["orientation"]);
  const Eigen::Vector3d target = p0 + Eigen::Vector3d(0.0, 0.0, 10.0);
  for (int i = 0; i < 100; ++i) {  // 2 s of a fixed setpoint 10 mm up
    ASSERT_EQ(api->servo_cp("ur5", goal_from(target, q0)).status, 200);
    steps(20);
  }
  EXPECT_LT((vec3(pose()["position"]) - target).norm(), 0.5);
  const auto far = api->servo_cp("ur5", goal_from(p0 + Eigen::Vector3d(0.0, 0.0, 60.0), q0));
  EXPECT_EQ(far.status, 422);
  EXPECT_EQ(far.code, "step_too_large") << far.message;
}

TEST_F(SerialArmTest, MeasuredCfReadsTheSimulatedContact) {
  auto config = arm_config();
  // Tissue 5 mm under the flange (0.5 N/mm), then the tool 4 mm into it: 2 N, under F_max (3 N).
  config.settings["arm"]["simulation"]["contact_surface"]["height_mm"] = kStartFlangeZ - 5.0;
  start({std::move(config)});
  EXPECT_NEAR(vec3(api->measured_cf("ur5").body["force"]).norm(), 0.0, 0.1);  // no contact
  enable();
  cartesian_mode();
  move_to(vec3(pose()["position"]) - Eigen::Vector3d(0.0, 0.0, 9.0));
  steps(300);
  const auto cf = api->measured_cf("ur5").body;
  const Eigen::Vector3d f = vec3(cf["force"]);
  // The tissue pushes the probe back along its own axis: −z in the tool frame (z points down, into it).
  EXPECT_NEAR(f.z(), -2.0, 0.15) << cf.dump();
  EXPECT_NEAR(f.x(), 0.0, 0.1);
  EXPECT_NEAR(f.y(), 0.0, 0.1);
  EXPECT_EQ(cf["frame"], "tool");
  const auto truth = arm().simulated_force_sensor().truth();
  EXPECT_TRUE(truth.in_contact);
  EXPECT_NEAR(truth.penetration, 4.0, 0.1);
  EXPECT_NEAR(op()["arm"]["contact_force_n"].get<double>(), 2.0, 0.15);
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(SerialArmTest, ContactForceOverFmaxHoldsAndRetracts) {
  auto config = arm_config();
  config.settings["arm"]["simulation"]["contact_surface"]["height_mm"] = kStartFlangeZ - 5.0;
  start({std::move(config)});
  enable();
  cartesian_mode();
  const Eigen::Vector3d p0 = vec3(pose()["position"]);
  // 15 mm down: 10 mm into 0.5 N/mm tissue would be 5 N.
  ASSERT_EQ(api->move_cp("ur5", goal_from(p0 - Eigen::Vector3d(0.0, 0.0, 15.0), quat(pose()["orientation"])))
                .status,
            202);
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 10000)) << op().dump();
  auto s = op();
  EXPECT_EQ(s["hold"]["cause"], "external fault");
  bool logged = false;
  for (const auto& e : api->faults())
    logged = logged || (e["kind"] == "hold" &&
                        e["message"].get<std::string>().find("over F_max 3.00 N") != std::string::npos);
  EXPECT_TRUE(logged) << api->faults().dump();
  EXPECT_TRUE(s["arm"]["force_hold"].get<bool>());
  // The force never got far past F_max: the hold comes within a sample of crossing it.
  EXPECT_LT(arm().simulated_force_sensor().truth().penetration, 6.6 + 0.5);
  // Retraction at ≤ 10 mm/s: it backs away along the contact force until under the resume bound (1.5 N).
  ASSERT_TRUE(step_until([&] { return !op()["arm"]["retracting"].get<bool>(); }, 5000)) << op().dump();
  steps(200);
  EXPECT_LT(op()["arm"]["contact_force_n"].get<double>(), 1.6);
  const auto resume = api->state_command("ur5", {{"command", "resume"}});
  EXPECT_EQ(resume.status, 200) << resume.message;
  steps(5);
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(SerialArmTest, ASilentForceSensorHoldsTheArmAndResumeIsRefused) {
  start({arm_config()});
  enable();
  cartesian_mode();
  stream_twist({10.0, 0.0, 0.0}, 0.2);
  arm().simulated_force_sensor().set_silent(true);
  // The last reading is 2 ms old when it goes silent; the hold comes once it is 20 ms old.
  int held_after = -1;
  for (int ms = 1; ms <= 40 && held_after < 0; ++ms) {
    if (ms % 20 == 0) api->servo_cv("ur5", {{"linear", {10.0, 0.0, 0.0}}, {"angular", {0, 0, 0}}});
    steps(1);
    if (op()["state"] == "PAUSED") held_after = ms;
  }
  ASSERT_GT(held_after, 0) << op().dump();
  EXPECT_LE(held_after, 20);
  EXPECT_EQ(op()["hold"]["cause"], "sensor stream stale");
  // The hold's text (the event log, GET /api/v1/faults): which device, for how long, and that the loop
  // kept time: a silent sensor, not a busy computer.
  std::string message;
  for (const auto& e : api->faults())
    if (e["kind"] == "hold" && message.empty()) message = e["message"].get<std::string>();
  EXPECT_TRUE(
      std::regex_match(message, std::regex("hold: sensor stream stale: SIMULATED force sensor of 'ur5' sent "
                                           "nothing for 2[01] ms \\(bound 20 ms\\): the device went "
                                           "silent; the control loop kept time \\(0 ms late this cycle\\)")))
      << message;
  const auto resume = api->state_command("ur5", {{"command", "resume"}});
  EXPECT_EQ(resume.status, 409);
  EXPECT_EQ(resume.code, "hold_not_cleared") << resume.message;
  arm().simulated_force_sensor().set_silent(false);
  steps(20);
  EXPECT_EQ(api->state_command("ur5", {{"command", "resume"}}).status, 200);
}

TEST_F(SerialArmTest, AStallUnderTheBoundWhileMovingLeavesTheForceSensorFresh) {
  // On a shared machine the whole process stalls for tens of ms; afterwards the control thread runs
  // first. The SIMULATED sensor samples in that thread, so its reading is as fresh as the cycle and a
  // 30 ms stall (under the 50 ms lost-control bound, over the sensor's 20 ms staleness bound) holds
  // nothing. (With the sensor in a thread of its own the first cycle read a 31 ms old value and held.)
  using Stall = RobotRuntime::Stall;
  start({arm_config()});
  enable();
  cartesian_mode();
  for (const auto what : {Stall::whole_process, Stall::control_thread}) {
    SCOPED_TRACE(what == Stall::whole_process ? "whole process" : "control thread");
    stream_twist({10.0, 0.0, 0.0}, 0.1);
    ASSERT_EQ(op()["arm"]["motion"], "servo_cv");
    const std::int64_t before = arm().simulated_force_sensor().read().stamp_ns;
    runtime->stall(std::chrono::milliseconds(30), what);
    runtime->step();
    const auto s = op();
    EXPECT_EQ(s["state"], "ENABLED") << s.dump();
    EXPECT_TRUE(s["arm"]["force_fresh"].get<bool>()) << s.dump();
    // The sensor sampled through the stall: its newest reading is from after it.
    EXPECT_GE(arm().simulated_force_sensor().read().stamp_ns - before, 29'000'000);
  }
}

TEST(SerialArmLive, TheControlThreadSamplesTheSimulatedForceSensor) {
  // A live runtime (real time, its own threads): the SIMULATED sensor has no thread of its own, yet
  // its readings come and keep coming, each newer than the last, fresh when the control cycle reads.
  RuntimeOptions o;
  o.control_rate_hz = 1000;
  o.realtime_priority = false;
  RobotRuntime runtime({load_robot_config(kConfig / "ur5_arm.json")}, o, builtin_robot_types());
  runtime.start();
  auto& sensor = dynamic_cast<SerialArm&>(*runtime.plugin("ur5")).simulated_force_sensor();
  std::int64_t first = 0;
  for (int k = 0; k < 2000 && !sensor.read().valid; ++k)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_TRUE(sensor.read().valid);
  first = sensor.read().stamp_ns;
  EXPECT_FALSE(sensor.running());
  std::int64_t later = first;
  for (int k = 0; k < 2000 && later - first < 50'000'000; ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    later = sensor.read().stamp_ns;
  }
  EXPECT_GE(later - first, 50'000'000);
  runtime.stop();
  EXPECT_FALSE(sensor.read().valid);  // stopped like any component
}

TEST_F(SerialArmTest, EstopStopsTheArm) {
  start({arm_config()});
  enable();
  auto goal = measured();
  goal[0] += 1.5;
  ASSERT_EQ(api->move_jp("ur5", {{"goal", goal}}).status, 202);
  steps(1000);  // mid-move, near full speed
  const double speed = std::abs(api->measured_js("ur5").body["velocity"][0].get<double>());
  ASSERT_GT(speed, 0.5);
  ASSERT_EQ(api->estop().status, 200);
  // Quick stop at the arm's 8 rad/s²: 1 rad/s stops in 0.125 s (plus the link's latency).
  steps(200);
  // The answer is kept: a range-for over a member of a temporary would read freed memory.
  const auto stopped = api->measured_js("ur5");
  for (const auto& v : stopped.body["velocity"]) EXPECT_LT(std::abs(v.get<double>()), 5e-3);
  EXPECT_TRUE(op()["estop"].get<bool>());
  EXPECT_NE(op()["state"], "ENABLED");
  EXPECT_EQ(arm().simulated_arm().truth().state, sim::ArmControllerState::quick_stop);
  const auto refused = api->move_jp("ur5", {{"goal", measured()}});
  EXPECT_EQ(refused.status, 409) << refused.message;
  const double at = measured()[0];
  steps(500);
  EXPECT_NEAR(measured()[0], at, 1e-3);
}

TEST_F(SerialArmTest, OutOfLimitGoalsAreRefusedAndNothingMoves) {
  start({arm_config()});
  enable();
  const auto q0 = measured();
  auto beyond = q0;
  beyond[2] = 3.5;  // elbow past +π
  auto r = api->move_jp("ur5", {{"goal", beyond}});
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "out_of_limits") << r.message;
  EXPECT_EQ(api->servo_jv("ur5", {{"velocity", {0, 0, 0, 0, 0, 1.5}}}).status, 422);  // over 1 rad/s
  // Cartesian commands need the cartesian mode.
  const Eigen::Quaterniond o = quat(pose()["orientation"]);
  r = api->move_cp("ur5", goal_from(vec3(pose()["position"]), o));
  EXPECT_EQ(r.status, 409);
  EXPECT_EQ(r.code, "wrong_mode") << r.message;
  cartesian_mode();
  r = api->move_cp("ur5", goal_from({-600.0, -100.0, 50.0}, o));  // under the workspace box's floor
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "out_of_workspace") << r.message;
  r = api->move_cp("ur5", goal_from({-850.0, 800.0, 900.0}, o));  // in the box, beyond the UR5's reach
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "unreachable") << r.message;
  r = api->servo_cv("ur5", {{"linear", {0.0, std::nan(""), 0.0}}, {"angular", {0, 0, 0}}});
  EXPECT_EQ(r.status, 400);
  steps(500);
  const auto q = measured();
  for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(q[i], q0[i], 1e-3);
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(SerialArmTest, TheWorkspaceBoxStopsAServoStream) {
  auto config = arm_config();
  config.settings["arm"]["workspace_mm"]["min"][2] = kStartFlangeZ - 10.0;
  start({std::move(config)});
  enable();
  cartesian_mode();
  stream_twist({0.0, 0.0, -20.0}, 1.5);  // 30 mm down against a floor 10 mm down
  EXPECT_NEAR(pose()["position"][2].get<double>(), kStartFlangeZ - 10.0, 0.3);
  EXPECT_TRUE(op()["arm"]["workspace_limited"].get<bool>());
  stream_twist({0.0, 0.0, 20.0}, 0.5);  // back up is allowed
  EXPECT_GT(pose()["position"][2].get<double>(), kStartFlangeZ - 5.0);
}

TEST_F(SerialArmTest, LostControlBoundOfALinkThatIsNotCan) {
  // The file's bound: half the simulated arm's 100 ms watchdog.
  start({arm_config()});
  EXPECT_DOUBLE_EQ(op()["loop_timing"]["max_lost_control_ms"].get<double>(), 50.0);
  runtime->stop();
  // Without it: half the command timeout (the robot has no CAN heartbeat consumer to bound it).
  auto config = arm_config();
  config.max_lost_control_ms = 0;
  start({std::move(config)});
  EXPECT_DOUBLE_EQ(op()["loop_timing"]["max_lost_control_ms"].get<double>(), 75.0);
}

TEST_F(SerialArmTest, RobotFilesTheTypeRefuses) {
  RuntimeOptions o;
  o.stepped = true;
  o.control_rate_hz = 1000;
  auto expect_refused = [&](RobotConfig c, const std::string& words) {
    try {
      RobotRuntime r({std::move(c)}, o, builtin_robot_types());
      ADD_FAILURE() << "accepted; expected an error with: " << words;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  auto c = arm_config();
  c.settings["arm"].erase("simulation");
  expect_refused(c, "RTDE");
  c = arm_config();
  c.joints.pop_back();
  expect_refused(c, "expected 6 joints");
  c = arm_config();
  c.joints[0].limit.upper = 7.0;
  expect_refused(c, "within the UR5's");
  auto document = read_json_file(kConfig / "ur5_arm.json");
  document["arm"]["work_space_mm"] = document["arm"]["workspace_mm"];
  expect_refused(parse_robot_config(document, kConfig / "ur5_arm.json"), "work_space_mm");
}

// ---- two robots in one runtime: the catheter and the arm, the set-up of Heunis et al. 2021 ------------

class TwoRobotsTest : public SerialArmTest {
 protected:
  void SetUp() override {
    auto srmc = load_robot_config(kConfig / "srmc.json");
    srmc.settings["catheter"]["simulation"].erase("vessel");  // free space
    start({std::move(srmc), arm_config()});
  }
};

TEST_F(TwoRobotsTest, EachRobotHasItsOwnStateAndMode) {
  ASSERT_EQ(api->robots().size(), 2u);
  enable("ur5");
  EXPECT_EQ(op("ur5")["state"], "ENABLED");
  EXPECT_EQ(op("srmc")["state"], "DISABLED");
  cartesian_mode();
  EXPECT_EQ(op("srmc")["mode"], "joint");
  EXPECT_EQ(api->mode("srmc", {{"mode", "cartesian"}}).status, 422);  // not a catheter mode
  enable("srmc");
  // Both move at once: the catheter in joint mode, the arm in Cartesian.
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {20.0, 0.0, 0.0, 0.0}}}).status, 202);
  const Eigen::Vector3d p0 = vec3(pose()["position"]);
  stream_twist({0.0, 20.0, 0.0}, 1.0);
  EXPECT_NEAR(vec3(pose()["position"]).y() - p0.y(), 20.0, 1.5);
  steps(1000);
  EXPECT_NEAR(api->measured_js("srmc").body["position"][0].get<double>(), 20.0, 0.05);
  // A pause of one leaves the other alone.
  ASSERT_EQ(api->state_command("ur5", {{"command", "pause"}}).status, 200);
  steps(5);
  EXPECT_EQ(op("ur5")["state"], "PAUSED");
  EXPECT_EQ(op("srmc")["state"], "ENABLED");
}

TEST_F(TwoRobotsTest, OneEstopStopsBoth) {
  enable("ur5");
  enable("srmc");
  auto goal = measured();
  goal[0] += 1.5;
  ASSERT_EQ(api->move_jp("ur5", {{"goal", goal}}).status, 202);
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {60.0, 0.0, 0.0, 0.0}}}).status, 202);
  steps(1000);
  ASSERT_GT(std::abs(api->measured_js("ur5").body["velocity"][0].get<double>()), 0.5);
  ASSERT_GT(std::abs(api->measured_js("srmc").body["velocity"][0].get<double>()), 0.5);
  ASSERT_EQ(api->estop().status, 200);
  steps(400);
  for (const std::string robot : {"ur5", "srmc"}) {
    EXPECT_TRUE(op(robot)["estop"].get<bool>()) << robot;
    EXPECT_NE(op(robot)["state"], "ENABLED") << robot;
    const auto stopped = api->measured_js(robot);
    for (const auto& v : stopped.body["velocity"]) EXPECT_LT(std::abs(v.get<double>()), 0.01) << robot;
  }
  ASSERT_EQ(api->estop_reset().status, 200);
  steps(5);
  EXPECT_EQ(op("ur5")["state"], "DISABLED");
  EXPECT_EQ(op("srmc")["state"], "DISABLED");
}

}  // namespace
}  // namespace tendril::server
