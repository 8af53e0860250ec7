// Two robots on one physical CAN bus with one CANopen master (issue 13): two SIMULATED steerable
// catheters, "srmc" (drives at nodes 1-4, ADC nodes 48 and 49) and "srmc_b" (drives 5-8, ADC nodes 58
// and 59), both naming bus can0. The bus budget counts both robots' drives and sensor nodes, node ids
// are unique across the robots on the bus, and both move at once through the one master (stepped time).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <set>

#include "json_api.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

namespace co = canopen;

const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";

// The shipped catheter in free space (these bends would touch the SIMULATED vessel's wall).
nlohmann::json catheter_document() {
  auto j = read_json_file(kSrmc);
  j["catheter"]["simulation"].erase("vessel");
  return j;
}

// A second catheter on the same bus: drives 5-8, ADC nodes 58 and 59.
nlohmann::json second_catheter_document() {
  auto j = catheter_document();
  j["name"] = "srmc_b";
  for (std::size_t i = 0; i < 4; ++i) j["joints"][i]["drive"]["node_id"] = 5 + static_cast<int>(i);
  j["catheter"]["spring_deflection"]["node_id"] = 59;
  j["catheter"]["joysticks"]["analog"]["node_id"] = 58;
  return j;
}

void set_sync_period(nlohmann::json& robot, int us) { robot["buses"][0]["sync_period_us"] = us; }

RuntimeOptions stepped() {
  RuntimeOptions o;
  o.stepped = true;
  o.control_rate_hz = 1000;
  return o;
}

// The ConfigError text of building a runtime from these robot files ("" when it builds).
std::string error_of(const std::vector<nlohmann::json>& documents) {
  std::vector<RobotConfig> configs;
  for (std::size_t i = 0; i < documents.size(); ++i)
    configs.push_back(parse_robot_config(documents[i], "robots/robot" + std::to_string(i) + ".json"));
  try {
    RobotRuntime rt(std::move(configs), stepped(), builtin_robot_types());
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// The sync period at which the two catheters share can0 in the tests below. At the shipped 2500 µs one
// catheter fits the 70 % ceiling and two do not (TheBudgetCountsBothRobots).
constexpr int kSharedSyncPeriodUs = 5000;

TEST(SharedBus, TheBudgetCountsBothRobots) {
  auto a = catheter_document();
  auto b = second_catheter_document();
  ASSERT_EQ(error_of({a}), "") << "one catheter at the shipped sync period";
  ASSERT_EQ(error_of({b}), "");
  auto e = error_of({a, b});
  EXPECT_NE(e.find("robots srmc, srmc_b: buses: bus 'can0' would run at"), std::string::npos) << e;
  EXPECT_NE(e.find("8 axis"), std::string::npos) << "both robots' drives are counted: " << e;
  EXPECT_NE(e.find("over its ceiling of 70 %"), std::string::npos) << e;
  // At 4400 µs the eight drives alone fit (about 67 %), and with the four ADC nodes' PDOs they do not:
  // the robot types' own nodes count, for both robots.
  set_sync_period(a, 4400);
  set_sync_period(b, 4400);
  e = error_of({a, b});
  EXPECT_NE(e.find("srmc: 2 ADC node(s)"), std::string::npos) << e;
  EXPECT_NE(e.find("srmc_b: 2 ADC node(s)"), std::string::npos) << e;
  set_sync_period(a, kSharedSyncPeriodUs);
  set_sync_period(b, kSharedSyncPeriodUs);
  EXPECT_EQ(error_of({a, b}), "");
}

TEST(SharedBus, NodeIdsAreUniqueAcrossTheRobotsOnTheBus) {
  auto a = catheter_document();
  set_sync_period(a, kSharedSyncPeriodUs);
  auto b = second_catheter_document();
  set_sync_period(b, kSharedSyncPeriodUs);

  auto clash = b;
  clash["joints"][0]["drive"]["node_id"] = 1;  // srmc's insertion drive
  auto e = error_of({a, clash});
  EXPECT_NE(
      e.find("robots/robot1.json: joints[0].drive.node_id: node 1 on bus 'can0' is already srmc/insertion"),
      std::string::npos)
      << e;

  clash = b;
  clash["catheter"]["spring_deflection"]["node_id"] = 49;  // srmc's spring-deflection ADC
  e = error_of({a, clash});
  EXPECT_NE(e.find("robots/robot1.json: catheter.spring_deflection.node_id: node 49 on bus 'can0' is already "
                   "srmc/spring-deflection ADC"),
            std::string::npos)
      << e;

  clash = b;
  clash["catheter"]["joysticks"]["analog"]["node_id"] = 7;  // srmc_b's own proximal bend drive
  e = error_of({a, clash});
  EXPECT_NE(e.find("catheter.joysticks.analog.node_id: node 7 on bus 'can0' is already srmc_b/"),
            std::string::npos)
      << e;

  // Two buses of the same name must be the same bus.
  clash = b;
  clash["buses"][0]["bitrate"] = 500000;
  e = error_of({a, clash});
  EXPECT_NE(e.find("bus 'can0' is also configured by robots/robot0.json with other settings"),
            std::string::npos)
      << e;
}

class SharedBusTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto a = catheter_document();
    auto b = second_catheter_document();
    set_sync_period(a, kSharedSyncPeriodUs);
    set_sync_period(b, kSharedSyncPeriodUs);
    runtime = std::make_unique<RobotRuntime>(
        std::vector<RobotConfig>{parse_robot_config(a, kSrmc), parse_robot_config(b, "robots/srmc_b.json")},
        stepped(), builtin_robot_types());
    api = json_api(*runtime);
    tap = runtime->tap_bus("can0");
    ASSERT_NE(tap, nullptr);
    runtime->start();
  }
  void TearDown() override {
    if (runtime) runtime->stop();
  }

  template <typename Pred>
  bool step_until(Pred pred, int max_steps) {
    for (int i = 0; i < max_steps; ++i) {
      if (pred()) return true;
      runtime->step();
    }
    return pred();
  }
  std::string state(const std::string& robot) {
    return api->operating_state(robot).body["state"].get<std::string>();
  }
  void enable(const std::string& robot) {
    ASSERT_EQ(api->state_command(robot, {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return api->operating_state(robot).body["drives_ready"].get<bool>(); }, 3000))
        << robot << ": " << api->operating_state(robot).body.dump();
  }
  bool at(const std::string& robot, const std::vector<double>& goal, double tol) {
    const auto q = api->measured_js(robot).body["position"].get<std::vector<double>>();
    for (std::size_t i = 0; i < goal.size(); ++i)
      if (std::abs(q[i] - goal[i]) > tol) return false;
    return true;
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  std::unique_ptr<can::Bus> tap;
};

TEST_F(SharedBusTest, OneMasterSyncsTheDrivesOfBothRobots) {
  // Both robots report the one bus, with one load that counts both.
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 2u);
  double load = -1.0;
  for (const auto& r : robots) {
    ASSERT_EQ(r["buses"].size(), 1u) << r.dump();
    EXPECT_EQ(r["buses"][0]["name"], "can0");
    if (load < 0) load = r["buses"][0]["load"].get<double>();
    EXPECT_DOUBLE_EQ(r["buses"][0]["load"].get<double>(), load) << "one bus, one budget";
  }
  EXPECT_GT(load, 0.0);
  EXPECT_LE(load, 0.7);
  // Over 20 ms of stepped time: one SYNC producer (the master), TPDO1 from all eight drives and PDOs
  // from all four ADC nodes.
  while (tap->receive(std::chrono::nanoseconds(0))) {
  }
  for (int i = 0; i < 20; ++i) runtime->step();
  int syncs = 0;
  std::set<std::uint32_t> drives, adc;
  while (auto f = tap->receive(std::chrono::nanoseconds(0))) {
    if (f->id == co::cob::sync) ++syncs;
    if (f->id > co::cob::tpdo1 && f->id <= co::cob::tpdo1 + 0x7F) {
      const auto node = f->id - co::cob::tpdo1;
      (node <= 8 ? drives : adc).insert(node);
    }
  }
  // 20 ms / 5 ms: four SYNCs, or five with the phase of the first; a second master would double them.
  EXPECT_GE(syncs, 4);
  EXPECT_LE(syncs, 5) << "one master sends SYNC every " << kSharedSyncPeriodUs << " µs";
  EXPECT_EQ(drives, (std::set<std::uint32_t>{1, 2, 3, 4, 5, 6, 7, 8}));
  EXPECT_EQ(adc, (std::set<std::uint32_t>{48, 49, 58, 59}));
}

TEST_F(SharedBusTest, BothCathetersMoveAtOnceAndKeepTheirOwnState) {
  enable("srmc");
  EXPECT_EQ(state("srmc_b"), "DISABLED") << "enabling one robot leaves the other alone";
  enable("srmc_b");
  const std::vector<double> goal_a{25.0, 0.6, 3.0, -2.0};
  const std::vector<double> goal_b{18.0, -0.4, -2.0, 1.0};
  auto ra = api->move_jp("srmc", {{"goal", goal_a}});
  auto rb = api->move_jp("srmc_b", {{"goal", goal_b}});
  ASSERT_EQ(ra.status, 202) << ra.message;
  ASSERT_EQ(rb.status, 202) << rb.message;
  const double longest = std::max(ra.body["duration_s"].get<double>(), rb.body["duration_s"].get<double>());
  EXPECT_TRUE(step_until([&] { return at("srmc", goal_a, 0.01) && at("srmc_b", goal_b, 0.01); },
                         static_cast<int>(longest * 1000) + 1500))
      << api->measured_js("srmc").body.dump() << "\n"
      << api->measured_js("srmc_b").body.dump();
  // The SIMULATED loads themselves moved, each robot's own (node 3 is srmc's, node 7 srmc_b's).
  EXPECT_NEAR(runtime->simulated_drive("srmc", "proximal_bend")->truth().position, 3.0, 0.01);
  EXPECT_NEAR(runtime->simulated_drive("srmc_b", "proximal_bend")->truth().position, -2.0, 0.01);
  // Disabling one leaves the other enabled and holding where it is.
  ASSERT_EQ(api->state_command("srmc", {{"command", "disable"}}).status, 200);
  EXPECT_TRUE(step_until([&] { return state("srmc") == "DISABLED"; }, 500));
  for (int i = 0; i < 200; ++i) runtime->step();
  EXPECT_EQ(state("srmc_b"), "ENABLED");
  EXPECT_TRUE(at("srmc_b", goal_b, 0.01));
}

}  // namespace
}  // namespace tendril::server
