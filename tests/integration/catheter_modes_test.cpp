// The steerable catheter's modes over the virtual bus in stepped simulated time (Abah 2022, §4.7,
// §4.10.2): configuration control through eq. 4.21, telemanipulation from the console and from the
// simulated ADC joystick with its deadman, active compliance from the simulated spring-deflection
// sensors, the spring-deflection hold with retraction only, and the dissertation's active-vs-passive bend.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>

#include "json_api.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";
constexpr double kDeg = std::numbers::pi / 180.0;

// The channel of the §4.10.2 reproduction (geometry chosen with drivers/sim's plant parameters,
// see drivers/sim/README.md).
struct Channel {
  double lead_in, bend_radius, turn_deg, lumen, insertion, passive_limit, band_deg;
};
constexpr Channel kChannel{55.0, 20.0, 120.0, 1.5875, 40.0, 9.5, 5.0};

RobotConfig free_space_srmc() {
  auto c = load_robot_config(kSrmc);
  c.settings["catheter"]["simulation"].erase("vessel");
  return c;
}

class CatheterTest : public ::testing::Test {
 protected:
  void start(RobotConfig config) {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    runtime =
        std::make_unique<RobotRuntime>(std::vector<RobotConfig>{std::move(config)}, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(50);  // first PDOs from the drives and the ADC nodes
  }
  void TearDown() override {
    if (runtime) runtime->stop();
  }

  // Steps while recording the largest per-tick setpoint change of each joint.
  void steps(int n) {
    for (int i = 0; i < n; ++i) {
      const auto before = setpoint();
      runtime->step();
      const auto after = setpoint();
      for (std::size_t j = 0; j < 4; ++j) max_step[j] = std::max(max_step[j], std::abs(after[j] - before[j]));
    }
  }
  template <typename Pred>
  bool step_until(Pred pred, int max_steps) {
    for (int i = 0; i < max_steps; ++i) {
      if (pred()) return true;
      steps(1);
    }
    return pred();
  }
  std::vector<double> setpoint() {
    return api->setpoint_js("srmc").body["position"].get<std::vector<double>>();
  }
  std::vector<double> measured() {
    return api->measured_js("srmc").body["position"].get<std::vector<double>>();
  }
  nlohmann::json op() { return api->operating_state("srmc").body; }
  void enable() {
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
  }
  void mode(const std::string& m) {
    const auto r = api->mode("srmc", {{"mode", m}});
    ASSERT_EQ(r.status, 200) << r.message;
    ASSERT_TRUE(step_until([&] { return op()["mode"] == m; }, 10)) << op().dump();
  }
  // Streams the console joystick for `ms` milliseconds, 50 Hz like the console.
  void joystick(std::array<double, 4> axes, bool deadman, int ms) {
    for (int t = 0; t < ms; t += 20) {
      const auto r = api->robot_command("srmc", "joystick", {{"axes", axes}, {"deadman", deadman}});
      ASSERT_EQ(r.status, 200) << r.message;
      steps(20);
    }
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  std::array<double, 4> max_step{};
};

TEST_F(CatheterTest, ListsTheModesAndTheConfigurationSpace) {
  start(free_space_srmc());
  const auto robot = api->robots()[0];
  EXPECT_EQ(robot["modes"], nlohmann::json({"joint", "configuration", "active_compliance", "telemanipulation",
                                            "image_guided", "path_following"}));
  EXPECT_EQ(robot["configuration"]["names"],
            nlohmann::json({"insertion", "roll", "theta_proximal", "theta_distal"}));
  // The dissertation's bend-drive limits: -6 <= q3 <= 10 mm, |q4| <= 5 mm.
  EXPECT_EQ(robot["joints"][2]["lower"], -6.0);
  EXPECT_EQ(robot["joints"][2]["upper"], 10.0);
  EXPECT_EQ(robot["joints"][3]["lower"], -5.0);
  EXPECT_EQ(robot["joints"][3]["upper"], 5.0);
  // The proximal bend range follows from those limits through the loss line (4.13): a1·k·q + b1.
  EXPECT_NEAR(robot["configuration"]["upper"][2].get<double>(), 0.063 * 1.4 * 10.0 - 0.049, 1e-3);
  const auto state = op();
  EXPECT_EQ(state["mode"], "joint");
  ASSERT_TRUE(state["spring_deflection_mm"].is_array()) << state.dump();
  EXPECT_LT(std::abs(state["spring_deflection_mm"][0].get<double>()), 0.05);  // free space, relaxed springs
}

TEST_F(CatheterTest, ModeSwitchesOnlyWhileHoldingAndSaysWhyNot) {
  start(free_space_srmc());
  enable();
  EXPECT_EQ(api->mode("srmc", {{"mode", "cartesian"}}).status, 422);
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {30.0, 0.0, 0.0, 0.0}}}).status, 202);
  steps(5);
  const auto refused = api->mode("srmc", {{"mode", "configuration"}});
  EXPECT_EQ(refused.status, 409);
  EXPECT_EQ(refused.code, "not_holding");
  EXPECT_EQ(op()["mode_refusal"]["mode"], "configuration");
  EXPECT_NE(op()["mode_refusal"]["reason"].get<std::string>().find("moving"), std::string::npos);
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 20000));
  const auto before = setpoint();
  for (const char* m : {"configuration", "telemanipulation", "active_compliance", "joint"}) {
    mode(m);
    steps(20);
    const auto after = setpoint();
    for (std::size_t j = 0; j < 4; ++j) EXPECT_NEAR(after[j], before[j], 0.02) << m << " joint " << j;
  }
  EXPECT_TRUE(op()["mode_refusal"].is_null());  // cleared by the accepted switch
}

TEST_F(CatheterTest, ConfigurationModeReachesBendAnglesThroughEq421) {
  start(free_space_srmc());
  enable();
  // Start bent and rolled: the coupling term then rides on a quintic at its speed bound.
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {20.0, 0.3, 2.0, -1.0}}}).status, 202);
  steps(5);
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 20000));
  // Joint commands are for joint mode; configuration goals for configuration mode.
  EXPECT_EQ(api->robot_command("srmc", "move_configuration", {{"goal", {{"theta_proximal", 0.2}}}}).status,
            409);
  mode("configuration");
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {10.0, 0.0, 0.0, 0.0}}}).code, "wrong_mode");
  EXPECT_EQ(
      api->robot_command("srmc", "move_configuration", {{"goal", {{"theta_proximal", 170 * kDeg}}}}).status,
      422);
  EXPECT_EQ(api->robot_command("srmc", "move_configuration", {{"goal", {{"yaw", 0.1}}}}).status, 400);
  max_step = {};
  const auto r = api->robot_command(
      "srmc", "move_configuration",
      {{"goal",
        {{"theta_proximal", 30 * kDeg}, {"theta_distal", -40 * kDeg}, {"insertion", 20.0}, {"roll", 0.0}}}});
  ASSERT_EQ(r.status, 202) << r.message;
  const double duration = r.body["duration_s"].get<double>();
  EXPECT_GT(duration, 0.5);
  steps(5);
  ASSERT_TRUE(
      step_until([&] { return !op()["is_busy"].get<bool>(); }, static_cast<int>(duration * 1000) + 3000));
  const auto psi = op()["configuration"];
  EXPECT_NEAR(psi[0].get<double>(), 20.0, 0.05);
  EXPECT_NEAR(psi[1].get<double>(), 0.0, 1e-3);
  EXPECT_NEAR(psi[2].get<double>(), 30 * kDeg, 0.5 * kDeg) << psi.dump();
  EXPECT_NEAR(psi[3].get<double>(), -40 * kDeg, 0.5 * kDeg) << psi.dump();
  // Smooth: no joint setpoint moved faster than its velocity limit in any tick.
  const std::array<double, 4> vmax{10.0, 1.5, 2.0, 2.0};
  for (std::size_t j = 0; j < 4; ++j) EXPECT_LE(max_step[j], vmax[j] * 0.001 * 1.05) << "joint " << j;
  // Coupling compensation (4.15/4.21) moves the distal drive when only the proximal bend changes.
  const double q4_before = setpoint()[3];
  ASSERT_EQ(
      api->robot_command("srmc", "move_configuration", {{"goal", {{"theta_proximal", 10 * kDeg}}}}).status,
      202);
  steps(5);
  ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>(); }, 20000));
  EXPECT_GT(std::abs(setpoint()[3] - q4_before), 0.01);
  EXPECT_NEAR(op()["configuration"][3].get<double>(), -40 * kDeg, 0.5 * kDeg);
}

TEST_F(CatheterTest, TelemanipulationMovesOnlyWhileTheDeadmanIsHeld) {
  start(free_space_srmc());
  enable();
  EXPECT_EQ(api->robot_command("srmc", "joystick", {{"axes", {0, 0, 0.5, 0}}, {"deadman", true}}).code,
            "wrong_mode");
  mode("telemanipulation");
  const auto q0 = setpoint();
  joystick({0, 0, 0.5, 0}, false, 500);
  EXPECT_NEAR(setpoint()[2], q0[2], 1e-9) << "moved without the deadman";
  joystick({0, 0, 0.5, 0}, true, 1000);
  // 0.5 of the configured 1.0 mm/s for 1 s.
  EXPECT_NEAR(setpoint()[2] - q0[2], 0.5, 0.05);
  EXPECT_EQ(op()["joystick"]["source"], "console");
  // The stream stops: motion stops within the command timeout (150 ms).
  const double after = setpoint()[2];
  steps(400);
  EXPECT_LT(setpoint()[2] - after, 0.5 * 1.0 * 0.16);
  EXPECT_EQ(api->robot_command("srmc", "joystick", {{"axes", {0, 0, 1.5, 0}}, {"deadman", true}}).status,
            422);
  EXPECT_EQ(api->robot_command("srmc", "joystick", {{"axes", {0, 0, 0}}, {"deadman", true}}).status, 422);
}

TEST_F(CatheterTest, TheDissertationsAnalogJoystickDrivesTheBendsWithThePedalHeld) {
  start(free_space_srmc());
  enable();
  mode("telemanipulation");
  auto* stick = catheter(*runtime).simulated_analog_joystick();
  ASSERT_NE(stick, nullptr);
  const auto q0 = setpoint();
  stick->set_deflection({0.0, 0.0, 1.0});  // distal bend full forward, pedal up
  steps(500);
  EXPECT_NEAR(setpoint()[3], q0[3], 1e-9) << "moved without the pedal";
  stick->set_pedal(true);
  steps(1000);
  EXPECT_EQ(op()["joystick"]["source"], "analog");
  EXPECT_NEAR(setpoint()[3] - q0[3], 1.0, 0.1);  // 1.0 mm/s at full stick for ~1 s
  // Both the console and the pedal: a conflict, nothing moves.
  const double q3 = setpoint()[3];
  joystick({0, 0, 0, -1}, true, 300);
  EXPECT_TRUE(op()["joystick"]["conflict"].get<bool>());
  EXPECT_NEAR(setpoint()[3], q3, 0.02);
  stick->set_pedal(false);
}

// The dissertation's channel experiment (§4.10.2) in the simulated vessel: a curved channel (the phantom
// tubing's lumen, a 55 mm lead-in, then a 120° bend of 20 mm radius), the catheter inserted 40 mm at
// 2 mm/s, once with the bend drives held (passive: only the springs let the tubes bend) and once
// under active compliance. For the comparison at equal depth both runs raise the deflection bound
// to 9.5 mm (the passive catheter ends near 6 mm; the dissertation's passive run had no such bound).
RobotConfig channel_srmc(double deflection_limit_mm) {
  auto c = load_robot_config(kSrmc);
  c.settings["catheter"]["simulation"]["vessel"] = {{"lead_in_mm", kChannel.lead_in},
                                                    {"bend_radius_mm", kChannel.bend_radius},
                                                    {"turn_deg", kChannel.turn_deg},
                                                    {"lumen_radius_mm", kChannel.lumen}};
  c.settings["catheter"]["spring_deflection"]["limit_mm"] = deflection_limit_mm;
  // A potentiometer range that can read the passive run's deflection (±10 mm over 0–5 V).
  c.settings["catheter"]["spring_deflection"]["volts_per_mm"] = 0.24;
  return c;
}

struct ChannelRun {
  double bend_deg = 0.0;
  double peak_contact_n = 0.0;
  std::string state;
};

class ChannelTest : public CatheterTest {
 protected:
  // Inserts by `distance` mm at 2 mm/s with servo_jv refreshed every 20 ms, in `mode_name`.
  ChannelRun insert(const std::string& mode_name, double distance) {
    enable();
    mode(mode_name);
    const int ms = static_cast<int>(distance / 2.0 * 1000.0);
    for (int t = 0; t < ms; t += 20) {
      const auto r = api->servo_jv("srmc", {{"velocity", {2.0, 0.0, 0.0, 0.0}}});
      if (r.status != 200) break;  // held: the run ends where the safety stopped it
      steps(20);
    }
    steps(300);
    const auto s = op();
    return {s["simulation"]["tip_bend_rad"].get<double>() / kDeg,
            s["simulation"]["peak_contact_force_n"].get<double>(), s["state"].get<std::string>()};
  }
};

TEST_F(ChannelTest, ActiveComplianceBendsFurtherThanPassiveWithLessWallForce) {
  start(channel_srmc(kChannel.passive_limit));
  const auto passive = insert("joint", kChannel.insertion);
  runtime->stop();
  start(channel_srmc(kChannel.passive_limit));
  const auto active = insert("active_compliance", kChannel.insertion);
  std::printf("  channel: passive %.1f deg (peak wall force %.3f N), active compliance %.1f deg (%.3f N)\n",
              passive.bend_deg, passive.peak_contact_n, active.bend_deg, active.peak_contact_n);
  EXPECT_EQ(passive.state, "ENABLED");
  EXPECT_EQ(active.state, "ENABLED");
  // The dissertation: 81° with active compliance against 43° passive.
  EXPECT_NEAR(active.bend_deg, 81.0, kChannel.band_deg);
  EXPECT_NEAR(passive.bend_deg, 43.0, kChannel.band_deg);
  // The contact force stays under its configured bound (max_contact_force_n, 0.1 N) with compliance;
  // the passive catheter loads the wall more.
  EXPECT_LE(active.peak_contact_n, 0.1);
  EXPECT_GT(passive.peak_contact_n, active.peak_contact_n);
}

TEST_F(ChannelTest, SpringDeflectionOverItsBoundHoldsAndAllowsOnlyRetraction) {
  start(channel_srmc(1.5));
  const auto run = insert("joint", kChannel.insertion);
  ASSERT_EQ(run.state, "PAUSED") << op().dump();
  auto s = op();
  EXPECT_EQ(s["hold_reason"], "spring deflection over its bound");
  EXPECT_TRUE(s["retraction_only"].get<bool>());
  const double deflection = std::max(std::abs(s["spring_deflection_mm"][0].get<double>()),
                                     std::abs(s["spring_deflection_mm"][1].get<double>()));
  EXPECT_GT(deflection, 1.4);
  // Forward is refused with the reason; so is a mode switch.
  const auto forward = api->servo_jv("srmc", {{"velocity", {1.0, 0.0, 0.0, 0.0}}});
  EXPECT_EQ(forward.status, 409);
  EXPECT_EQ(forward.code, "retraction_only");
  EXPECT_EQ(api->mode("srmc", {{"mode", "active_compliance"}}).code, "held_after_limit");
  // Withdrawal moves the catheter back out.
  const double q1 = setpoint()[0];
  for (int t = 0; t < 1000; t += 20) {
    ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {-2.0, 0.0, 0.0, 0.0}}}).status, 200);
    steps(20);
  }
  EXPECT_NEAR(setpoint()[0], q1 - 2.0, 0.1);
  EXPECT_EQ(op()["state"], "PAUSED");
}

// Issue 12: after a deflection hold the robot was stuck (withdrawal does not relax a bend drive's
// spring; resume, disable/enable and e-stop/reset all led back to PAUSED). The way out: relax the
// springs (active compliance on the bend drives while held), then resume; resume is refused with the
// cause and what to do while the cause persists, never accepted into a new hold.
TEST_F(ChannelTest, ADeflectionHoldIsLeftByRelaxingTheSpringsThenResuming) {
  start(channel_srmc(1.5));
  ASSERT_EQ(insert("joint", kChannel.insertion).state, "PAUSED") << op().dump();
  auto s = op();
  EXPECT_EQ(s["hold"]["cause"], "spring_deflection");
  EXPECT_FALSE(s["hold"]["cleared"].get<bool>());
  EXPECT_EQ(s["hold"]["allowed"], nlohmann::json({"relax", "withdraw"})) << s["hold"].dump();
  EXPECT_NE(s["hold"]["next"].get<std::string>().find("relax the springs"), std::string::npos)
      << s["hold"].dump();
  const double worst_before = std::max(std::abs(s["spring_deflection_mm"][0].get<double>()),
                                       std::abs(s["spring_deflection_mm"][1].get<double>()));
  EXPECT_GT(worst_before, 1.5);

  // Resume now: refused with the cause and the way out, and the robot stays held without a new hold.
  const auto refused = api->state_command("srmc", {{"command", "resume"}});
  EXPECT_EQ(refused.status, 409);
  EXPECT_EQ(refused.code, "hold_not_cleared");
  EXPECT_NE(refused.message.find("spring is deflected"), std::string::npos) << refused.message;
  EXPECT_NE(refused.message.find("relax"), std::string::npos) << refused.message;
  const auto events_before = api->faults(1000).size();
  steps(100);
  EXPECT_EQ(op()["state"], "PAUSED");
  EXPECT_EQ(api->faults(1000).size(), events_before) << "nothing happened, not even a new hold";

  // Disable and enable, or e-stop and reset: held again at once (the cause is still there), and
  // still with a way out.
  ASSERT_EQ(api->estop().status, 200);
  steps(5);
  ASSERT_EQ(api->estop_reset().status, 200);
  steps(5);
  ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 3000)) << op().dump();
  EXPECT_EQ(op()["hold"]["cause"], "spring_deflection");

  // Withdraw by a distance: the insertion goes back by exactly that, nothing else moves.
  EXPECT_EQ(api->state_command("srmc", {{"command", "withdraw"}, {"distance_mm", 0.0}}).status, 422);
  EXPECT_EQ(api->state_command("srmc", {{"command", "withdraw"}, {"distance_mm", 11.0}}).status, 422);
  EXPECT_EQ(api->state_command("srmc", {{"command", "withdraw"}}).status, 400);
  const auto q_held = setpoint();
  max_step = {};
  ASSERT_EQ(api->state_command("srmc", {{"command", "withdraw"}, {"distance_mm", 1.5}}).status, 202);
  steps(5);
  EXPECT_TRUE(op()["hold"]["withdraw"]["running"].get<bool>());
  ASSERT_TRUE(step_until([&] { return !op()["hold"]["withdraw"]["running"].get<bool>(); }, 3000));
  EXPECT_NEAR(setpoint()[0], q_held[0] - 1.5, 1e-6);
  for (std::size_t j = 1; j < 4; ++j) EXPECT_NEAR(setpoint()[j], q_held[j], 1e-9) << "joint " << j;
  EXPECT_LE(max_step[0], 3.0 * 0.001 * 1.001);  // the joystick's full insertion speed, 3 mm/s (srmc.json)

  // Relax: only the bend drives move, in the direction that relaxes their springs, until both are
  // within the resume bound (0.75 mm = half the 1.5 mm hold bound).
  ASSERT_GT(std::max(std::abs(op()["spring_deflection_mm"][0].get<double>()),
                     std::abs(op()["spring_deflection_mm"][1].get<double>())),
            0.75)
      << "withdrawal alone did not clear it";
  max_step = {};
  const auto q_before = setpoint();
  const double relax_start = runtime->time();
  const auto relax = api->state_command("srmc", {{"command", "relax"}});
  ASSERT_EQ(relax.status, 202) << relax.message;
  steps(5);
  EXPECT_TRUE(op()["hold"]["relax"]["running"].get<bool>());
  EXPECT_TRUE(op()["is_busy"].get<bool>());
  EXPECT_EQ(api->state_command("srmc", {{"command", "resume"}}).code, "hold_not_cleared");
  ASSERT_TRUE(step_until([&] { return !op()["hold"]["relax"]["running"].get<bool>(); }, 12000))
      << op().dump();
  s = op();
  std::printf("  relax: %.2f mm -> %.2f / %.2f mm in %.2f s (simulated), peak wall force %.3f N\n",
              worst_before, s["spring_deflection_mm"][0].get<double>(),
              s["spring_deflection_mm"][1].get<double>(), runtime->time() - relax_start,
              s["simulation"]["peak_contact_force_n"].get<double>());
  EXPECT_EQ(s["hold"]["relax"]["outcome"], "relaxed") << s["hold"].dump();
  EXPECT_TRUE(s["hold"]["cleared"].get<bool>());
  for (int i = 0; i < 2; ++i) EXPECT_LE(std::abs(s["spring_deflection_mm"][i].get<double>()), 0.75 + 0.02);
  const auto q_after = setpoint();
  EXPECT_NEAR(q_after[0], q_before[0], 1e-9) << "relax does not move the insertion";
  EXPECT_NEAR(q_after[1], q_before[1], 1e-9) << "relax does not move the roll";
  EXPECT_GT(std::abs(q_after[2] - q_before[2]) + std::abs(q_after[3] - q_before[3]), 0.1);
  // No setpoint moved faster than the compliance law's v_max (2 mm/s) in any tick.
  for (std::size_t j = 2; j < 4; ++j) EXPECT_LE(max_step[j], 2.0 * 0.001 * 1.05) << "joint " << j;
  EXPECT_LE(s["simulation"]["peak_contact_force_n"].get<double>(), 1.0);

  // Resume is accepted now, and the robot stays ENABLED.
  const auto resumed = api->state_command("srmc", {{"command", "resume"}});
  ASSERT_EQ(resumed.status, 200) << resumed.message;
  steps(500);
  s = op();
  EXPECT_EQ(s["state"], "ENABLED") << s.dump();
  EXPECT_FALSE(s["retraction_only"].get<bool>());
  EXPECT_TRUE(s["hold"].is_null());
  // The event log tells the story: hold, refused resume, relax started and ended.
  std::string log;
  for (const auto& e : api->faults(1000))
    log += e["kind"].get<std::string>() + ": " + e["message"].get<std::string>() + "\n";
  EXPECT_NE(log.find("recovery: springs relaxed"), std::string::npos) << log;
  EXPECT_NE(log.find("recovery: relax: bend drives follow their springs"), std::string::npos) << log;
}

TEST_F(ChannelTest, RelaxIsOnlyForAHeldRobotAndPauseStopsIt) {
  start(channel_srmc(1.5));
  enable();
  EXPECT_EQ(api->state_command("srmc", {{"command", "relax"}}).code, "invalid_state");
  EXPECT_EQ(api->state_command("srmc", {{"command", "withdraw"}, {"distance_mm", 1.0}}).code,
            "invalid_state");
  ASSERT_EQ(insert("joint", kChannel.insertion).state, "PAUSED") << op().dump();
  ASSERT_EQ(api->state_command("srmc", {{"command", "relax"}}).status, 202);
  steps(50);
  ASSERT_TRUE(op()["hold"]["relax"]["running"].get<bool>());
  ASSERT_EQ(api->state_command("srmc", {{"command", "pause"}}).status, 200);
  steps(5);
  const auto q = setpoint();
  steps(200);
  EXPECT_EQ(op()["hold"]["relax"]["outcome"], "stopped");
  for (std::size_t j = 0; j < 4; ++j) EXPECT_NEAR(setpoint()[j], q[j], 1e-9) << "joint " << j;
}

// An operator's pause, then the deflection sensor goes silent: resuming would hold again at once, so
// it is refused the same way, with the cause; once the sensor reads again, resume works.
TEST_F(CatheterTest, ResumeAfterAnOperatorPauseIsRefusedWhileTheSensorIsSilent) {
  start(free_space_srmc());
  enable();
  ASSERT_EQ(api->state_command("srmc", {{"command", "pause"}}).status, 200);
  steps(5);
  auto* sensor = catheter(*runtime).simulated_spring_sensor();
  sensor->set_silent(true);
  steps(200);
  auto s = op();
  EXPECT_EQ(s["hold"]["cause"], "operator_pause");
  EXPECT_FALSE(s["hold"]["cleared"].get<bool>());
  EXPECT_EQ(s["hold"]["allowed"], nlohmann::json::array());
  const auto refused = api->state_command("srmc", {{"command", "resume"}});
  EXPECT_EQ(refused.code, "hold_not_cleared");
  EXPECT_NE(refused.message.find("paused by the operator"), std::string::npos) << refused.message;
  sensor->set_silent(false);
  steps(50);
  ASSERT_EQ(api->state_command("srmc", {{"command", "resume"}}).status, 200);
  steps(300);
  EXPECT_EQ(op()["state"], "ENABLED");
}

TEST_F(CatheterTest, ASilentDeflectionSensorHoldsTheRobotUntilItReadsAgain) {
  start(free_space_srmc());
  enable();
  auto* sensor = catheter(*runtime).simulated_spring_sensor();
  ASSERT_NE(sensor, nullptr);
  sensor->set_silent(true);
  ASSERT_TRUE(step_until([&] { return op()["state"] == "PAUSED"; }, 300)) << op().dump();
  EXPECT_EQ(op()["hold_reason"], "sensor stream stale");
  EXPECT_TRUE(op()["spring_deflection_mm"].is_null());
  EXPECT_EQ(api->mode("srmc", {{"mode", "active_compliance"}}).status, 409);
  auto s = op();
  EXPECT_EQ(s["hold"]["cause"], "sensor_stale");
  EXPECT_FALSE(s["hold"]["cleared"].get<bool>());
  EXPECT_NE(s["hold"]["next"].get<std::string>().find("0x31"), std::string::npos) << s["hold"].dump();
  // Resume is refused while the sensor is silent (it would hold again at once); withdrawal works.
  const auto refused = api->state_command("srmc", {{"command", "resume"}});
  EXPECT_EQ(refused.status, 409);
  EXPECT_EQ(refused.code, "hold_not_cleared");
  EXPECT_NE(refused.message.find("no valid spring-deflection reading"), std::string::npos) << refused.message;
  EXPECT_EQ(api->state_command("srmc", {{"command", "relax"}}).code, "sensor_stale");
  const double q1 = setpoint()[0];
  for (int t = 0; t < 500; t += 20) {
    ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {-2.0, 0.0, 0.0, 0.0}}}).status, 200);
    steps(20);
  }
  EXPECT_LT(setpoint()[0], q1 - 0.5);
  // The sensor reads again: the hold has cleared, resume works and the robot stays ENABLED.
  sensor->set_silent(false);
  steps(50);
  s = op();
  EXPECT_TRUE(s["hold"]["cleared"].get<bool>()) << s["hold"].dump();
  EXPECT_EQ(s["hold"]["allowed"], nlohmann::json({"resume", "withdraw"}));
  ASSERT_EQ(api->state_command("srmc", {{"command", "resume"}}).status, 200);
  steps(300);
  EXPECT_EQ(op()["state"], "ENABLED");
}

// Every other way the robot holds, with its way out: an operator's pause (resume), a servo stream
// that stops (the setpoint holds, ENABLED; a new stream moves again) and a lost operator connection
// (the same).
TEST_F(CatheterTest, EveryOtherHoldHasAWayOut) {
  start(free_space_srmc());
  enable();
  ASSERT_EQ(api->state_command("srmc", {{"command", "pause"}}).status, 200);
  steps(5);
  auto s = op();
  EXPECT_EQ(s["state"], "PAUSED");
  EXPECT_EQ(s["hold"]["cause"], "operator_pause");
  EXPECT_EQ(s["hold"]["allowed"], nlohmann::json({"resume"}));
  EXPECT_EQ(api->servo_jv("srmc", {{"velocity", {1.0, 0.0, 0.0, 0.0}}}).status, 409);
  ASSERT_EQ(api->state_command("srmc", {{"command", "resume"}}).status, 200);
  steps(5);
  EXPECT_EQ(op()["state"], "ENABLED");
  EXPECT_TRUE(op()["hold"].is_null());

  // Servo command timeout: a hold of the stream, not of the robot.
  const double q0 = setpoint()[0];
  for (int t = 0; t < 200; t += 20) {
    ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {2.0, 0.0, 0.0, 0.0}}}).status, 200);
    steps(20);
  }
  steps(400);  // the stream stopped: the setpoint holds after the 150 ms timeout
  const double held = setpoint()[0];
  EXPECT_GT(held, q0 + 0.3);
  steps(200);
  EXPECT_NEAR(setpoint()[0], held, 1e-9);
  EXPECT_EQ(op()["state"], "ENABLED");
  bool timeout_logged = false;
  for (const auto& e : api->faults(50))
    timeout_logged = timeout_logged || (e["kind"] == "hold" && e["code"] == "servo command timeout");
  EXPECT_TRUE(timeout_logged);
  for (int t = 0; t < 200; t += 20) {  // the way out: stream again
    ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {2.0, 0.0, 0.0, 0.0}}}).status, 200);
    steps(20);
  }
  EXPECT_GT(setpoint()[0], held + 0.3);

  // The operator's connection goes: the stream stops at once; commands work again afterwards.
  api->operator_lost("srmc");
  steps(5);
  const double lost = setpoint()[0];
  steps(100);
  EXPECT_NEAR(setpoint()[0], lost, 1e-9);
  ASSERT_EQ(api->servo_jv("srmc", {{"velocity", {-2.0, 0.0, 0.0, 0.0}}}).status, 200);
  steps(50);
  EXPECT_LT(setpoint()[0], lost - 0.05);
}

}  // namespace
}  // namespace tendril::server
