// The calibration store of the serial arm plug-in (calibrations persisted and versioned): a round trip
// through the files, versions that only grow, the newest valid version in use, a corrupt file reported and
// skipped, a non-rigid transform refused, a restart that finds what was saved.
#include <unistd.h>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "serial_arm/calibration_runner.hpp"
#include "serial_arm/calibration_store.hpp"

namespace tendril::server {
namespace {

class CalibrationStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    directory_ = std::filesystem::temp_directory_path() /
                 ("tendril_calibration_store_" + std::to_string(::getpid()) + "_" +
                  ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(directory_);
  }
  void TearDown() override { std::filesystem::remove_all(directory_); }

  std::unique_ptr<CalibrationStore> open() {
    auto store = std::make_unique<CalibrationStore>(directory_, "us_arm");
    store->register_kind({"robot", "robot–world (hand-eye)", "POST calibrate {\"kind\":\"robot\"}", true});
    store->register_kind(
        {"catheter", "FBG in the catheter base", "POST calibrate {\"kind\":\"catheter\"}", false});
    return store;
  }

  static CalibrationRecord robot_calibration(double x, bool valid = true) {
    CalibrationRecord r;
    r.kind = "robot";
    r.method = "Park–Martin rotation, linear translation, Gauss–Newton";
    Eigen::Isometry3d h = Eigen::Isometry3d::Identity();
    h.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    h.translation() = Eigen::Vector3d(x, -250.0, 120.0);
    r.transforms["H_B^G"] = h;
    r.transforms["X_marker_probe"] = Eigen::Isometry3d(Eigen::Translation3d(0, 30, 40));
    r.values["pairs"] = 14;
    r.residual_mm = 0.61;
    r.residuals = {{"rms_mm", 0.61}, {"max_mm", 1.2}};
    r.valid = valid;
    r.summary = "H_B^G from 14 poses, 0.61 mm rms";
    return r;
  }

  std::filesystem::path directory_;
};

TEST_F(CalibrationStoreTest, SavesAndReadsBackTheSameCalibration) {
  const auto saved = [&]() -> CalibrationRecord {
    auto store = open();
    EXPECT_FALSE(store->current("robot"));
    EXPECT_EQ(store->missing_required().size(), 1u);
    if (!store->missing_required().empty()) EXPECT_EQ(store->missing_required()[0].kind, "robot");
    return store->save(robot_calibration(400.0));
  }();
  EXPECT_EQ(saved.version, 1);
  EXPECT_EQ(saved.robot, "us_arm");
  EXPECT_EQ(saved.taken_utc.size(), 20u);  // 2026-12-04T02:10:00Z
  EXPECT_TRUE(std::filesystem::exists(directory_ / "robot-v000001.json"));

  auto store = open();  // a restart
  EXPECT_TRUE(store->problems().empty());
  EXPECT_TRUE(store->missing_required().empty());
  const auto loaded = store->current("robot");
  ASSERT_TRUE(loaded);
  EXPECT_EQ(loaded->version, 1);
  EXPECT_EQ(loaded->taken_unix_s, saved.taken_unix_s);
  EXPECT_EQ(loaded->method, saved.method);
  EXPECT_EQ(loaded->summary, saved.summary);
  EXPECT_DOUBLE_EQ(loaded->residual_mm, 0.61);
  EXPECT_DOUBLE_EQ(loaded->values.at("pairs"), 14.0);
  EXPECT_DOUBLE_EQ(loaded->residuals.at("max_mm").get<double>(), 1.2);
  ASSERT_EQ(loaded->transforms.size(), 2u);
  EXPECT_TRUE(loaded->transforms.at("H_B^G").isApprox(saved.transforms.at("H_B^G"), 1e-12));
  EXPECT_TRUE(loaded->transforms.at("X_marker_probe").isApprox(saved.transforms.at("X_marker_probe"), 1e-12));
}

TEST_F(CalibrationStoreTest, VersionsIncreaseAndAFailedOneLeavesThePreviousInUse) {
  auto store = open();
  EXPECT_EQ(store->save(robot_calibration(400.0)).version, 1);
  EXPECT_EQ(store->save(robot_calibration(401.0)).version, 2);
  const auto failed = store->save(robot_calibration(999.0, false));
  EXPECT_EQ(failed.version, 3);
  EXPECT_EQ(store->current("robot")->version, 2);
  EXPECT_EQ(store->newest("robot")->version, 3);
  EXPECT_EQ(store->save(robot_calibration(402.0, true)).version, 4);

  auto reopened = open();
  EXPECT_EQ(reopened->current("robot")->version, 4);
  EXPECT_DOUBLE_EQ(reopened->current("robot")->transforms.at("H_B^G").translation().x(), 402.0);
  std::filesystem::remove(directory_ / CalibrationStore::file_name("robot", 4));
  auto after_removal = open();  // the newest valid one left is 2 (3 failed its validation)
  EXPECT_EQ(after_removal->current("robot")->version, 2);
  EXPECT_EQ(after_removal->save(robot_calibration(403.0)).version, 4);
}

TEST_F(CalibrationStoreTest, ACorruptFileIsReportedSkippedAndItsVersionNotReused) {
  {
    auto store = open();
    store->save(robot_calibration(400.0));
    store->save(robot_calibration(401.0));
  }
  {
    std::ofstream out(directory_ / CalibrationStore::file_name("robot", 2), std::ios::trunc);
    out << "{\"format\": \"tendril.calibration/1\", \"kind\": \"robot\", \"vers";
  }
  {
    std::ofstream out(directory_ / "notes.txt");  // not a calibration file: left alone, not reported
    out << "hello";
  }
  auto store = open();
  ASSERT_EQ(store->problems().size(), 1u);
  EXPECT_NE(store->problems()[0].find("robot-v000002.json"), std::string::npos) << store->problems()[0];
  EXPECT_NE(store->problems()[0].find("not valid JSON"), std::string::npos) << store->problems()[0];
  EXPECT_EQ(store->current("robot")->version, 1);
  EXPECT_EQ(store->save(robot_calibration(402.0)).version, 3);
}

TEST_F(CalibrationStoreTest, ANonRigidTransformIsRefusedOnSaveAndOnLoad) {
  auto store = open();
  auto sheared = robot_calibration(400.0);
  sheared.transforms["H_B^G"].matrix()(0, 1) += 0.01;
  try {
    store->save(sheared);
    FAIL() << "a sheared transform was saved";
  } catch (const CalibrationStoreError& e) {
    EXPECT_NE(std::string(e.what()).find("not rigid"), std::string::npos) << e.what();
  }
  auto mirrored = robot_calibration(400.0);
  mirrored.transforms["H_B^G"].matrix().col(2) *= -1.0;
  EXPECT_THROW(store->save(mirrored), CalibrationStoreError);
  EXPECT_FALSE(store->current("robot"));
  EXPECT_FALSE(std::filesystem::exists(directory_ / CalibrationStore::file_name("robot", 1)));

  // A file edited by hand into a scaled matrix is reported, not used.
  store->save(robot_calibration(400.0));
  auto document = to_json(robot_calibration(400.0));
  document["version"] = 2;
  document["robot"] = "us_arm";
  document["taken_utc"] = "2026-12-04T00:00:00Z";
  document["transforms"]["H_B^G"]["matrix_row_major"][0] = 2.0;
  std::ofstream(directory_ / CalibrationStore::file_name("robot", 2)) << document.dump();
  auto reopened = open();
  ASSERT_EQ(reopened->problems().size(), 1u);
  EXPECT_NE(reopened->problems()[0].find("not rigid"), std::string::npos) << reopened->problems()[0];
  EXPECT_EQ(reopened->current("robot")->version, 1);
}

TEST_F(CalibrationStoreTest, AnotherRobotsFileAndAnUnknownKindAreRefused) {
  auto store = open();
  auto other = to_json(robot_calibration(400.0));
  other["version"] = 1;
  other["robot"] = "ur5";
  other["taken_utc"] = "2026-12-04T00:00:00Z";
  std::ofstream(directory_ / CalibrationStore::file_name("robot", 1)) << other.dump();
  auto reopened = open();
  ASSERT_EQ(reopened->problems().size(), 1u);
  EXPECT_NE(reopened->problems()[0].find("\"ur5\""), std::string::npos) << reopened->problems()[0];
  EXPECT_FALSE(reopened->current("robot"));
  auto unknown = robot_calibration(400.0);
  unknown.kind = "laser";
  EXPECT_THROW(reopened->save(unknown), CalibrationStoreError);
  EXPECT_THROW(reopened->register_kind({"robot", "", "", false}), CalibrationStoreError);
}

TEST(CalibrationStoreDefaults, TheDefaultDirectoryFollowsTheStateDirectory) {
  ::setenv("TENDRIL_STATE_DIR", "/var/lib/tendril", 1);
  EXPECT_EQ(default_calibration_directory("us_arm"),
            std::filesystem::path("/var/lib/tendril/calibrations/us_arm"));
  ::unsetenv("TENDRIL_STATE_DIR");
}

TEST_F(CalibrationStoreTest, OneRoutineRunsAtATimeAndItsOutcomeStays) {
  CalibrationStore store(directory_, "us_arm");
  CalibrationRunner runner(store);
  int started = 0;
  runner.add({"robot", "robot–world", "POST calibrate {\"kind\":\"robot\"}", true},
             [&](const OperatingStateView& state) -> std::optional<std::string> {
               if (state.mode != "cartesian") return "switch to cartesian mode first";
               ++started;
               return std::nullopt;
             });
  runner.add({"catheter", "FBG", "POST calibrate {\"kind\":\"catheter\"}", false},
             [](const OperatingStateView&) -> std::optional<std::string> { return std::nullopt; });
  OperatingStateView state;
  state.mode = "joint";
  EXPECT_EQ(runner.run("robot", state).value_or(""), "switch to cartesian mode first");
  EXPECT_FALSE(runner.running());
  EXPECT_NE(runner.run("laser", state).value_or("").find("no calibration of kind \"laser\""),
            std::string::npos);
  state.mode = "cartesian";
  EXPECT_FALSE(runner.run("robot", state));
  EXPECT_EQ(started, 1);
  runner.progress(3, 12, "moving to pose 4 of 12");
  const auto busy = runner.run("catheter", state);
  ASSERT_TRUE(busy);
  EXPECT_NE(busy->find("the robot calibration is running (step 3 of 12)"), std::string::npos) << *busy;
  auto json = runner.state_json();
  EXPECT_EQ(json["running"]["kind"], "robot");
  EXPECT_EQ(json["running"]["steps"], 12);
  EXPECT_TRUE(json["robot"].is_null());
  EXPECT_EQ(json["missing"], nlohmann::json::array({"robot"}));
  runner.finish(false, 0, "the tracker lost the marker");
  json = runner.state_json();
  EXPECT_TRUE(json["running"].is_null());
  EXPECT_EQ(json["last"]["ok"], false);
  EXPECT_EQ(json["last"]["message"], "the tracker lost the marker");
  // A refused start runs nothing: the last outcome stays what the operator sees.
  state.mode = "joint";
  EXPECT_TRUE(runner.run("robot", state));
  json = runner.state_json();
  EXPECT_TRUE(json["running"].is_null());
  EXPECT_EQ(json["last"]["message"], "the tracker lost the marker");
  EXPECT_THROW(runner.add({"running", "", "", false}, nullptr), CalibrationStoreError);
}

}  // namespace
}  // namespace tendril::server
