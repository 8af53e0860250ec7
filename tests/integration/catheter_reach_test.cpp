// The shipped catheter in the shipped scene (issue 31, item 6): a surgeon reaches the vessel's target in
// the configuration, path-following and image-guided modes, in stepped time over the virtual bus, with
// the SIMULATED plant in the scene's vessel. The passive shaft lies along the vessel (vessel_shaft.hpp);
// with the shaft kept straight (before issue 31) every mode was held by the wall a third of the way in.
// Each test prints how far the catheter got and its tip's distance from the target.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <thread>

#include "json_api.hpp"
#include "steerable_catheter/planning_service.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/image_feedback.hpp"
#include "tendril/server/imaging_worker.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config";
// Reached: the tip within this distance of the target (about the vessel's radius there).
constexpr double kReachedMm = 2.5;

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The scene's vessel file (TENDRIL_REACH_VESSEL: another, for trying scenes).
std::filesystem::path scene_file() {
  if (const char* other = std::getenv("TENDRIL_REACH_VESSEL")) return other;
  const auto server = load_server_config(kConfig / "server.json");
  return kConfig / server.scene.at("vessel").get<std::string>();
}

// The plan a surgeon makes in the console's Plan tab for the mounted catheter (its design, ds 0.5 mm,
// dq1 3 mm), on the scene's vessel file; made once.
const nlohmann::json& shipped_plan() {
  static const nlohmann::json plan = [] {
    const auto server = load_server_config(kConfig / "server.json");
    PlanningService planning(server.robots);
    const auto csv = read_file(scene_file());
    const auto job =
        planning.submit_plan_file(csv, "text/csv", {{"robot", "srmc"}, {"ds", "0.5"}, {"dq1", "3"}});
    if (job.status != 202) throw std::runtime_error(job.message);
    const auto id = job.body["id"].get<std::string>();
    for (int i = 0; i < 2400; ++i) {
      const auto state = planning.job(id).body;
      if (state["state"] == "succeeded") {
        const auto& r = state["result"];
        std::cout << "[ plan ] " << r["steps"].size() << " steps to " << r["planned_length_mm"] << " of "
                  << r["vessel_length_mm"] << " mm, position error mean "
                  << r["summary"]["mean_position_error_mm"] << " max "
                  << r["summary"]["max_position_error_mm"] << " mm\n";
        return r;
      }
      if (state["state"] != "queued" && state["state"] != "running") throw std::runtime_error(state.dump());
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    throw std::runtime_error("plan job timed out");
  }();
  return plan;
}

class CatheterReachTest : public ::testing::Test {
 protected:
  void SetUp() override { start(false); }
  // straight_shaft: the plant of before issue 31 in the same vessel — the scene's vessel placed at the entry
  // behind its introducer, given to the robot as its own channel (a robot file's channel keeps the straight
  // axis), its lumen the widest of the scene's radii.
  void start(bool straight_shaft) {
    if (runtime) runtime->stop();
    auto server = load_server_config(kConfig / "server.json");
    auto scene_json = server.scene;
    scene_json["vessel"] = scene_file().string();
    scene = load_scene_vessel(scene_json, server.imaging, server.file);
    ASSERT_FALSE(scene.branches.empty());
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    o.scene_vessel = scene.branches;
    if (straight_shaft) {
      const auto& branch = scene.branches.front();
      Eigen::Isometry3d entry = Eigen::Isometry3d::Identity();
      entry.translation().z() = 40.8;  // L1 + L2 of the shipped catheter
      const auto placement = teleop::placement_at_entry(branch, entry);
      const auto file = std::filesystem::temp_directory_path() / "catheter_reach_straight_shaft.csv";
      std::ofstream out(file);
      out << "x,y,z\n";
      for (int i = 0; - 1.0 + 0.5 * i < 40.8; ++i) out << "0,0," << -1.0 + 0.5 * i << "\n";
      for (const auto& p : branch.points) {
        const Eigen::Vector3d q = placement * p;
        out << q.x() << "," << q.y() << "," << q.z() << "\n";
      }
      out.close();
      auto& vessel = server.robots.front().settings["catheter"]["simulation"]["vessel"];
      vessel["centerline"] = file.string();
      vessel["lumen_radius_mm"] = *std::max_element(branch.radii.begin(), branch.radii.end());
      o.scene_vessel.clear();
    }
    runtime = std::make_unique<RobotRuntime>(server.robots, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    // The target: the end of the vessel, placed at the catheter's entry as the one world places it.
    const auto entry = runtime->vessel_entry("srmc");
    ASSERT_TRUE(entry);
    const auto& branch = scene.branches.front();
    target = teleop::placement_at_entry(branch, *entry) * branch.points.back();
    steps(10);
  }
  void TearDown() override {
    if (runtime) runtime->stop();
  }
  void steps(int n) {
    for (int i = 0; i < n; ++i) {
      runtime->step();
      ++tick;
      if (imaging && tick % 67 == 0) expose();  // 15 fps
      if (servo_insertion != 0.0 && tick % 20 == 0)
        (void)api->servo_jv("srmc", {{"velocity", {servo_insertion, 0.0, 0.0, 0.0}}});
      if (tick % 20 == 0) peak = std::max(peak, op()["contact_force_n"].get<double>());
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
  nlohmann::json op() { return api->operating_state("srmc").body; }
  bool held() { return op()["state"] == "PAUSED"; }
  double insertion() { return api->measured_js("srmc").body["position"][0].get<double>(); }
  Eigen::Vector3d tip() {
    std::vector<Eigen::Vector3d> b;
    EXPECT_TRUE(catheter(*runtime).simulated_backbone(b));
    return b.empty() ? Eigen::Vector3d::Zero() : b.back();
  }
  double to_target() { return (tip() - target).norm(); }
  void enable() {
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
  }
  // The tracked tip as the bi-plane tracking reports it (0.25 mm noise per axis), at the seam.
  void expose() {
    std::normal_distribution<double> noise(0.0, 0.25);
    ImagedTip t;
    t.found = true;
    t.position = tip() + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    t.capture_ns = static_cast<std::uint64_t>(tick) * 1'000'000ULL;
    catheter(*runtime).image_feedback()->on_tip(t);
  }
  void report(const char* mode) {
    std::cout << "[ reach ] " << mode << ": insertion " << insertion() << " mm, tip " << to_target()
              << " mm from the target, peak wall force " << peak << " N, state " << op()["state"]
              << (held() ? " hold: " + op()["hold"].dump() : std::string()) << "\n";
  }

  SceneVessel scene;
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  long tick = 0;
  bool imaging = false;
  // Enables the robot, loads the plan and steps along it to its end or a hold, each step to rest.
  void follow(const nlohmann::json& plan) {
    enable();
    ASSERT_EQ(api->load_path("srmc", plan, "p").status, 200);
    ASSERT_EQ(api->mode("srmc", {{"mode", "path_following"}}).status, 200);
    steps(2);
    for (std::size_t k = 0; k < plan["steps"].size() && !held(); ++k) {
      const auto r = api->path_step("srmc", {{"advance", 1}});
      ASSERT_EQ(r.status, 202) << r.message;
      steps(3);
      ASSERT_TRUE(step_until([&] { return !api->path_following("srmc").body["moving"].get<bool>(); }, 30000));
    }
  }

  double servo_insertion = 0.0;
  double peak = 0.0;
  std::mt19937 rng{3};
};

TEST_F(CatheterReachTest, PathFollowingReachesTheTarget) {
  const auto& plan = shipped_plan();
  ASSERT_TRUE(plan["within_joint_limits"].get<bool>()) << plan["limit_violation"];
  follow(plan);
  if (HasFatalFailure()) return;
  report("path_following");
  EXPECT_FALSE(held()) << op()["hold"].dump();
  EXPECT_LT(to_target(), kReachedMm);
}

// Today's plant before issue 31 (the shaft kept straight) in the same vessel, with the same plan: the wall
// holds it, or it ends far from the target.
TEST_F(CatheterReachTest, WithTheStraightShaftOfBeforePathFollowingDoesNotReachTheTarget) {
  start(true);
  const auto& plan = shipped_plan();
  follow(plan);
  if (HasFatalFailure()) return;
  report("path_following, straight shaft (before issue 31)");
  EXPECT_TRUE(held() || to_target() > kReachedMm);
}

TEST_F(CatheterReachTest, ConfigurationModeReachesTheTarget) {
  // The surgeon commands, configuration by configuration, what the plan shows.
  const auto& plan = shipped_plan();
  enable();
  ASSERT_EQ(api->mode("srmc", {{"mode", "configuration"}}).status, 200);
  steps(2);
  for (const auto& st : plan["steps"]) {
    if (held()) break;
    const auto r = api->robot_command("srmc", "move_configuration", {{"goal", st["configuration"]}});
    ASSERT_EQ(r.status, 202) << r.message << " " << st["configuration"];
    steps(3);
    ASSERT_TRUE(step_until([&] { return !op()["is_busy"].get<bool>() || held(); }, 30000));
  }
  report("configuration");
  EXPECT_FALSE(held()) << op()["hold"].dump();
  EXPECT_LT(to_target(), kReachedMm);
}

TEST_F(CatheterReachTest, ImageGuidedModeReachesTheTarget) {
  // The surgeon inserts at 1 mm/s; roll and bends follow the replanner on the tracked tip.
  const auto& plan = shipped_plan();
  enable();
  ASSERT_EQ(api->load_path("srmc", plan, "p").status, 200);
  catheter(*runtime).image_feedback()->tracking_attached([](bool) {});
  imaging = true;
  const auto entered = api->mode("srmc", {{"mode", "image_guided"}});
  ASSERT_EQ(entered.status, 200) << entered.message;
  const double goal = plan["steps"].back()["q"][0].get<double>();
  servo_insertion = 1.0;
  step_until([&] { return insertion() >= goal || held(); }, 150000);
  servo_insertion = 0.0;
  steps(1500);
  report("image_guided");
  EXPECT_FALSE(held()) << op()["hold"].dump();
  EXPECT_LT(to_target(), kReachedMm);
}

// The shipped scene vessel is what make_synthetic_vessel --scene writes.
TEST(SceneVessel, TheShippedFileIsTheSyntheticIcaOfSeed2WithWideBends) {
  const auto shipped = teleop::parse_centerline_csv(read_file(kConfig / "vessels/scene_vessel.csv"));
  ASSERT_EQ(shipped.size(), 1u);
  teleop::SyntheticIcaOptions o;
  o.point_spacing = 0.2;
  o.length = 112.0;
  o.min_bend_radius = 25.0;
  o.max_bend_radius = 45.0;
  const auto ica = teleop::make_synthetic_ica(2, o);
  ASSERT_EQ(shipped[0].points.size(), ica.points.size());
  for (std::size_t i = 0; i < ica.points.size(); ++i) {
    EXPECT_LE((shipped[0].points[i] - ica.points[i]).norm(), 1e-3) << "point " << i;
    EXPECT_NEAR(shipped[0].radii[i], ica.radii[i], 1e-4);
  }
}

}  // namespace
}  // namespace tendril::server
