// One world (issue 14): the server's scene vessel (config/vessels/scene_vessel.csv since issue 31, as
// config/server.json names it) placed at the catheter's insertion point is the vessel the SIMULATED catheter
// touches, the vessel the fluoroscope images and the frame a plan is shown in. At its start pose the shipped
// catheter lies inside it; pushed straight past the vessel's first bend, it meets the wall (stepped time).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "json_api.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/imaging_worker.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config";

class OneWorldTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto server = load_server_config(kConfig / "server.json");
    scene = load_scene_vessel(server.scene, server.imaging, server.file);
    ASSERT_FALSE(scene.branches.empty()) << scene.source;
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    o.scene_vessel = scene.branches;
    runtime = std::make_unique<RobotRuntime>(server.robots, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(200);
  }
  void TearDown() override {
    if (runtime) runtime->stop();
  }
  void steps(int n) {
    for (int i = 0; i < n; ++i) runtime->step();
  }
  nlohmann::json op() { return api->operating_state("srmc").body; }

  SceneVessel scene;
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(OneWorldTest, TheShippedServerFileNamesTheSceneVesselAndTheCatheterUsesIt) {
  EXPECT_NE(scene.source.find("scene_vessel.csv"), std::string::npos) << scene.source;
  // The insertion point: where the tip is at zero insertion, L1 + L2 = 22 + 18.8 mm up the axis.
  const auto entry = runtime->vessel_entry("srmc");
  ASSERT_TRUE(entry);
  EXPECT_NEAR((entry->translation() - Eigen::Vector3d(0.0, 0.0, 40.8)).norm(), 0.0, 1e-9);
  // The touched vessel is the scene's, placed there (its start at the entry, its lumen from the file),
  // after the straight introducer up the insertion axis that reaches the entry.
  const auto& touched = catheter(*runtime).vessel();
  const auto& file_points = scene.branches.front().points;
  ASSERT_GT(touched.size(), file_points.size());
  const std::size_t lead = touched.size() - file_points.size();
  EXPECT_LE(touched.front().z(), 0.0)
      << "the introducer reaches back to the steerable base at zero insertion";
  EXPECT_NEAR(touched.front().head<2>().norm(), 0.0, 1e-9);
  const auto placement = teleop::placement_at_entry(scene.branches.front(), *entry);
  for (std::size_t i = 0; i < file_points.size(); i += 50)
    EXPECT_NEAR((touched[lead + i] - placement * file_points[i]).norm(), 0.0, 1e-9) << i;
  const auto& radii = scene.branches.front().radii;
  EXPECT_DOUBLE_EQ(catheter(*runtime).lumen_radius_mm(), *std::min_element(radii.begin(), radii.end()));
  // GET /robots says where plans (in the insertion frame) go.
  const auto robots = api->robots();
  ASSERT_TRUE(robots[0].contains("vessel_entry"));
  EXPECT_DOUBLE_EQ(robots[0]["vessel_entry"]["position"][2].get<double>(), 40.8);
}

TEST_F(OneWorldTest, AtItsStartPoseTheCatheterIsInsideTheVesselAndPushedPastTheBendItTouchesTheWall) {
  // Shipped start: insertion 10 mm, straight — the tip 10 mm into the vessel's straight first part.
  EXPECT_NEAR(api->measured_js("srmc").body["position"][0].get<double>(), 10.0, 1e-3);
  EXPECT_EQ(op()["contact_force_n"].get<double>(), 0.0) << op().dump();
  EXPECT_EQ(op()["simulation"]["peak_contact_force_n"].get<double>(), 0.0);
  // Straight on to 30 mm: the vessel turns away from the axis after about 10 mm (15 mm off it at
  // 30 mm), so the straight catheter meets the wall (and the spring or contact safety may hold it).
  ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
  for (int i = 0; i < 3000 && !op()["drives_ready"].get<bool>(); ++i) runtime->step();
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {30.0, 0.0, 0.0, 0.0}}}).status, 202);
  double peak = 0.0;
  for (int i = 0; i < 6000; ++i) {
    runtime->step();
    if (i % 50 == 0) peak = std::max(peak, op()["simulation"]["peak_contact_force_n"].get<double>());
  }
  EXPECT_GT(peak, 0.0) << op().dump();
}

}  // namespace
}  // namespace tendril::server
