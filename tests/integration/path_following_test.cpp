// Path following in stepped simulated time over the virtual bus: a plan is loaded (checked against
// the joint limits), the mode switches only while holding, and the robot steps through the plan with
// quintic moves that never make the setpoint jump. Also: the shipped sample vessel is what
// make_synthetic_vessel writes, and a plan of it runs through PlanningService.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <thread>
#include <vector>

#include "json_api.hpp"
#include "steerable_catheter/planning_service.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {
namespace {

const std::filesystem::path kSource(TENDRIL_SOURCE_DIR);
const std::filesystem::path kSrmc = kSource / "config/robots/srmc.json";
const std::filesystem::path kIca = kSource / "config/vessels/synthetic_ica.csv";

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The mounted catheter's design as srmc.json gives it (and GET /robots): a plan carries the design it
// was made for.
nlohmann::json srmc_design() {
  return {{"L1", 22.0}, {"L2", 18.8}, {"k1", 0.0882}, {"k2", 0.238}, {"delta2", -0.76}};
}

// Five steps inside the limits, starting where the simulated robot starts (insertion 10 mm).
nlohmann::json inline_plan() {
  auto steps = nlohmann::json::array();
  for (int k = 0; k < 5; ++k) steps.push_back({{"q", {10.0 + 3.0 * k, 0.1 * k, 0.5 * k, -0.3 * k}}});
  return {{"design", srmc_design()}, {"steps", steps}};
}

class PathFollowingTest : public ::testing::Test {
 protected:
  void SetUp() override {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    config = load_robot_config(kSrmc);
    config.settings["catheter"]["simulation"].erase(
        "vessel");  // free space: these bends would touch the wall
    runtime = std::make_unique<RobotRuntime>(std::vector<RobotConfig>{config}, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(10);
  }
  void TearDown() override { runtime->stop(); }

  // Steps while recording the largest per-tick setpoint change of each joint.
  void steps(int n) {
    for (int i = 0; i < n; ++i) {
      const auto before = setpoint();
      runtime->step();
      const auto after = setpoint();
      for (std::size_t j = 0; j < after.size(); ++j)
        max_step[j] = std::max(max_step[j], std::abs(after[j] - before[j]));
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
  nlohmann::json status() { return api->path_following("srmc").body; }
  nlohmann::json op() { return api->operating_state("srmc").body; }
  void enable() {
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
  }
  // Waits until the robot holds again after a move.
  bool settle() {
    return step_until([&] { return !status()["moving"].get<bool>(); }, 20000);
  }

  RobotConfig config;
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
  std::array<double, 4> max_step{};
};

TEST_F(PathFollowingTest, ModeSwitchNeedsALoadedPlan) {
  EXPECT_EQ(op()["mode"], "joint");
  const auto refused = api->mode("srmc", {{"mode", "path_following"}});
  EXPECT_EQ(refused.status, 409);
  EXPECT_EQ(refused.code, "no_plan");
  EXPECT_NE(refused.message.find("load one first"), std::string::npos) << refused.message;
  EXPECT_EQ(api->mode("srmc", {{"mode", "cartesian"}}).status, 422);
  const auto robots = api->robots();
  EXPECT_EQ(robots[0]["modes"], nlohmann::json({"joint", "configuration", "active_compliance",
                                                "telemanipulation", "image_guided", "path_following"}));
}

TEST_F(PathFollowingTest, LoadRejectsAStepOutsideTheJointLimitsNamingIt) {
  auto plan = inline_plan();
  plan["steps"][3]["q"][2] = 12.0;  // proximal_bend upper limit is 10 mm
  const auto r = api->load_path("srmc", plan, "");
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "out_of_limits");
  EXPECT_EQ(r.message.rfind("step 3: ", 0), 0u) << r.message;
  EXPECT_FALSE(status()["loaded"].get<bool>());
  plan["steps"][1]["q"] = {1, 2, 3};
  EXPECT_EQ(api->load_path("srmc", plan, "").status, 422);  // wrong size
  EXPECT_EQ(api->load_path("srmc", {{"steps", nlohmann::json::array()}}, "").status, 400);
}

// Issue 31: a plan made for another catheter (the design optimiser's 5/5 mm segments) is refused naming
// both designs, and so is a plan that does not say its catheter; nothing is loaded.
TEST_F(PathFollowingTest, LoadRefusesAPlanForAnotherCatheterNamingBothDesigns) {
  auto plan = inline_plan();
  plan["design"]["L1"] = 5.0;
  plan["design"]["L2"] = 5.0;
  auto r = api->load_path("srmc", plan, "j7");
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "other_catheter");
  EXPECT_NE(r.message.find("segments of 5 and 5 mm; the mounted catheter has segments of 22 and 18.8 mm"),
            std::string::npos)
      << r.message;
  EXPECT_FALSE(status()["loaded"].get<bool>());

  plan = inline_plan();
  plan.erase("design");
  r = api->load_path("srmc", plan, "");
  EXPECT_EQ(r.status, 422);
  EXPECT_EQ(r.code, "no_design");
  EXPECT_NE(r.message.find("does not say which catheter it was made for"), std::string::npos) << r.message;
  EXPECT_FALSE(status()["loaded"].get<bool>());

  // The design as GET /robots gives it is the mounted one: loaded.
  plan = inline_plan();
  plan["design"] = api->robots()[0]["design"];
  EXPECT_EQ(api->load_path("srmc", plan, "").status, 200);
  EXPECT_TRUE(status()["loaded"].get<bool>());
}

TEST_F(PathFollowingTest, SwitchesOnlyWhileHoldingAndStepsThroughThePlanWithoutASetpointJump) {
  enable();
  ASSERT_EQ(api->load_path("srmc", inline_plan(), "j1").status, 200);
  EXPECT_EQ(status()["loaded"], true);
  EXPECT_EQ(status()["steps"], 5);
  EXPECT_EQ(status()["step"], -1);
  EXPECT_EQ(status()["plan"], "j1");

  // Moving: refused, with the reason.
  ASSERT_EQ(api->move_jp("srmc", {{"goal", {12.0, 0.0, 0.0, 0.0}}}).status, 202);
  steps(5);
  const auto moving = api->mode("srmc", {{"mode", "path_following"}});
  EXPECT_EQ(moving.status, 409);
  EXPECT_EQ(moving.code, "not_holding");
  EXPECT_NE(moving.message.find("moving"), std::string::npos);
  ASSERT_TRUE(settle());

  // Holding: the switch leaves the setpoint where it is.
  const auto before = setpoint();
  ASSERT_EQ(api->mode("srmc", {{"mode", "path_following"}}).status, 200);
  steps(2);
  EXPECT_EQ(op()["mode"], "path_following");
  EXPECT_EQ(setpoint(), before);

  // Joint commands are refused in path following.
  EXPECT_EQ(api->move_jp("srmc", {{"goal", {12.0, 0.0, 0.0, 0.0}}}).code, "wrong_mode");
  EXPECT_EQ(api->servo_jv("srmc", {{"velocity", {0.1, 0.0, 0.0, 0.0}}}).code, "wrong_mode");

  max_step = {};
  const auto plan = inline_plan();
  for (int k = 0; k < 5; ++k) {
    const auto r = api->path_step("srmc", {{"advance", 1}});
    ASSERT_EQ(r.status, 202) << r.message;
    EXPECT_EQ(r.body["step"], k);
    EXPECT_GT(r.body["duration_s"].get<double>(), 0.0);
    steps(3);
    if (k > 0) {
      // Still moving: a second step is refused until it holds.
      const auto busy = api->path_step("srmc", {{"advance", 1}});
      EXPECT_EQ(busy.status, 409);
      EXPECT_EQ(busy.code, "not_holding");
    }
    ASSERT_TRUE(settle());
    EXPECT_EQ(status()["step"], k);
    const auto sp = setpoint();
    for (std::size_t j = 0; j < 4; ++j) EXPECT_NEAR(sp[j], plan["steps"][k]["q"][j].get<double>(), 1e-6);
  }
  // Per tick the setpoint moves at most max_velocity · dt (no jump anywhere on the way).
  for (std::size_t j = 0; j < 4; ++j)
    EXPECT_LE(max_step[j], config.joints[j].limit.max_velocity * 0.001 * 1.01) << config.joints[j].name();

  const auto end = api->path_step("srmc", {{"advance", 1}});
  EXPECT_EQ(end.status, 409);
  EXPECT_EQ(end.code, "end_of_plan");
  EXPECT_EQ(api->path_step("srmc", {{"step", 7}}).status, 422);
  EXPECT_EQ(api->path_step("srmc", {{"step", 1}}).status, 202);  // back, by index
  steps(2);  // the command reaches the control thread on its next tick
  ASSERT_TRUE(settle());
  EXPECT_EQ(status()["step"], 1);

  // Back to joint mode while holding.
  ASSERT_EQ(api->mode("srmc", {{"mode", "joint"}}).status, 200);
  steps(2);
  EXPECT_EQ(op()["mode"], "joint");
  EXPECT_EQ(api->path_step("srmc", {{"advance", 1}}).code, "wrong_mode");
}

TEST_F(PathFollowingTest, StepsNeedAnEnabledRobotAndSwitchesAreRefusedUnderEstop) {
  ASSERT_EQ(api->load_path("srmc", inline_plan(), "").status, 200);
  ASSERT_EQ(api->mode("srmc", {{"mode", "path_following"}}).status, 200);  // disabled, holding
  steps(2);
  const auto disabled = api->path_step("srmc", {{"step", 0}});
  EXPECT_EQ(disabled.status, 409);
  EXPECT_EQ(disabled.code, "not_enabled");
  api->estop();
  steps(3);
  const auto estop = api->mode("srmc", {{"mode", "joint"}});
  EXPECT_EQ(estop.status, 409);
  EXPECT_EQ(estop.code, "estop_latched");
}

TEST_F(PathFollowingTest, APauseMidStepLeavesTheLastReachedStep) {
  enable();
  ASSERT_EQ(api->load_path("srmc", inline_plan(), "").status, 200);
  ASSERT_EQ(api->mode("srmc", {{"mode", "path_following"}}).status, 200);
  steps(2);
  ASSERT_EQ(api->path_step("srmc", {{"step", 0}}).status, 202);
  steps(2);
  ASSERT_TRUE(settle());
  ASSERT_EQ(api->path_step("srmc", {{"step", 4}}).status, 202);
  steps(100);
  ASSERT_EQ(api->state_command("srmc", {{"command", "pause"}}).status, 200);
  steps(5);
  EXPECT_EQ(status()["step"], 0);
  EXPECT_EQ(status()["target"], 0);
}

TEST(SampleVessel, TheShippedFileIsTheSyntheticIcaOfSeed7) {
  const auto shipped = teleop::parse_centerline_csv(read_file(kIca));
  ASSERT_EQ(shipped.size(), 1u);
  teleop::SyntheticIcaOptions o;
  o.point_spacing = 0.2;
  const auto ica = teleop::make_synthetic_ica(7, o);
  ASSERT_EQ(shipped[0].points.size(), ica.points.size());
  for (std::size_t i = 0; i < ica.points.size(); ++i) {
    EXPECT_LE((shipped[0].points[i] - ica.points[i]).norm(), 1e-3) << "point " << i;
    EXPECT_NEAR(shipped[0].radii[i], ica.radii[i], 1e-4);
  }
}

TEST(PlanningServiceOnTheSampleVessel, PlansWithinTheJointLimitsAndTheRuntimeLoadsThePlan) {
  const auto config = load_robot_config(kSrmc);
  PlanningService planning({config});
  const auto csv = read_file(kIca);
  const auto start = std::chrono::steady_clock::now();
  const auto job =
      planning.submit_plan_file(csv, "text/csv", {{"robot", "srmc"}, {"ds", "0.5"}, {"dq1", "3"}});
  ASSERT_EQ(job.status, 202) << job.message;
  const auto id = job.body["id"].get<std::string>();
  nlohmann::json state;
  for (int i = 0; i < 1200; ++i) {  // up to 2 minutes on a loaded machine
    state = planning.job(id).body;
    if (state["state"] != "queued" && state["state"] != "running") break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(state["state"], "succeeded") << state["message"];
  const auto& result = state["result"];
  std::cout << "[ plan ] synthetic ICA: " << result["steps"].size() << " steps, mean position error "
            << result["summary"]["mean_position_error_mm"] << " mm, compute "
            << result["summary"]["compute_s"] << " s, job " << seconds << " s\n";
  EXPECT_TRUE(result["truncated_to_insertion_range"].get<bool>());  // 150 mm vessel, 120 mm insertion
  EXPECT_LE(result["planned_length_mm"].get<double>(), 119.5 + 1e-9);
  ASSERT_FALSE(result["steps"].empty());
  EXPECT_FALSE(result["steps"][0]["backbone"].empty());
  EXPECT_EQ(state["progress"], 1.0);

  RuntimeOptions o;
  o.stepped = true;
  RobotRuntime runtime({config}, o, builtin_robot_types());
  runtime.start();
  const auto loaded = json_api(runtime)->load_path("srmc", result, id);
  if (result["within_joint_limits"].get<bool>()) {
    EXPECT_EQ(loaded.status, 200) << loaded.message;
  } else {
    // The planner does not bound the roll; the load must then name the step that is out of range.
    EXPECT_EQ(loaded.status, 422);
    EXPECT_NE(loaded.message.find("step "), std::string::npos);
  }
  runtime.stop();

  // Unknown job, design of a bad vessel id, bad parameters.
  EXPECT_EQ(planning.job("j999").status, 404);
  EXPECT_EQ(planning.submit_plan({{"vessel", "v999"}}).status, 404);
  EXPECT_EQ(planning.submit_plan_file(csv, "text/csv", {{"ds", "abc"}}).status, 400);
  EXPECT_EQ(planning.submit_plan_file(csv, "text/csv", {{"dq1", "0"}}).status, 422);
  EXPECT_EQ(planning.submit_plan_file("", "text/csv", {}).code, "bad_vessel");
  // The reader names the format and line once (it used to read "centerline CSV: centerline CSV line 2").
  const auto bad_line = planning.upload_vessel("0,0,0\n0,0,x\n", "text/csv", {});
  EXPECT_EQ(bad_line.code, "bad_vessel");
  EXPECT_EQ(bad_line.message.rfind("centerline CSV line 2: ", 0), 0u) << bad_line.message;
  EXPECT_EQ(bad_line.message.find("centerline CSV", 1), std::string::npos) << bad_line.message;
  const auto bad_stl = planning.upload_vessel(std::string(84, '\0'), "model/stl", {});
  EXPECT_EQ(bad_stl.code, "bad_vessel");
  EXPECT_EQ(bad_stl.message.find("STL", bad_stl.message.find("STL") + 1), std::string::npos)
      << bad_stl.message;
  EXPECT_EQ(planning.upload_vessel(csv, "application/pdf", {}).status, 415);
}

// CSV text of a synthetic ICA with a point every `spacing` mm (x,y,z,radius).
std::string ica_csv(double spacing, std::size_t* points = nullptr) {
  teleop::SyntheticIcaOptions o;
  o.point_spacing = spacing;
  const auto ica = teleop::make_synthetic_ica(3, o);
  if (points != nullptr) *points = ica.points.size();
  std::ostringstream csv;
  csv.precision(9);
  for (std::size_t i = 0; i < ica.points.size(); ++i)
    csv << ica.points[i].x() << ',' << ica.points[i].y() << ',' << ica.points[i].z() << ',' << ica.radii[i]
        << '\n';
  return csv.str();
}

// The vessel store is bounded by count and by the memory of the centerlines it keeps (issue 30: a
// 28.6 MiB upload kept 148 MB, 16 of them about 2.4 GB); the oldest upload is forgotten first.
TEST(PlanningServiceVesselStore, KeepsVesselsWithinACountAndAByteBudgetOldestFirst) {
  std::size_t points = 0;
  const auto csv = ica_csv(0.01, &points);  // 15 000 points
  PlanningOptions options;
  options.max_vessels = 3;
  // Room for two of these vessels: 32 bytes a point (x, y, z, radius as doubles) and a little more.
  options.max_stored_vessel_bytes = 2 * points * 32 + 16 * 1024;
  PlanningService planning({load_robot_config(kSrmc)}, options);

  const auto first = planning.upload_vessel(csv, "text/csv", {{"name", "first"}});
  ASSERT_EQ(first.status, 201) << first.message;
  // What is kept is the centerline itself: no spare vector capacity, nothing of the file's text.
  const auto bytes = first.body["stored_bytes"].get<std::size_t>();
  std::cout << "[ store ] " << csv.size() << " bytes of CSV, " << points << " points: " << bytes
            << " bytes kept\n";
  EXPECT_GE(bytes, points * 32);
  EXPECT_LE(bytes, points * 32 + 4096);
  EXPECT_EQ(first.body["store"]["vessels"], 1);
  EXPECT_EQ(first.body["store"]["max_vessels"], 3);
  EXPECT_EQ(first.body["store"]["bytes"], bytes);
  EXPECT_EQ(first.body["store"]["max_bytes"], options.max_stored_vessel_bytes);
  EXPECT_NE(first.body["store"]["policy"].get<std::string>().find("oldest"), std::string::npos);

  const auto second = planning.upload_vessel(csv, "text/csv", {});
  ASSERT_EQ(second.status, 201) << second.message;
  EXPECT_EQ(second.body["store"]["forgotten"], nlohmann::json::array());
  // A third would pass the byte budget (not the count): the first is forgotten.
  const auto third = planning.upload_vessel(csv, "text/csv", {});
  ASSERT_EQ(third.status, 201) << third.message;
  EXPECT_EQ(third.body["store"]["forgotten"], nlohmann::json::array({first.body["id"]}));
  EXPECT_EQ(third.body["store"]["vessels"], 2);
  EXPECT_LE(third.body["store"]["bytes"].get<std::size_t>(), options.max_stored_vessel_bytes);
  EXPECT_EQ(planning.vessel(first.body["id"].get<std::string>(), {}).status, 404);
  EXPECT_EQ(planning.vessel(second.body["id"].get<std::string>(), {}).status, 200);
  EXPECT_EQ(planning.vessels().body.size(), 2u);

  // Small vessels: the count decides.
  const auto small = ica_csv(0.5);
  ASSERT_EQ(planning.delete_vessel(second.body["id"].get<std::string>()).status, 200);
  const auto after_delete = planning.upload_vessel(small, "text/csv", {});
  ASSERT_EQ(after_delete.status, 201);
  EXPECT_EQ(after_delete.body["store"]["vessels"], 2);
  EXPECT_EQ(after_delete.body["store"]["bytes"],
            bytes + after_delete.body["stored_bytes"].get<std::size_t>());
  ASSERT_EQ(planning.upload_vessel(small, "text/csv", {}).status, 201);
  const auto over_count = planning.upload_vessel(small, "text/csv", {});
  EXPECT_EQ(over_count.body["store"]["forgotten"], nlohmann::json::array({third.body["id"]}));
  EXPECT_EQ(over_count.body["store"]["vessels"], 3);

  // One vessel larger than the whole budget is refused, saying both sizes.
  const auto too_large = planning.upload_vessel(ica_csv(0.002), "text/csv", {});
  EXPECT_EQ(too_large.status, 413);
  EXPECT_EQ(too_large.code, "vessel_too_large");
  EXPECT_NE(too_large.message.find("MiB in memory"), std::string::npos) << too_large.message;
  EXPECT_EQ(planning.vessels().body.size(), 3u);  // nothing was forgotten for it
}

TEST(PlanningServiceVesselStore, RefusesAFileOfMoreBranchesThanAVesselHas) {
  PlanningOptions options;
  options.max_vessel_branches = 10;
  PlanningService planning({load_robot_config(kSrmc)}, options);
  // Short straight pieces 50 mm apart: each is a branch.
  const auto pieces = [](int count) {
    std::ostringstream csv;
    for (int b = 0; b < count; ++b)
      for (int i = 0; i < 4; ++i) csv << 50 * b << ",0," << i << '\n';
    return csv.str();
  };
  const auto ten = planning.upload_vessel(pieces(10), "text/csv", {});
  ASSERT_EQ(ten.status, 201) << ten.message;
  EXPECT_EQ(ten.body["branches"].size(), 10u);
  const auto eleven = planning.upload_vessel(pieces(11), "text/csv", {});
  EXPECT_EQ(eleven.code, "bad_vessel");
  EXPECT_NE(eleven.message.find("splits into 11 branches"), std::string::npos) << eleven.message;
  EXPECT_NE(eleven.message.find("at most 10"), std::string::npos) << eleven.message;
}

// POST /designs with flexure: the design job reports how the optimiser converged, and the flexure
// design is no worse than the best design without it (issue 15).
TEST(PlanningServiceOnTheSampleVessel, DesignJobReportsConvergence) {
  PlanningService planning({load_robot_config(kSrmc)});
  const auto vessel = planning.upload_vessel(read_file(kIca), "text/csv", {});
  ASSERT_EQ(vessel.status, 201) << vessel.message;
  // ds 2 / dq1 6 keep the job to seconds under the sanitizers.
  const auto job = planning.submit_design(
      {{"vessel", vessel.body["id"]}, {"branch", 0}, {"flexure", true}, {"ds", 2.0}, {"dq1", 6.0}});
  ASSERT_EQ(job.status, 202) << job.message;
  const auto id = job.body["id"].get<std::string>();
  nlohmann::json state;
  for (int i = 0; i < 1200; ++i) {
    state = planning.job(id).body;
    if (state["state"] != "queued" && state["state"] != "running") break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ(state["state"], "succeeded") << state["message"];
  const auto& result = state["result"];
  const auto& c = result["convergence"];
  std::cout << "[ design ] g " << result["initial_penalty"] << " -> " << result["penalty"] << ", "
            << c["stop_reason"] << ", subset g " << c["subset_penalty"] << "\n";
  EXPECT_LT(result["penalty"].get<double>(), result["initial_penalty"].get<double>());
  EXPECT_LE(result["penalty"].get<double>(), c["subset_penalty"].get<double>());
  EXPECT_TRUE(c["stop_reason"].is_string());
  EXPECT_TRUE(c["converged"].is_boolean());
  EXPECT_TRUE(c["flexure_improved"].is_boolean());
  EXPECT_GE(c["local_runs"].get<int>(), 2);
  const auto history = c["best_penalty_history"].get<std::vector<double>>();
  ASSERT_FALSE(history.empty());
  EXPECT_TRUE(std::is_sorted(history.rbegin(), history.rend()));
  EXPECT_GE(result["summary"]["max_tip_error_mm"].get<double>(),
            result["summary"]["mean_tip_error_mm"].get<double>());
  EXPECT_TRUE(result["design"]["flexure"].get<bool>());
}

}  // namespace
}  // namespace tendril::server
