// The mbcr_vd robot type (server/src/robots/mbcr_vd) end to end through the runtime and the JSON API with
// config/robots/mbcr_vd.json: seven SIMULATED CiA 402 drives on a virtual bus, stepped simulated time
// at 1 kHz. The dissertation's circle (Abah 2022, §2.7.2) run through the plug-in with the diameter variable
// and fixed gives the library's numbers (RMS ‖τ̃_s‖ 177.7 N against 203.2 N, reduction RMS 39.8 N on the hook
// branch at 74 GPa; the dissertation's 48.3 ± 17.6 N) and the grow–shrink–grow diameter; bad goals are
// refused; an operator's motion stops before the disks must touch.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "allocation_counter.hpp"
#include "json_api.hpp"
#include "mbcr_vd/mbcr_vd_robot.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";
constexpr double kMinInnerRadius = 2.613;  // a_min (mm) of the Table 2.3 geometry

class MbcrTest : public ::testing::Test {
 protected:
  void start() {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    runtime = std::make_unique<RobotRuntime>(std::vector<RobotConfig>{config()}, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(20);
  }
  static RobotConfig config() { return load_robot_config(kConfig / "mbcr_vd.json"); }
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
  json op() { return api->operating_state("mbcr").body; }
  MbcrRobot& robot() { return dynamic_cast<MbcrRobot&>(*runtime->plugin("mbcr")); }
  void enable_task_mode() {
    ASSERT_EQ(api->state_command("mbcr", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 5000))
        << op().dump();
    const auto r = api->mode("mbcr", {{"mode", "task"}});
    ASSERT_EQ(r.status, 200) << r.message;
    steps(2);
    ASSERT_EQ(op()["mode"], "task");
  }

  struct CircleRecord {
    std::vector<double> force;     // ‖τ̃_s‖ per sample
    std::vector<double> diameter;  // a after each sample (mm)
    std::vector<double> upper;     // upper limit of a
    std::vector<bool> unavoidable;
    double rms = 0.0;
    std::uint32_t unavoidable_steps = 0;
  };
  // Runs the reference circle through the API and records it sample by sample from the published snapshot.
  CircleRecord run_circle(const std::string& diameter) {
    CircleRecord rec;
    const auto r = api->robot_command("mbcr", "trajectory",
                                      {{"action", "start"}, {"name", "seed_circle"}, {"diameter", diameter}});
    EXPECT_EQ(r.status, 202) << r.message;
    const double duration = r.body.value("duration_s", 0.0);
    EXPECT_GT(duration, 20.0);
    steps(2);
    std::uint32_t seen = 0;
    const int budget = static_cast<int>((duration + 2.0) * 1000);
    for (int i = 0; i < budget; ++i) {
      runtime->step();
      const auto s = robot().snapshot();
      if (s.motion == MbcrMotion::circle || (s.motion == MbcrMotion::none && s.circle_samples > seen)) {
        if (s.circle_samples == seen + 1) {
          rec.force.push_back(s.circle_sample_force);
          rec.diameter.push_back(s.diameter_joint);
          rec.upper.push_back(s.limits.upper);
          rec.unavoidable.push_back(s.interference_unavoidable);
          seen = s.circle_samples;
        }
      }
      if (s.motion == MbcrMotion::none && seen > 0) {
        rec.rms = s.circle_rms;
        rec.unavoidable_steps = s.circle_unavoidable_steps;
        break;
      }
    }
    return rec;
  }

  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(MbcrTest, DescribesSevenJointsInMillimetresAndATaskMode) {
  start();
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 1u);
  const auto& r = robots[0];
  EXPECT_EQ(r["kind"], "mbcr_vd");
  EXPECT_TRUE(r["cartesian"].get<bool>());
  ASSERT_EQ(r["joints"].size(), 7u);
  for (const auto& j : r["joints"]) EXPECT_EQ(j["unit"], "mm");
  EXPECT_EQ(r["modes"], json({"joint", "task"}));
  // Seven CiA 402 axes at a 5 ms SYNC on 1 Mbit/s: within the 70 % budget.
  ASSERT_EQ(r["buses"].size(), 1u);
  EXPECT_LT(r["buses"][0]["load"].get<double>(), 0.7);
  std::printf("mbcr bus %s: worst-case load %.1f %%\n", r["buses"][0]["name"].get<std::string>().c_str(),
              100.0 * r["buses"][0]["load"].get<double>());
  EXPECT_NEAR(r["mbcr"]["linkage"]["inner_radius_mm"][0].get<double>(), kMinInnerRadius, 1e-3);  // a_min
  EXPECT_NEAR(r["mbcr"]["linkage"]["inner_radius_mm"][1].get<double>(), 47.224, 1e-3);
  // Straight at start: the tip 3 × 200 mm up the base's z axis.
  const auto p = api->measured_cp("mbcr").body;
  EXPECT_NEAR(p["position"][2].get<double>(), 600.0, 0.05) << p.dump();
  EXPECT_NEAR(p["position"][0].get<double>(), 0.0, 0.05);
  const auto state = op();
  ASSERT_TRUE(state["mbcr"]["actuation"].is_object()) << state.dump();
  EXPECT_EQ(state["mbcr"]["actuation"]["backbone_forces_n"].size(), 12u);
}

TEST_F(MbcrTest, ReferenceCircleVariableDiameterLowersTheActuationForces) {
  start();
  enable_task_mode();
  const CircleRecord fixed = run_circle("fixed");
  ASSERT_EQ(op()["state"], "ENABLED") << op().dump();  // the drives followed: no tracking fault
  const CircleRecord variable = run_circle("variable");
  ASSERT_EQ(op()["state"], "ENABLED") << op().dump();
  ASSERT_EQ(fixed.force.size(), 20001u);
  ASSERT_EQ(variable.force.size(), 20001u);
  // The library's numbers (teleop/mbcr_vd/README.md, hook, 74 GPa): RMS 203.2 N fixed, 177.7 N varying.
  EXPECT_NEAR(fixed.rms, 203.2, 0.3);
  EXPECT_NEAR(variable.rms, 177.7, 0.3);
  double sum_sq = 0.0, min_reduction = 1e9;
  for (std::size_t i = 0; i < fixed.force.size(); ++i) {
    const double d = fixed.force[i] - variable.force[i];
    sum_sq += d * d;
    min_reduction = std::min(min_reduction, d);
  }
  const double reduction = std::sqrt(sum_sq / static_cast<double>(fixed.force.size()));
  EXPECT_NEAR(reduction, 39.8, 0.3);
  EXPECT_GT(reduction, 48.3 - 2 * 17.6);  // the dissertation's 48.3 ± 17.6 N, within two standard deviations
  EXPECT_LT(reduction, 48.3 + 2 * 17.6);
  EXPECT_GE(min_reduction, -1e-6);  // never worse than the fixed diameter
  // Fixed: a stays at a_min.
  for (double a : fixed.diameter) EXPECT_NEAR(a, kMinInnerRadius, 1e-3);
  // Varying: grows to ~17 mm in the first 2 s, is pushed back to a_min by the interference limit
  // through the bottom of the circle, grows again to ~28.6 mm at the end (Abah 2022, Fig. 2.12).
  double early_peak = 0.0, middle_low = 1e9;
  for (std::size_t i = 0; i < 3000; ++i) early_peak = std::max(early_peak, variable.diameter[i]);
  for (std::size_t i = 8000; i < 12000; ++i) middle_low = std::min(middle_low, variable.diameter[i]);
  EXPECT_GT(early_peak, 15.0);
  EXPECT_LT(middle_low, kMinInnerRadius + 0.1);
  EXPECT_GT(variable.diameter.back(), 25.0);
  std::printf(
      "reference circle through the plug-in: RMS fixed %.2f N, variable %.2f N, reduction RMS %.2f N; a: "
      "%.2f mm "
      "by 3 s, %.3f mm at 8-12 s, %.2f mm at the end; unavoidable interference %u / %u steps\n",
      fixed.rms, variable.rms, reduction, early_peak, middle_low, variable.diameter.back(),
      fixed.unavoidable_steps, variable.unavoidable_steps);
  // Interference: a never above the interference limit where a diameter avoids it; where none does (the
  // hook curls past 179° near the bottom), both runs report it on exactly the same steps.
  for (std::size_t i = 0; i < variable.diameter.size(); ++i)
    if (!variable.unavoidable[i]) ASSERT_LE(variable.diameter[i], variable.upper[i] + 1e-6) << "sample " << i;
  EXPECT_EQ(fixed.unavoidable_steps, variable.unavoidable_steps);
  EXPECT_NEAR(static_cast<double>(fixed.unavoidable_steps), 3597.0, 20.0);
  // The API's view of both runs.
  const auto circle = op()["mbcr"]["actuation"]["circle"];
  EXPECT_NEAR(circle["last_rms_fixed_n"].get<double>(), 203.2, 0.3);
  EXPECT_NEAR(circle["last_rms_variable_n"].get<double>(), 177.7, 0.3);
}

TEST_F(MbcrTest, BadGoalsAndCommandsAreRefused) {
  start();
  const json pose = {
      {"goal", {{"position", {0.0, 150.0, 505.0}}, {"orientation", {-0.7071068, 0.0, 0.0, 0.7071068}}}}};
  // Not in task mode yet.
  EXPECT_EQ(api->move_cp("mbcr", pose).status, 409);
  EXPECT_EQ(api->robot_command("mbcr", "trajectory", {{"action", "start"}}).status, 409);
  enable_task_mode();
  // Not finite, out of reach.
  auto r = api->move_cp("mbcr", {{"goal", {{"position", {NAN, 0.0, 500.0}}, {"orientation", {0, 0, 0, 1}}}}});
  EXPECT_GE(r.status, 400);
  r = api->move_cp("mbcr", {{"goal", {{"position", {0.0, 0.0, 900.0}}, {"orientation", {0, 0, 0, 1}}}}});
  EXPECT_EQ(r.code, "unreachable") << r.message;
  r = api->servo_cv("mbcr", {{"linear", {NAN, 0, 0}}, {"angular", {0, 0, 0}}});
  EXPECT_GE(r.status, 400);
  // Bad bodies of the type's commands.
  EXPECT_EQ(api->robot_command("mbcr", "trajectory", json::object()).status, 400);
  EXPECT_EQ(api->robot_command("mbcr", "trajectory", {{"action", "jump"}}).status, 400);
  EXPECT_EQ(api->robot_command("mbcr", "trajectory", {{"action", "start"}, {"name", "square"}}).status, 400);
  EXPECT_EQ(api->robot_command("mbcr", "trajectory", {{"action", "start"}, {"diameter", "huge"}}).status,
            400);
  EXPECT_EQ(api->robot_command("mbcr", "diameter", {{"mode", 3}}).status, 400);
  // Nothing moved.
  steps(50);
  EXPECT_EQ(op()["mbcr"]["motion"], "none");
  EXPECT_NEAR(api->measured_cp("mbcr").body["position"][2].get<double>(), 600.0, 0.1);
  // A reachable goal is taken and reached (within 1 mm).
  r = api->move_cp("mbcr", {{"goal", {{"position", {30.0, 0.0, 590.0}}, {"orientation", {0, 0, 0, 1}}}}});
  // Keeping the tip's orientation while moving sideways bends the segments both ways: reachable.
  ASSERT_EQ(r.status, 202) << r.message;
  const int budget = static_cast<int>((r.body["duration_s"].get<double>() + 6.0) * 1000);
  steps(2);
  ASSERT_TRUE(step_until([&] { return op()["mbcr"]["motion"] == "none"; }, budget)) << op().dump();
  steps(300);  // the drives settle
  const auto p = api->measured_cp("mbcr").body["position"];
  EXPECT_NEAR(p[0].get<double>(), 30.0, 1.0) << p.dump();
  EXPECT_NEAR(p[2].get<double>(), 590.0, 1.0) << p.dump();
}

TEST_F(MbcrTest, AnOperatorMotionStopsBeforeTheDisksMustTouch) {
  start();
  enable_task_mode();
  // To the circle's start on the hook branch (segments bent 46°, 87°, 131°), then stop the circle.
  auto r = api->robot_command("mbcr", "trajectory", {{"action", "start"}, {"diameter", "variable"}});
  ASSERT_EQ(r.status, 202) << r.message;
  steps(2);
  ASSERT_TRUE(step_until([&] { return op()["mbcr"]["motion"] == "circle"; }, 60000)) << op().dump();
  ASSERT_EQ(api->robot_command("mbcr", "trajectory", {{"action", "stop"}}).status, 202);
  steps(2);
  ASSERT_EQ(op()["mbcr"]["motion"], "none");
  // Straight down towards the circle's bottom, where the hook curls past 179°: the stream stops there.
  bool stopped = false;
  for (int ms = 0; ms < 9000; ms += 20) {
    r = api->servo_cv("mbcr", {{"linear", {0.0, 0.0, -20.0}}, {"angular", {0, 0, 0}}});
    ASSERT_EQ(r.status, 200) << r.message;
    for (int i = 0; i < 20; ++i) {
      runtime->step();
      ASSERT_FALSE(robot().snapshot().interference_unavoidable) << "at " << ms << " ms";
      stopped = stopped || robot().snapshot().interference_limited;
    }
  }
  EXPECT_TRUE(stopped);
  std::printf(
      "servo_cv down from the circle's top stopped at tip z = %.1f mm (the circle's bottom: 365 mm)\n",
      api->measured_cp("mbcr").body["position"][2].get<double>());
  EXPECT_EQ(op()["state"], "ENABLED") << op().dump();
}

TEST_F(MbcrTest, BadRobotFilesAreRefusedNamingTheKey) {
  RuntimeOptions o;
  o.stepped = true;
  o.control_rate_hz = 1000;
  const auto refused = [&](RobotConfig c) -> std::string {
    try {
      RobotRuntime r({std::move(c)}, o, builtin_robot_types());
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  };
  // The diameter joint's range must contain the linkage's [2.613, 47.224] mm.
  auto c = config();
  c.joints[6].limit.lower = 5.0;
  EXPECT_NE(refused(c).find("joints[6]"), std::string::npos) << refused(c);
  EXPECT_NE(refused(c).find("2.613"), std::string::npos) << refused(c);
  c = config();
  c.joints.pop_back();
  EXPECT_NE(refused(c).find("expected 7 joints"), std::string::npos) << refused(c);
  c = config();
  c.settings["mbcr"]["linkage"]["hinge_diameter_mm"] = 30.0;  // no admissible range left
  EXPECT_NE(refused(c).find("mbcr"), std::string::npos) << refused(c);
}

TEST_F(MbcrTest, AFixedDiameterHoldsTheDiameterJointInTaskMode) {
  start();
  enable_task_mode();
  auto r = api->robot_command("mbcr", "diameter", {{"mode", "fixed"}});
  ASSERT_EQ(r.status, 202) << r.message;
  steps(2);
  EXPECT_EQ(op()["mbcr"]["diameter"], "fixed");
  const double a0 = robot().snapshot().diameter_joint;
  r = api->move_cp("mbcr", {{"goal", {{"position", {30.0, 0.0, 590.0}}, {"orientation", {0, 0, 0, 1}}}}});
  ASSERT_EQ(r.status, 202) << r.message;
  steps(2);
  ASSERT_TRUE(step_until([&] { return op()["mbcr"]["motion"] == "none"; }, 10000)) << op().dump();
  EXPECT_NEAR(robot().snapshot().diameter_joint, a0, 1e-9);
  EXPECT_NEAR(api->setpoint_js("mbcr").body["position"][6].get<double>(), a0, 1e-9);
  EXPECT_NEAR(api->measured_cp("mbcr").body["position"][0].get<double>(), 30.0, 1.0);
}

TEST_F(MbcrTest, JointsReadBackIntoTheSameShapeWhicheverSignTheReferenceHad) {
  start();
  const auto& model = robot().model();
  const auto& psi = robot().circle_start();  // the hook: segment 1 bent one way, 2 and 3 the other
  const double a = 10.0;
  const auto q = model.joints(psi, a);
  auto data = model.make_data();
  const Eigen::Isometry3d tip = model.tip_pose(psi, data);
  teleop::StackConfiguration negative, positive;
  negative << 1.0, 0.0, 1.0, 0.0, 1.0, 0.0;  // every Θ < 0
  positive << 2.0, 0.0, 2.0, 0.0, 2.0, 0.0;  // every Θ > 0
  for (const auto& previous : {negative, positive, psi}) {
    const auto back = configuration_from_joints(model, q.data(), previous);
    EXPECT_LT((model.joints(back, a) - q).norm(), 1e-9);
    const Eigen::Isometry3d again = model.tip_pose(back, data);
    EXPECT_LT((again.translation() - tip.translation()).norm(), 1e-9);
    EXPECT_LT((again.linear() - tip.linear()).norm(), 1e-9);
    for (Eigen::Index k = 0; k < 3; ++k)  // the sign of Θ follows the previous reference
      EXPECT_EQ(back[2 * k] > teleop::kStraightTangentAngle, previous[2 * k] > teleop::kStraightTangentAngle);
  }
}

// A control context of the test's own, to run the plug-in's controller outside the runtime's thread.
class TickContext final : public ControlContext {
 public:
  bool servo_live() const noexcept override { return false; }
  std::span<const double> servo_velocity() const noexcept override { return {}; }
  void stop_servo() noexcept override {}
  bool hold(safety::FaultCode, int, const char*) noexcept override { return false; }
  safety::FaultCode hold_cause() const noexcept override { return safety::FaultCode::kNone; }
  void setpoint_moved() noexcept override {}
};

TEST_F(MbcrTest, TheControlTickDoesNotAllocate) {
  start();  // the runtime is not stepped below: the controller runs only here
  auto& controller = robot().controller();
  std::array<double, 7> q{}, qd{}, effort{}, q_des{}, qd_des{};
  q_des[6] = q[6] = 2.663;
  safety::OperatingLimits limits;
  limits.servo_timeout_s = 0.15;
  TickContext ctx;
  ctx.n = 7;
  ctx.period = 0.001;
  ctx.state = safety::OperatingState::kEnabled;
  ctx.drives_ready = true;
  ctx.mode = kTaskMode;
  ctx.q = q;
  ctx.qd = qd;
  ctx.effort = effort;
  ctx.q_des = q_des;
  ctx.qd_des = qd_des;
  ctx.limits = &limits;
  controller.reset(ctx);
  PluginCommand start_circle;
  start_circle.id = static_cast<std::uint16_t>(MbcrCommand::circle_start);
  start_circle.flag = 1;
  const long before = tendril::testing::allocation_count.load();
  controller.apply(ctx, start_circle);
  // The approach (about 5 s) and the first 2 s of the circle, with the diameter moving.
  for (int i = 0; i < 7000; ++i) {
    ctx.t = i * ctx.period;
    controller.control(ctx);
    controller.publish(ctx);
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_EQ(robot().snapshot().motion, MbcrMotion::circle);
  EXPECT_GT(robot().snapshot().diameter_joint, 10.0);  // the tick did the work it was counted on
}

}  // namespace
}  // namespace tendril::server
