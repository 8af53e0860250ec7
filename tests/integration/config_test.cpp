// Configuration validation: every mistake names the file, the key and what was expected.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";

nlohmann::json srmc() {
  std::ifstream in(kSrmc);
  return nlohmann::json::parse(in);
}

std::string error_of(const nlohmann::json& j) {
  try {
    RuntimeOptions o;
    o.stepped = true;
    RobotRuntime rt({parse_robot_config(j, "robots/test.json")}, o, builtin_robot_types());
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(Config, ShippedFilesLoad) {
  const auto sc = load_server_config(std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/server.json");
  ASSERT_EQ(sc.robots.size(), 1u);
  EXPECT_EQ(sc.robots[0].name, "srmc");
  EXPECT_EQ(sc.robots[0].joints.size(), 4u);
  EXPECT_EQ(sc.host, "127.0.0.1");
  EXPECT_EQ(sc.port, 8080);
}

TEST(Config, ErrorsNameFileKeyAndExpectation) {
  auto j = srmc();
  j["joints"][2]["upper"] = -8.0;
  const auto e = error_of(j);
  EXPECT_NE(e.find("robots/test.json"), std::string::npos) << e;
  EXPECT_NE(e.find("joints[2].upper"), std::string::npos) << e;
  EXPECT_NE(e.find("greater than lower"), std::string::npos) << e;

  j = srmc();
  j["joints"][0]["drive"]["bus"] = "can7";
  EXPECT_NE(error_of(j).find("joints[0].drive.bus"), std::string::npos);

  j = srmc();
  j["joints"][1]["drive"]["node_id"] = 1;
  EXPECT_NE(error_of(j).find("node id not used"), std::string::npos);

  j = srmc();
  j["joints"][0]["max_velocity"] = "fast";
  EXPECT_NE(error_of(j).find("joints[0].max_velocity: expected a finite number"), std::string::npos);

  j = srmc();
  j["kinematics"]["model"] = "mystery";
  EXPECT_NE(error_of(j).find("kinematics.model"), std::string::npos);

  j = srmc();
  j["joints"][3]["drive"]["counts_per_unit"] = 1000.0;
  EXPECT_NE(error_of(j).find("counts_per_unit"), std::string::npos);
}

TEST(Config, BusOverItsLoadCeilingIsRefusedWithTheNumbers) {
  auto j = srmc();
  j["buses"][0]["sync_period_us"] = 1000;  // 4 axes at 1 kHz on 1 Mbit/s: well over 70 %
  const auto e = error_of(j);
  EXPECT_NE(e.find("bus 'can0' would run at"), std::string::npos) << e;
  EXPECT_NE(e.find("over its ceiling of 70 %"), std::string::npos) << e;
  j["buses"][0]["sync_period_us"] = 2500;
  EXPECT_EQ(error_of(j), "");
}

TEST(Config, NothingAssumesFourJoints) {
  auto j = srmc();
  j["name"] = "linear_stage";
  j["kinematics"] = {{"model", "constant_curvature_catheter"}};
  // A single-joint robot needs a kinematic model of its own; the error says so.
  j["joints"] = nlohmann::json::array({srmc()["joints"][0]});
  const auto e = error_of(j);
  EXPECT_NE(e.find("needs the 4 SRMC joints"), std::string::npos) << e;
}

}  // namespace
}  // namespace tendril::server

namespace tendril::server {
namespace {

TEST(CatheterConfig, MistakesInTheCatheterSettingsNameTheKey) {
  auto j = srmc();
  j["catheter"]["simulation"]["vessel"]["lumen_radius_mm"] = 0.5;  // narrower than the 0.6 mm catheter
  auto e = error_of(j);
  EXPECT_NE(e.find("catheter.simulation.vessel.lumen_radius_mm"), std::string::npos) << e;
  EXPECT_NE(e.find("wider than the catheter"), std::string::npos) << e;

  j = srmc();
  j["catheter"]["active_compliance"]["max_deflection_mm"] = 2.0;  // beyond the 1.5 mm hold bound
  e = error_of(j);
  EXPECT_NE(e.find("catheter.active_compliance.max_deflection_mm"), std::string::npos) << e;

  j = srmc();
  j["catheter"]["telemanipulation"]["max_speed"] = {3.0, 0.5, 1.0};
  EXPECT_NE(error_of(j).find("catheter.telemanipulation.max_speed: expected 4 speeds"), std::string::npos);

  j = srmc();
  j["catheter"]["telemanipulation"]["max_speed"] = {30.0, 0.5, 1.0, 1.0};  // insertion limit is 10 mm/s
  EXPECT_NE(error_of(j).find("max_velocity"), std::string::npos);

  j = srmc();
  j["catheter"]["spring_deflection"]["limit_mm"] = 6.0;  // 3 V off centre: the potentiometer cannot read it
  EXPECT_NE(error_of(j).find("catheter.spring_deflection.limit_mm"), std::string::npos);

  j = srmc();
  j["catheter"]["joysticks"]["analog"]["node_id"] = 49;  // the deflection sensor's node
  EXPECT_NE(error_of(j).find("catheter.joysticks.analog.node_id"), std::string::npos);

  j = srmc();
  j["catheter"]["joysticks"]["evdev"] = {{"device", "name:Gamepad"},
                                         {"axes", {{{"joint", "yaw"}, {"code", 0}}}}};
  EXPECT_NE(error_of(j).find("unknown: yaw"), std::string::npos) << error_of(j);

  j = srmc();
  j["catheter"]["model"]["proximal_loss"] = {0.0, 0.1};
  EXPECT_NE(error_of(j).find("catheter.model.proximal_loss"), std::string::npos);

  // A calibrated shape matrix: rows of equal length, finite, at most 6×6.
  j = srmc();
  j["catheter"]["model"]["distal_shape_matrix"] = {{1.57, 0.0}, {0.0}};
  EXPECT_NE(error_of(j).find("catheter.model.distal_shape_matrix: expected a shape matrix"),
            std::string::npos)
      << error_of(j);
  j["catheter"]["model"]["distal_shape_matrix"] = {{1.57, 0.0}, {0.0, "x"}};
  EXPECT_NE(error_of(j).find("catheter.model.distal_shape_matrix"), std::string::npos);
  j["catheter"]["model"]["distal_shape_matrix"] = {{1.57, 0.0}, {0.0, -0.07}, {0.0, 0.0}, {0.0, 0.0}};
  EXPECT_EQ(error_of(j), "");
}

}  // namespace
}  // namespace tendril::server
