// The us_arm's "us" (image-to-probe, N-wire phantom) and "catheter" (mold) calibrations as routines of the
// robot's CalibrationRunner (Heunis et al. 2021, §2.2–2.3): each run saves a new version in the
// store, a valid one becomes the one in use, the ultrasound topics' reconstruction maps with it (a wrong
// H_I^U shows as a centroid offset, the calibrated one removes it), and the refusals.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <thread>

#include <unistd.h>

#include "json_api.hpp"
#include "serial_arm/calibration_runner.hpp"
#include "serial_arm/calibration_store.hpp"
#include "serial_arm/serial_arm_robot.hpp"
#include "serial_arm/ultrasound_calibrations.hpp"
#include "serial_arm/ultrasound_topics.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

namespace us = tendril::ultrasound;
using Eigen::Isometry3d;
using Eigen::Vector3d;

class UsCalibrationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    directory = std::filesystem::temp_directory_path() /
                ("tendril-uscal-" + std::to_string(::getpid()) + "-" +
                 ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(directory);
    store = std::make_unique<CalibrationStore>(directory, "us_arm");
    runner = std::make_unique<CalibrationRunner>(*store);
    calibrations = std::make_unique<UltrasoundCalibrations>("us_arm", *runner,
                                                            UltrasoundCalibrationSimulation::standard(),
                                                            [this]() -> std::optional<std::string> {
                                                              std::lock_guard lock(mutex);
                                                              return busy;
                                                            });
  }
  void TearDown() override {
    calibrations.reset();
    runner.reset();
    store.reset();
    std::filesystem::remove_all(directory);
  }
  // Runs a kind and waits (real time: the routine is on its own thread) for its outcome.
  CalibrationRunner::Outcome run(const std::string& kind) {
    const auto refusal = runner->run(kind, OperatingStateView{});
    EXPECT_FALSE(refusal) << *refusal;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (runner->running() && std::chrono::steady_clock::now() < until)
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    EXPECT_FALSE(runner->running()) << "the " << kind << " routine did not end in 120 s";
    const auto last = runner->last();
    EXPECT_TRUE(last.has_value());
    return last.value_or(CalibrationRunner::Outcome{});
  }

  std::filesystem::path directory;
  std::unique_ptr<CalibrationStore> store;
  std::unique_ptr<CalibrationRunner> runner;
  std::unique_ptr<UltrasoundCalibrations> calibrations;
  std::mutex mutex;
  std::optional<std::string> busy;
};

TEST_F(UsCalibrationTest, RegistersUsAsRequiredAndCatheterAsNot) {
  const auto kinds = store->kinds();
  ASSERT_EQ(kinds.size(), 2U);
  EXPECT_EQ(kinds[0].kind, "us");
  EXPECT_TRUE(kinds[0].required);
  EXPECT_EQ(kinds[1].kind, "catheter");
  EXPECT_FALSE(kinds[1].required);
  ASSERT_EQ(store->missing_required().size(), 1U);
  EXPECT_EQ(store->missing_required()[0].kind, "us");
  EXPECT_FALSE(calibrations->image_in_use());
  EXPECT_FALSE(calibrations->fiber_in_use());
}

TEST_F(UsCalibrationTest, CatheterMoldCalibrationStoresANewValidVersionEachRun) {
  const auto first = run("catheter");
  std::printf("catheter: %s\n", first.message.c_str());
  ASSERT_TRUE(first.ok) << first.message;
  EXPECT_EQ(first.version, 1);
  const auto record = store->current("catheter");
  ASSERT_TRUE(record);
  EXPECT_TRUE(record->valid);
  EXPECT_EQ(record->transforms.count("H_F^C"), 1U);
  EXPECT_LE(record->residuals.at("channel_iii_mean_mm").get<double>(), 0.82);  // Heunis et al. 2021, §4.2
  EXPECT_LE(record->residuals.at("channel_iii_max_mm").get<double>(), 1.52);
  EXPECT_TRUE(std::filesystem::exists(directory / CalibrationStore::file_name("catheter", 1)));
  const auto in_use = calibrations->fiber_in_use();
  ASSERT_TRUE(in_use);
  EXPECT_EQ(in_use->first, 1);
  // The fit is near the SIMULATED truth (two tracked recordings of 0.3 mm each).
  const Isometry3d& truth = calibrations->simulation().mold.simulated_true_fiber_in_base;
  EXPECT_LT((in_use->second.translation() - truth.translation()).norm(), 1.5);
  const auto second = run("catheter");
  ASSERT_TRUE(second.ok) << second.message;
  EXPECT_EQ(second.version, 2);
  EXPECT_EQ(calibrations->fiber_in_use()->first, 2);
}

TEST_F(UsCalibrationTest, ImageCalibrationIsRefusedWhileTheSweepHoldsTheProbe) {
  {
    std::lock_guard lock(mutex);
    busy = "calibrate: the sweep is using the probe (phase moving)";
  }
  const auto refusal = runner->run("us", OperatingStateView{});
  ASSERT_TRUE(refusal);
  EXPECT_NE(refusal->find("sweep"), std::string::npos) << *refusal;
  EXPECT_FALSE(runner->running());
  EXPECT_FALSE(store->newest("us"));
}

// The reconstruction's view: three UltrasoundTopics over one straight artery, the same probe state (an
// acquisition at one via-point), the scanner imaging through its TRUE H_I^U: one maps with the nominal
// calibration (none in use), one with the store's calibration in use, one with the truth.
struct Reconstruction {
  std::optional<UltrasoundProbeState> state;
  std::unique_ptr<UltrasoundTopics> topics;
  Reconstruction(const UltrasoundCalibrationSimulation& sim,
                 std::function<std::optional<std::pair<int, us::ImageCalibration>>()> reader) {
    us::ReconstructionSessionConfig c;
    for (int x = -100; x <= 100; ++x) {
      c.artery.points.emplace_back(static_cast<double>(x), -30.0, 0.0);
      c.artery.radii.push_back(5.0);
    }
    c.errors.enabled = false;  // only the calibration differs
    c.simulated_true_image = sim.true_image;
    UltrasoundTopicsSettings settings;
    settings.own_thread = false;
    settings.image_calibration_reader = std::move(reader);
    topics = std::make_unique<UltrasoundTopics>(c, settings, [this] { return state; });
    us::SweepPlan plan;  // the segmentation's seed: the planned centroid on the artery's axis
    plan.centroids.emplace_back(0.0, -30.0, 0.0);
    topics->set_plan(plan);
    // The probe on the skin (y = 0 of {P}) over the artery, looking down (−y), its image plane across
    // the artery (the image's x, the elevation axis, along the artery).
    UltrasoundProbeState s;
    s.tick = 1;
    s.t = 1.0;
    Isometry3d probe = Isometry3d::Identity();
    probe.linear().col(0) = Vector3d::UnitX();
    probe.linear().col(1) = Vector3d::UnitZ();
    probe.linear().col(2) = -Vector3d::UnitY();
    s.world_T_probe = probe;
    s.in_contact = true;
    s.acquiring = true;
    s.via_point = 0;
    state = s;
  }
  Vector3d centroid() {
    topics->step(2'000'000'000ULL);
    const auto c = topics->last_slice_centroid();
    EXPECT_TRUE(c.has_value()) << topics->last_message();
    return c.value_or(Vector3d::Constant(1e9));
  }
};

TEST_F(UsCalibrationTest, ImageCalibrationIsStoredAndTheReconstructionMapsWithIt) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto outcome = run("us");
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("us: %s (%.1f s)\n", outcome.message.c_str(), seconds);
  ASSERT_TRUE(outcome.ok) << outcome.message;
  EXPECT_EQ(outcome.version, 1);
  const auto record = store->current("us");
  ASSERT_TRUE(record);
  EXPECT_LT(record->residuals.at("validation_mean_mm").get<double>(), 0.5);  // image-to-probe calibration
  EXPECT_TRUE(store->missing_required().empty());
  const auto in_use = calibrations->image_in_use();
  ASSERT_TRUE(in_use);
  EXPECT_EQ(in_use->first, 1);
  const auto& truth = calibrations->simulation().true_image;
  EXPECT_NEAR(in_use->second.s_u, truth.s_u, 0.002);
  EXPECT_NEAR(in_use->second.s_v, truth.s_v, 0.002);

  const auto& sim = calibrations->simulation();
  Reconstruction nominal(sim, {});
  Reconstruction calibrated(sim, [this] { return calibrations->image_in_use(); });
  Reconstruction exact(sim, [&truth] { return std::make_optional(std::make_pair(99, truth)); });
  const Vector3d truly = exact.centroid();
  const double nominal_offset = (nominal.centroid() - truly).norm();
  const double calibrated_offset = (calibrated.centroid() - truly).norm();
  std::printf("slice centroid off the true mapping's: nominal H_I^U %.3f mm, calibrated %.3f mm\n",
              nominal_offset, calibrated_offset);
  EXPECT_EQ(calibrated.topics->image_calibration_version(), 1);
  EXPECT_EQ(nominal.topics->image_calibration_version(), 0);
  EXPECT_GT(nominal_offset, 0.8);
  EXPECT_LT(calibrated_offset, 0.3);

  // The hook-up make_us_arm_topics uses: the truths into the SIMULATED scanner and fibre, the readers.
  us::ReconstructionSessionConfig session;
  UltrasoundTopicsSettings settings;
  use_ultrasound_calibrations(*calibrations, session, settings);
  ASSERT_TRUE(session.simulated_true_image);
  EXPECT_EQ(session.simulated_true_image->s_u, truth.s_u);
  ASSERT_TRUE(session.simulated_true_fiber_in_base);
  ASSERT_TRUE(settings.image_calibration_reader && settings.fiber_calibration_reader);
  EXPECT_EQ(settings.image_calibration_reader()->first, 1);
  EXPECT_FALSE(settings.fiber_calibration_reader());  // no catheter calibration yet
}

TEST_F(UsCalibrationTest, OneRoutineAtATime) {
  ASSERT_FALSE(runner->run("us", OperatingStateView{}));
  const auto refusal = runner->run("catheter", OperatingStateView{});
  // The image routine takes seconds; the mold one cannot start meanwhile.
  if (runner->running()) {
    ASSERT_TRUE(refusal);
    EXPECT_NE(refusal->find("running"), std::string::npos) << *refusal;
  }
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (runner->running() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_FALSE(runner->running());
}

// Through the runtime and the JSON API with config/robots/us_arm.json: the kinds in GET /robots, the
// commands, the progress and outcome in operating_state, a restart finding the versions.
class UsArmRuntimeCalibrationTest : public ::testing::Test {
 protected:
  void SetUp() override {
    state_dir = std::filesystem::temp_directory_path() /
                ("tendril-uscal-runtime-" + std::to_string(::getpid()) + "-" +
                 ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(state_dir);
    ::setenv("TENDRIL_STATE_DIR", state_dir.c_str(), 1);
  }
  void TearDown() override {
    stop();
    ::unsetenv("TENDRIL_STATE_DIR");
    std::filesystem::remove_all(state_dir);
  }
  void start() {
    RuntimeOptions o;
    o.stepped = true;
    o.control_rate_hz = 1000;
    const auto config = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/us_arm.json";
    runtime = std::make_unique<RobotRuntime>(std::vector<RobotConfig>{load_robot_config(config)}, o,
                                             builtin_robot_types());
    api = json_api(*runtime);
    runtime->start();
    for (int i = 0; i < 20; ++i) runtime->step();
  }
  void stop() {
    if (runtime) runtime->stop();
    api.reset();
    runtime.reset();
  }
  nlohmann::json calibration() { return api->operating_state("us_arm").body["calibration"]; }
  // Posts the kind and waits in real time (the routine is on a worker thread), stepping the runtime.
  nlohmann::json calibrate(const std::string& kind) {
    const auto r = api->robot_command("us_arm", "calibrate", {{"kind", kind}});
    EXPECT_EQ(r.status, 202) << r.message;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (!calibration()["running"].is_null() && std::chrono::steady_clock::now() < until) {
      runtime->step();
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return calibration();
  }
  std::filesystem::path state_dir;
  std::unique_ptr<RobotRuntime> runtime;
  std::unique_ptr<JsonControlApi> api;
};

TEST_F(UsArmRuntimeCalibrationTest, CatheterAndImageCalibrationsThroughTheApi) {
  start();
  const auto robots = api->robots();
  ASSERT_EQ(robots.size(), 1U);
  EXPECT_EQ(robots[0]["calibrations"]["kinds"], nlohmann::json({"robot", "us", "catheter"}));
  EXPECT_EQ(robots[0]["calibrations"]["required"], nlohmann::json({"robot", "us"}));
  auto c = calibrate("catheter");
  ASSERT_TRUE(c["last"]["ok"].get<bool>()) << c.dump();
  EXPECT_EQ(c["catheter"]["version"], 1);
  EXPECT_LE(c["catheter"]["residual_mm"].get<double>(), 0.82);
  c = calibrate("us");
  std::printf("through the API: %s\n", c["us"]["summary"].get<std::string>().c_str());
  ASSERT_TRUE(c["last"]["ok"].get<bool>()) << c.dump();
  EXPECT_EQ(c["us"]["version"], 1);
  EXPECT_LT(c["us"]["residual_mm"].get<double>(), 0.5);
  EXPECT_EQ(c["missing"], nlohmann::json({"robot"}));
  EXPECT_EQ(api->robot_command("us_arm", "calibrate", {{"kind", "ultrasound"}}).status, 400);
  // The arm's topics map with the versions in use.
  SerialArm& arm = dynamic_cast<SerialArm&>(*runtime->plugin("us_arm"));
  ASSERT_NE(arm.ultrasound_calibrations(), nullptr);
  EXPECT_EQ(arm.ultrasound_calibrations()->image_in_use()->first, 1);
  EXPECT_EQ(arm.ultrasound_calibrations()->fiber_in_use()->first, 1);
  // A restart finds both versions.
  stop();
  start();
  c = calibration();
  EXPECT_EQ(c["us"]["version"], 1) << c.dump();
  EXPECT_EQ(c["catheter"]["version"], 1) << c.dump();
}

}  // namespace
}  // namespace tendril::server
