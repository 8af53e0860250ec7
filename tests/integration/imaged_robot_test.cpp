// Which robot the bi-plane imaging images (issue 31): with all five shipped robot files and no
// imaging.robot it was the first in the list (the variable-diameter robot); now it is the one that enters
// the vessel and uses the images (the catheter), the one named, or a configuration error.
#include <gtest/gtest.h>

#include <filesystem>

#include "json_api.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/image_feedback.hpp"
#include "tendril/server/imaged_robot.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kRobots = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";

struct Runtime {
  explicit Runtime(const std::vector<std::string>& files) {
    std::vector<RobotConfig> configs;
    for (const auto& f : files) {
      configs.push_back(load_robot_config(kRobots / f));
      names.push_back(configs.back().name);
    }
    RuntimeOptions o;
    o.stepped = true;
    runtime = std::make_unique<RobotRuntime>(configs, o, builtin_robot_types());
  }
  std::vector<std::string> names;
  std::unique_ptr<RobotRuntime> runtime;
};

TEST(ImagedRobot, WithAllFiveRobotsTheCatheterIsImagedNotTheFirstInTheList) {
  Runtime r({"mbcr_vd.json", "sdu_continuum.json", "ur5_arm.json", "us_arm.json", "srmc.json"});
  ASSERT_EQ(r.names.front(), "mbcr");
  EXPECT_EQ(choose_imaged_robot(*r.runtime, r.names, "", "", "server.json"), "srmc");
  // Named: that one, whatever it is; a name that is not a robot is a configuration error.
  EXPECT_EQ(choose_imaged_robot(*r.runtime, r.names, "mbcr", "", "server.json"), "mbcr");
  try {
    choose_imaged_robot(*r.runtime, r.names, "catheter", "", "server.json");
    FAIL() << "an unknown imaging.robot was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("server.json: imaging.robot: no robot named 'catheter'"),
              std::string::npos)
        << e.what();
  }
}

TEST(ImagedRobot, SeveralRobotsNoneOfWhichUsesTheImagesIsAConfigurationError) {
  Runtime r({"mbcr_vd.json", "ur5_arm.json"});
  try {
    choose_imaged_robot(*r.runtime, r.names, "", "", "server.json");
    FAIL() << "no imaged robot, yet none refused";
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("imaging.robot: 2 robots are configured (mbcr, ur5)"), std::string::npos) << m;
    EXPECT_NE(m.find("name the imaged robot in imaging.robot"), std::string::npos) << m;
  }
  // One robot: that one, as before.
  Runtime one({"ur5_arm.json"});
  EXPECT_EQ(choose_imaged_robot(*one.runtime, one.names, "", "", "server.json"), "ur5");
}

TEST(ImagedRobot, GetRobotsSaysWhetherTheCatheterIsImaged) {
  Runtime r({"srmc.json"});
  auto api = json_api(*r.runtime);
  EXPECT_EQ(api->robots()[0]["imaged"], false);
  r.runtime->plugin("srmc")->image_feedback()->tracking_attached([](bool) {});  // what ImagingWorker does
  EXPECT_EQ(api->robots()[0]["imaged"], true);
  // The mounted design, which a plan must have been made for (issue 31).
  EXPECT_EQ(api->robots()[0]["design"]["L1"], 22.0);
  EXPECT_EQ(api->robots()[0]["design"]["L2"], 18.8);
}

}  // namespace
}  // namespace tendril::server
