// The ultrasound arm's control-side guarantees (issue 17):
//  * /us_arm/force (force_topic.hpp) carries the control tick's reading, consistent with the sweep's own
//    state (/us_arm/sweep), once per new tick, with the sweep's phase and the 0.8 N target;
//  * UltrasoundSweep::step — the phase machine, the target from the tracked limb pose, the hybrid
//    position/force controller (App. A) with its kinematics and damped inverse, the velocity
//    feed-forward's filter and second resolution — allocates nothing over a whole sweep (pre-position,
//    approach, 16 acquisitions, pause, continue, done and the retraction, then a new sweep aborted),
//    counted with the test allocation counter around every call.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "allocation_counter.hpp"
#include "json_api.hpp"
#include "serial_arm/force_topic.hpp"
#include "serial_arm/serial_arm_robot.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "us_arm_calibrated.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::filesystem::path kConfig = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots";

TEST(UsArmForceTopic, PublishesEachNewTickConsistentWithTheSweep) {
  const testing::ScopedStateDir state_dir("tendril_us_arm_control");
  RuntimeOptions o;
  o.stepped = true;
  o.control_rate_hz = 1000;
  auto runtime = std::make_unique<RobotRuntime>(
      std::vector<RobotConfig>{load_robot_config(kConfig / "us_arm.json")}, o, builtin_robot_types());
  auto api = json_api(*runtime);
  runtime->start();
  auto& arm = dynamic_cast<SerialArm&>(*runtime->plugin("us_arm"));
  testing::store_true_calibrations(arm);  // the sweep refuses without them
  auto topic = make_arm_force_topic(arm, /*own_thread=*/false);
  ASSERT_EQ(topic->topics().size(), 1u);
  EXPECT_EQ(topic->topics()[0].topic, "/us_arm/force");
  EXPECT_FALSE(topic->latest("/us_arm/force", 0).has_value());  // nothing before the first message

  const auto step_until = [&](auto pred, int max_steps) {
    for (int i = 0; i < max_steps && !pred(); ++i) runtime->step();
    return pred();
  };
  ASSERT_EQ(api->state_command("us_arm", {{"command", "enable"}}).status, 200);
  ASSERT_TRUE(step_until(
      [&] {
        const auto s = api->operating_state("us_arm").body;
        return s["drives_ready"].get<bool>() && !s["is_busy"].get<bool>();
      },
      3000));
  ASSERT_EQ(api->mode("us_arm", {{"mode", "sweep"}}).status, 200);
  runtime->step();
  ASSERT_EQ(api->robot_command("us_arm", "sweep", {{"action", "plan"}}).status, 200);
  runtime->step();
  ASSERT_EQ(api->robot_command("us_arm", "sweep", {{"action", "pre_position"}}).status, 202);
  ASSERT_TRUE(step_until([&] { return arm.sweep_snapshot().phase == SweepPhase::ready; }, 60'000));
  ASSERT_EQ(api->robot_command("us_arm", "sweep", {{"action", "start"}}).status, 202);

  // Each tick: the message carries this tick's force and the sweep's state; a second read of the same
  // tick publishes nothing.
  std::uint64_t version = 0;
  int messages = 0, in_contact = 0, acquiring = 0;
  double acquiring_sum = 0.0;
  for (int i = 0; i < 20'000 && acquiring < 200; ++i) {
    runtime->step();
    const std::uint64_t now = 1'000'000'000ULL + static_cast<std::uint64_t>(i) * 1'000'000ULL;
    ASSERT_TRUE(topic->step(now));
    ASSERT_FALSE(topic->step(now + 1));
    const auto latest = topic->latest("/us_arm/force", version);
    ASSERT_TRUE(latest.has_value());
    version = latest->version;
    EXPECT_EQ(latest->log_time_ns, now);
    const json m = json::parse(*latest->payload);
    ++messages;
    const SweepSnapshot sw = arm.sweep_snapshot();
    const ArmSnapshot snap = arm.snapshot();
    ASSERT_TRUE(snap.force_valid);
    EXPECT_EQ(m["frame_id"], "us_arm_probe");
    EXPECT_EQ(m["timestamp"]["sec"], 1 + i / 1000);
    EXPECT_DOUBLE_EQ(m["target_n"].get<double>(), 0.8);
    EXPECT_EQ(m["phase"], to_string(sw.phase));
    EXPECT_EQ(m["in_contact"].get<bool>(), sw.in_contact);
    ASSERT_EQ(m["force_n"].size(), 3u);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(m["force_n"][k].get<double>(), snap.force_n[k], 1e-4);
    // F_n is the sweep's own F_n (the reading the hybrid controller used this tick).
    EXPECT_NEAR(m["normal_n"].get<double>(), sw.force_n, 1e-4);
    EXPECT_NEAR(m["normal_n"].get<double>(), -m["force_n"][2].get<double>(), 1e-9);
    EXPECT_NEAR(m["t"].get<double>(), arm.probe_state().t, 1e-6);
    if (sw.in_contact) ++in_contact;
    if (sw.phase == SweepPhase::acquiring) {
      ++acquiring;
      acquiring_sum += m["normal_n"].get<double>();
    }
  }
  ASSERT_EQ(acquiring, 200) << "the first acquisition was not reached";
  EXPECT_GT(in_contact, 200);
  // While acquiring, F_n is on its target (the gate's ±0.1 N).
  EXPECT_NEAR(acquiring_sum / acquiring, 0.8, 0.1);
  std::printf("force topic: %d messages, %d in contact, mean F_n while acquiring %.3f N\n", messages,
              in_contact, acquiring_sum / acquiring);
  runtime->stop();
}

TEST(UsArmForceTopic, RefusesBadSettings) {
  const auto reader = [] { return ArmForceSample{}; };
  ArmForceTopicSettings bad;
  bad.own_thread = false;
  bad.rate_hz = 0.0;
  EXPECT_THROW(ArmForceTopic(bad, reader), std::invalid_argument);
  bad.rate_hz = std::nan("");
  EXPECT_THROW(ArmForceTopic(bad, reader), std::invalid_argument);
  ArmForceTopicSettings ok;
  ok.own_thread = false;
  EXPECT_THROW(ArmForceTopic(ok, ArmForceTopic::Reader{}), std::invalid_argument);
  // Before the control loop published anything: no message; without a reading: nulls, not zeros.
  ArmForceTopic empty(ok, reader);
  EXPECT_FALSE(empty.step(1));
  ArmForceSample s;
  s.tick = 1;
  const json m = json::parse(empty.message(s, 5));
  EXPECT_TRUE(m["force_n"].is_null());
  EXPECT_TRUE(m["normal_n"].is_null());
  EXPECT_TRUE(m["target_n"].is_null());
  EXPECT_TRUE(m["phase"].is_null());
  EXPECT_FALSE(m["fresh"].get<bool>());
}

// The SIMULATED tracker's noise is what the file asks (σ = 0.3 mm per axis), and the sweep's filter
// takes it down while it follows the limb's motion: 120 Hz reports of the limb's PLM through the
// shipped 0.5 Hz alpha-beta filter, compared with the truth at the report's time.
TEST(UsArmTrackerFilter, TheFilterRemovesMostOfTheTrackersNoiseAndFollowsTheLimb) {
  const RobotConfig rc = load_robot_config(kConfig / "us_arm.json");
  const auto us = parse_ultrasound_settings(rc);
  ASSERT_TRUE(us.has_value());
  EXPECT_DOUBLE_EQ(us->limb.tracker_noise, 0.3);
  EXPECT_DOUBLE_EQ(us->tracker_filter_hz, 0.5);
  LimbSimulation limb(us->limb);
  LimbPoseFilter filter;
  filter.configure(us->tracker_filter_hz, 1.0 / us->limb.tracker_rate);
  const Eigen::Vector3d via(40.0, 0.0, 0.0);  // a point on the skin 40 mm along the limb
  double raw2 = 0.0, filtered2 = 0.0, velocity2 = 0.0, speed2 = 0.0;
  int n = 0;
  double last_t = -1.0;
  for (int i = 0; i <= 60'000; ++i) {  // 60 s at 1 kHz: two PLM periods
    const double t = i * 1e-3;
    limb.advance(t);
    const LimbPoseSample k = limb.tracked();
    if (k.t == last_t) continue;
    last_t = k.t;
    filter.update(to_isometry(k.pose), k.t);
    if (t < 5.0) continue;  // the filter's start (its time constant is 1/ω_n ≈ 0.3 s)
    const Eigen::Isometry3d truth = limb.pose_at(k.t);
    raw2 += (to_isometry(k.pose).translation() - truth.translation()).squaredNorm();
    filtered2 += (filter.pose().translation() - truth.translation()).squaredNorm();
    const Eigen::Vector3d v_true = (limb.pose_at(k.t + 1e-4) * via - limb.pose_at(k.t - 1e-4) * via) / 2e-4;
    velocity2 += (filter.point_velocity(via) - v_true).squaredNorm();
    speed2 += v_true.squaredNorm();
    ++n;
  }
  ASSERT_GT(n, 6000);
  const double raw = std::sqrt(raw2 / n), filtered = std::sqrt(filtered2 / n);
  const double velocity = std::sqrt(velocity2 / n), speed = std::sqrt(speed2 / n);
  std::printf(
      "tracker: raw %.3f mm rms (3 axes), filtered %.3f mm; velocity error %.3f mm/s rms (limb %.3f mm/s)\n",
      raw, filtered, velocity, speed);
  EXPECT_NEAR(raw, 0.3 * std::sqrt(3.0), 0.05);  // σ = 0.3 mm on each axis
  EXPECT_LT(filtered, 0.3 * raw);
  // A raw difference over one 8.3 ms report would be σ·√2·120 ≈ 50 mm/s per axis.
  EXPECT_LT(velocity, 0.5);
  EXPECT_GT(speed, 0.3);  // the limb did move
  // A stall of the reports (> 0.1 s) restarts the filter from the next report.
  const Eigen::Isometry3d far = Eigen::Translation3d(100.0, 0.0, 0.0) * limb.pose_at(last_t);
  filter.update(far, last_t + 1.0);
  EXPECT_LT((filter.pose().translation() - far.translation()).norm(), 1e-9);
}

// A closed loop of a simulated set-up like the article's (a 0.5 N/mm tissue spring, 0.02 N force noise, the
// limb's periodic movement) around UltrasoundSweep alone: the arm as a kinematic integrator of q̇ at 1 kHz,
// the SIMULATED limb (PLM, the 120 Hz tracker) and its skin as the contact surface (0.5 N/mm), force noise
// 0.02 N. Only the sweep's step is counted.
TEST(UsArmSweepAllocation, AWholeSweepStepsWithoutAllocating) {
  const RobotConfig rc = load_robot_config(kConfig / "us_arm.json");
  const ArmSettings arm = parse_arm_settings(rc);
  const auto us = parse_ultrasound_settings(rc);
  ASSERT_TRUE(us.has_value());
  const teleop::SerialArmKinematics model(arm.parameters);
  LimbSimulation limb(us->limb);
  const SweepPlan plan = make_sweep_plan(limb, *us);
  SweepPlanData data;
  data.count = static_cast<int>(plan.via_points.size());
  for (int i = 0; i < data.count; ++i)
    data.via_points[static_cast<std::size_t>(i)] = to_array(plan.via_points[static_cast<std::size_t>(i)]);
  sim::ContactSurfaceParameters skin;
  skin.pose = us->limb.rest_pose;
  skin.stiffness = us->limb.stiffness;
  skin.damping = us->limb.damping;
  skin.height_map = &limb;
  sim::ContactSurface surface(skin);
  UltrasoundSweep sweep(*us, arm.gains, arm.cartesian);
  teleop::SerialArmData d = model.make_data();
  teleop::SerialArmData fk = model.make_data();
  teleop::ArmVector q;
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i)
    q[static_cast<Eigen::Index>(i)] = rc.joints[i].initial_position;
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, 0.02);

  const double dt = 0.001;
  double t = 0.0;
  long allocations = 0, steps = 0;
  teleop::CartesianCommandResult out;
  teleop::ArmVector qd = teleop::ArmVector::Zero();
  // One control cycle: the limb and the tissue, the force in the probe frame, the sweep (counted), the
  // kinematic arm.
  const auto cycle = [&] {
    limb.advance(t);
    surface.move_to(limb.pose_at(t), limb.velocity_at(t));
    model.forward_kinematics(q, fk);
    model.compute_jacobian(fk);
    const Eigen::Vector3d v = (fk.jacobian * qd).head<3>();
    const sim::ContactSample c = surface.contact(fk.tool.translation(), v);
    UltrasoundSweep::Inputs in;
    in.q = q;
    in.force = fk.tool.linear().transpose() * c.force + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    in.force_valid = true;
    const LimbPoseSample tracked = limb.tracked();
    in.world_T_limb = to_isometry(tracked.pose);
    in.limb_t = tracked.t;
    in.t = t;
    in.dt = dt;
    const long before = tendril::testing::allocation_count.load();
    const bool moves = sweep.step(model, d, in, out);
    allocations += tendril::testing::allocation_count.load() - before;
    ++steps;
    qd = moves && out.joints.valid ? out.joints.joint_velocity : teleop::ArmVector::Zero();
    q += qd * dt;
    t += dt;
  };
  const auto run_until = [&](auto pred, int max_steps) {
    for (int i = 0; i < max_steps && !pred(); ++i) cycle();
    return pred();
  };
  const auto count_command = [&](SweepAction a) {
    const long before = tendril::testing::allocation_count.load();
    sweep.command(a, t);
    allocations += tendril::testing::allocation_count.load() - before;
  };
  // The counter sees allocations at all (else a zero below would prove nothing).
  const long probe_before = tendril::testing::allocation_count.load();
  tendril::testing::allocate_probe();
  ASSERT_GT(tendril::testing::allocation_count.load(), probe_before);

  const long load_before = tendril::testing::allocation_count.load();
  sweep.load(data);
  allocations += tendril::testing::allocation_count.load() - load_before;
  count_command(SweepAction::pre_position);
  ASSERT_TRUE(run_until([&] { return sweep.snapshot().phase == SweepPhase::ready; }, 60'000))
      << sweep.snapshot().message;
  count_command(SweepAction::start);
  ASSERT_TRUE(run_until([&] { return sweep.snapshot().slices == 3; }, 60'000)) << sweep.snapshot().message;
  count_command(SweepAction::pause);
  ASSERT_EQ(sweep.snapshot().phase, SweepPhase::paused);
  for (int i = 0; i < 500; ++i) cycle();
  count_command(SweepAction::start);
  ASSERT_TRUE(run_until(
      [&] { return sweep.snapshot().phase == SweepPhase::done && !sweep.snapshot().retracting; }, 200'000))
      << sweep.snapshot().message;
  EXPECT_EQ(sweep.snapshot().slices, data.count);
  // A second sweep, aborted on the skin.
  count_command(SweepAction::pre_position);
  ASSERT_TRUE(run_until([&] { return sweep.snapshot().phase == SweepPhase::ready; }, 60'000));
  count_command(SweepAction::start);
  ASSERT_TRUE(run_until([&] { return sweep.snapshot().in_contact; }, 60'000));
  count_command(SweepAction::abort);
  ASSERT_TRUE(run_until([&] { return !sweep.snapshot().retracting; }, 10'000));
  std::printf("sweep steps counted: %ld (%.1f s simulated), allocations: %ld\n", steps, t, allocations);
  EXPECT_EQ(allocations, 0);
}

}  // namespace
}  // namespace tendril::server
