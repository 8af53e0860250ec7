// The us_arm's robot–world calibration (Heunis et al. 2021, §2.3) through the runtime and the
// JSON API in stepped time at 1 kHz: the routine moves the arm through its poses while the SIMULATED
// optical tracker watches the marker, the solve recovers H_B^G within the error budget, the result is
// stored and used (a restart finds it); the refusals; a tracker that goes silent ends the routine with
// the previous calibration in use; the sweep refuses without a calibration and plans after it.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "json_api.hpp"
#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "us_arm_calibrated.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";

class UsArmCalibrationTest : public ::testing::Test {
 protected:
  void TearDown() override {
    if (runtime) runtime->stop();
    runtime.reset();
  }
  void start() {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    runtime = std::make_unique<RobotRuntime>(
        std::vector<RobotConfig>{load_robot_config(kConfig / "us_arm.json")}, o, builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    steps(20);
  }
  void stop() {
    runtime->stop();
    api.reset();
    runtime.reset();
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
  json op() { return api->operating_state("us_arm").body; }
  SerialArm& arm() { return dynamic_cast<SerialArm&>(*runtime->plugin("us_arm")); }
  ApiResult calibrate(const std::string& kind = "robot") {
    return api->robot_command("us_arm", "calibrate", {{"kind", kind}});
  }
  void enable() {
    ASSERT_EQ(api->state_command("us_arm", {{"command", "enable"}}).status, 200);
    ASSERT_TRUE(
        step_until([&] { return op()["drives_ready"].get<bool>() && !op()["is_busy"].get<bool>(); }, 3000))
        << op().dump();
  }
  void mode(const std::string& m) {
    const auto r = api->mode("us_arm", {{"mode", m}});
    ASSERT_EQ(r.status, 200) << r.message;
    steps(2);
  }
  // Steps until the routine has ended (the worker solves on its own thread: give it wall time too).
  // A routine on a worker thread ("us", "catheter"): waited for in real time, the runtime stepped meanwhile.
  bool until_finished_in(double seconds) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (arm().calibrations()->running()) {
      if (std::chrono::steady_clock::now() > until) return false;
      runtime->step();
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return true;
  }
  // The image-to-probe calibration (helper uscal's N-wire routine), which the sweep also requires.
  void calibrate_image() {
    const auto r = calibrate("us");
    ASSERT_EQ(r.status, 202) << r.message;
    ASSERT_TRUE(until_finished_in(120.0)) << op()["calibration"].dump();
    ASSERT_TRUE(op()["calibration"]["last"]["ok"].get<bool>()) << op()["calibration"].dump();
  }
  bool until_finished(int max_steps) {
    return step_until(
        [&] {
          const auto c = arm().calibrations()->running();
          return !c.has_value();
        },
        max_steps);
  }
  // The calibrated H_B^G's error where the limb is (what the sweep sees of it): the limb's rest
  // origin and two points 50 mm away, mapped with the estimate against the truth.
  static double error_at_limb_mm(const Eigen::Isometry3d& estimate, const Eigen::Isometry3d& truth,
                                 const Eigen::Vector3d& limb) {
    double worst = 0;
    for (const Eigen::Vector3d& d : {Eigen::Vector3d::Zero().eval(), Eigen::Vector3d(50, 0, 0).eval(),
                                     Eigen::Vector3d(0, 50, -30).eval()})
      worst = std::max(worst, (estimate * (limb + d) - truth * (limb + d)).norm());
    return worst;
  }

  testing::ScopedStateDir state_dir_{"tendril_us_arm_calibration"};
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(UsArmCalibrationTest, DescribesItsCalibrationsAndTheSweepRefusesWithoutOne) {
  start();
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 1u);
  EXPECT_EQ(robots[0]["calibrations"]["kinds"], json({"robot", "us", "catheter"}));
  EXPECT_EQ(robots[0]["calibrations"]["required"], json({"robot", "us"}));
  EXPECT_EQ(robots[0]["calibrations"]["store"], (state_dir_.path() / "calibrations" / "us_arm").string());
  // The SIMULATED tracker's truth comes from the file's ultrasound.simulation.tracker.
  EXPECT_TRUE(
      arm().tracker_settings()->global_T_base.translation().isApprox(Eigen::Vector3d(850, -620, 540)));
  EXPECT_DOUBLE_EQ(arm().tracker_settings()->triangulation_mean_mm, 0.56);
  EXPECT_DOUBLE_EQ(arm().tracker_settings()->robot_error_mean_mm, 0.3);
  const auto c = op()["calibration"];
  EXPECT_TRUE(c["robot"].is_null());
  EXPECT_TRUE(c["running"].is_null());
  EXPECT_EQ(c["missing"], json({"robot", "us"}));
  enable();
  mode("sweep");
  const auto plan = api->robot_command("us_arm", "sweep", {{"action", "plan"}});
  EXPECT_EQ(plan.status, 409);
  EXPECT_NE(plan.message.find("no valid robot"), std::string::npos) << plan.message;
  EXPECT_NE(plan.message.find("calibrate {\"kind\":\"robot\"}"), std::string::npos) << plan.message;
  // The routine's own refusals.
  auto r = calibrate();
  EXPECT_EQ(r.status, 409);
  EXPECT_NE(r.message.find("switch to cartesian mode"), std::string::npos) << r.message;
  EXPECT_EQ(calibrate("laser").status, 400);
  EXPECT_EQ(api->robot_command("us_arm", "calibrate", {{"type", "robot"}}).status, 400);
  ASSERT_EQ(api->state_command("us_arm", {{"command", "disable"}}).status, 200);
  steps(20);
  mode("cartesian");
  r = calibrate();
  EXPECT_EQ(r.status, 409);
  EXPECT_NE(r.message.find("enable it"), std::string::npos) << r.message;
}

TEST_F(UsArmCalibrationTest, TheRoutineRecoversTheBaseInTheTrackersFrameAndTheSweepUsesIt) {
  start();
  enable();
  mode("cartesian");
  const auto r = calibrate();
  ASSERT_EQ(r.status, 202) << r.message;
  EXPECT_EQ(calibrate().status, 409);  // one at a time
  steps(200);
  EXPECT_EQ(op()["calibration"]["running"]["kind"], "robot");
  EXPECT_EQ(op()["calibration"]["running"]["steps"], 12);
  // Through the routine (simulated time until the motion has collected its pairs).
  int routine_steps = 200;
  ASSERT_TRUE(step_until(
      [&] {
        ++routine_steps;
        return arm().calibration_snapshot().phase == CalibrationPhase::collected ||
               arm().calibration_snapshot().phase == CalibrationPhase::failed;
      },
      200'000))
      << op()["calibration"].dump();
  std::printf("robot calibration: the motion took %.1f s (simulated)\n", routine_steps * 1e-3);
  ASSERT_TRUE(until_finished(5000)) << op()["calibration"].dump();
  const auto c = op()["calibration"];
  ASSERT_TRUE(c["last"]["ok"].get<bool>()) << c.dump();
  ASSERT_EQ(c["robot"]["version"], 1) << c.dump();
  EXPECT_TRUE(c["robot"]["valid"].get<bool>());
  EXPECT_EQ(c["missing"], json({"us"}));
  const auto record = arm().calibrations()->store().current("robot");
  ASSERT_TRUE(record);
  const Eigen::Isometry3d estimate = record->transforms.at("H_B^G");
  const Eigen::Isometry3d truth = arm().tracker_settings()->global_T_base;
  const Eigen::Vector3d limb = arm().ultrasound()->limb.rest_pose.translation();
  const double at_limb = error_at_limb_mm(estimate, truth, limb);
  const double rotation = Eigen::AngleAxisd(estimate.linear().transpose() * truth.linear()).angle();
  const double x_error =
      (record->transforms.at("H_U^M").translation() - arm().tracker_settings()->marker_T_probe.translation())
          .norm();
  std::printf(
      "robot calibration: %d poses, residual %.3f mm rms (max %.3f); H_B^G error at the limb %.3f mm, "
      "rotation %.4f deg, translation %.3f mm; marker->probe translation error %.3f mm\n",
      static_cast<int>(record->values.at("pairs")), record->residual_mm,
      record->residuals.at("max_mm").get<double>(), at_limb, rotation * 180.0 / M_PI,
      (estimate.translation() - truth.translation()).norm(), x_error);
  EXPECT_EQ(record->values.at("pairs"), 12.0);
  // The article's budget: robot 0.3 ± 0.1 mm, tracker 0.56 ± 0.08 mm per measurement.
  EXPECT_LT(record->residual_mm, 1.0);
  EXPECT_LT(at_limb, 2.0);
  EXPECT_TRUE(std::filesystem::exists(state_dir_.path() / "calibrations" / "us_arm" / "robot-v000001.json"));
  // The arm is back where it started, still, and enabled.
  EXPECT_EQ(op()["state"], "ENABLED");

  // With the image calibration too, the sweep plans now, and maps the tracked limb through the
  // calibrated H_B^G: the limb it sees is off the true one by the calibration's error only.
  calibrate_image();
  EXPECT_EQ(op()["calibration"]["us"]["version"], 1);
  EXPECT_EQ(op()["calibration"]["missing"], json::array());
  mode("sweep");
  const auto plan = api->robot_command("us_arm", "sweep", {{"action", "plan"}});
  ASSERT_EQ(plan.status, 200) << plan.message;
  steps(5);
  const auto p = arm().probe_state();
  const double limb_error = (p.world_T_limb.translation() - p.world_T_limb_true.translation()).norm();
  std::printf("tracked limb in the base frame vs the truth: %.3f mm\n", limb_error);
  EXPECT_LT(limb_error, 2.5);
  EXPECT_GT(limb_error, 0.0);

  // /tf: "world" is now the tracker's frame {G}; world→us_arm_base is the calibrated H_B^G.
  {
    // The arm's sources: /{robot}/force and the ultrasound topics; /tf is among the latter.
    std::shared_ptr<TopicSource> frames_source;
    for (const auto& source : arm().topic_sources())
      for (const auto& info : source->topics())
        if (info.topic == "/tf") frames_source = source;
    ASSERT_TRUE(frames_source);
    std::optional<TopicPayload> tf;
    for (int i = 0; i < 400 && !tf; ++i) {
      steps(5);
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      tf = frames_source->latest("/tf", 0);
    }
    ASSERT_TRUE(tf);
    bool found = false;
    const json frames = json::parse(*tf->payload);
    for (const auto& t : frames.at("transforms"))
      if (t.at("parent_frame_id") == "world" && t.at("child_frame_id") == "us_arm_base") {
        found = true;
        const auto& v = t.at("translation");
        EXPECT_NEAR(v.at("x").get<double>(), estimate.translation().x(), 0.01) << t.dump();
        EXPECT_NEAR(v.at("y").get<double>(), estimate.translation().y(), 0.01) << t.dump();
        EXPECT_NEAR(v.at("z").get<double>(), estimate.translation().z(), 0.01) << t.dump();
      }
    EXPECT_TRUE(found) << tf->payload->substr(0, 400);
  }

  // A restart finds version 1 and uses it.
  stop();
  start();
  const auto again = op()["calibration"];
  EXPECT_EQ(again["robot"]["version"], 1) << again.dump();
  EXPECT_EQ(again["missing"], json::array());
  enable();
  mode("sweep");
  EXPECT_EQ(api->robot_command("us_arm", "sweep", {{"action", "plan"}}).status, 200);
}

TEST_F(UsArmCalibrationTest, ASilentTrackerEndsTheRoutineAndTheArmStaysStill) {
  start();
  enable();
  mode("cartesian");
  ASSERT_EQ(calibrate().status, 202);
  ASSERT_TRUE(step_until([&] { return arm().calibration_snapshot().pose >= 2; }, 60'000))
      << op()["calibration"].dump();
  arm().set_marker_hidden(true);
  ASSERT_TRUE(
      step_until([&] { return arm().calibration_snapshot().phase == CalibrationPhase::failed; }, 500));
  ASSERT_TRUE(until_finished(2000));
  const auto c = op()["calibration"];
  EXPECT_FALSE(c["last"]["ok"].get<bool>());
  const std::string message = c["last"]["message"].get<std::string>();
  EXPECT_NE(message.find("tracker has not seen the marker"), std::string::npos) << message;
  EXPECT_NE(message.find("previous calibration stays in use"), std::string::npos) << message;
  EXPECT_TRUE(c["robot"].is_null());
  EXPECT_FALSE(arm().calibrations()->store().newest("robot"));
  // The setpoint stands still once the routine ended.
  const auto before = arm().snapshot().setpoint;
  steps(300);
  const auto after = arm().snapshot().setpoint;
  for (std::size_t i = 0; i < before.size(); ++i) EXPECT_NEAR(before[i], after[i], 1e-9);
  EXPECT_EQ(op()["state"], "ENABLED");
  arm().set_marker_hidden(false);
}

TEST_F(UsArmCalibrationTest, TheRoutineIsRefusedWhileTheSweepRuns) {
  start();
  testing::store_true_calibrations(arm());
  enable();
  mode("sweep");
  ASSERT_EQ(api->robot_command("us_arm", "sweep", {{"action", "plan"}}).status, 200);
  steps(2);
  ASSERT_EQ(api->robot_command("us_arm", "sweep", {{"action", "pre_position"}}).status, 202);
  steps(50);
  ASSERT_EQ(arm().sweep_snapshot().phase, SweepPhase::pre_positioning);
  const auto r = calibrate();
  EXPECT_EQ(r.status, 409);
  EXPECT_NE(r.message.find("the sweep is pre_positioning; abort it first"), std::string::npos) << r.message;
  // The image calibration too (the probe is the sweep's); the mold one needs no probe and runs.
  const auto image_refusal = calibrate("us");
  EXPECT_EQ(image_refusal.status, 409);
  EXPECT_NE(image_refusal.message.find("the sweep is using the probe"), std::string::npos)
      << image_refusal.message;
  EXPECT_FALSE(arm().calibrations()->running());
  EXPECT_EQ(arm().calibration_snapshot().phase, CalibrationPhase::idle);
}

TEST_F(UsArmCalibrationTest, ABadTrackerSectionIsRefusedWithItsKey) {
  auto file = load_robot_config(kConfig / "us_arm.json");
  file.settings["ultrasound"]["simulation"]["tracker"]["robot_error_mm"] = {0.3};
  RuntimeOptions o;
  o.stepped = true;
  try {
    RobotRuntime bad({file}, o, builtin_robot_types());
    FAIL() << "a robot error of one number was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("ultrasound.simulation.tracker.robot_error_mm"), std::string::npos)
        << e.what();
  }
}

TEST_F(UsArmCalibrationTest, ThePreviousCalibrationStaysInUseWhenTheRobotIsPaused) {
  start();
  // A calibration already in the store (as a previous run would have left it).
  CalibrationRecord previous;
  previous.kind = "robot";
  previous.method = "test";
  previous.transforms["H_B^G"] = arm().tracker_settings()->global_T_base;
  previous.transforms["H_U^M"] = arm().tracker_settings()->marker_T_probe;
  previous.valid = true;
  previous.summary = "the truth";
  arm().calibrations()->store().save(previous);
  arm().publish_calibration_in_use();
  enable();
  mode("cartesian");
  ASSERT_EQ(calibrate().status, 202);
  ASSERT_TRUE(step_until([&] { return arm().calibration_snapshot().pose >= 1; }, 60'000));
  ASSERT_EQ(api->state_command("us_arm", {{"command", "pause"}}).status, 200);
  ASSERT_TRUE(until_finished(2000));
  const auto c = op()["calibration"];
  EXPECT_FALSE(c["last"]["ok"].get<bool>());
  EXPECT_NE(c["last"]["message"].get<std::string>().find("paused"), std::string::npos) << c.dump();
  EXPECT_EQ(c["robot"]["version"], 1);
}

}  // namespace
}  // namespace tendril::server
