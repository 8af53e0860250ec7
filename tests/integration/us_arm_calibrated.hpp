// Shared by the us_arm tests that sweep: the sweep refuses without valid "robot" and "us"
// calibrations, so these tests get a calibration store of their own (a temporary TENDRIL_STATE_DIR) and
// store the SIMULATED truths in it. What they then measure is the control, not a calibration's error;
// the routines themselves are tested in us_arm_calibration_tests and us_calibration_tests.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include "serial_arm/calibration_store.hpp"
#include "serial_arm/serial_arm_robot.hpp"
#include "serial_arm/ultrasound_calibrations.hpp"

namespace tendril::server::testing {

// TENDRIL_STATE_DIR pointed at a fresh directory named after the running test; on exit the directory
// is removed and the caller's TENDRIL_STATE_DIR (scripts/test.sh sets one) is back.
class ScopedStateDir {
 public:
  explicit ScopedStateDir(const std::string& prefix)
      : path_(std::filesystem::temp_directory_path() /
              (prefix + "_" + std::to_string(::getpid()) + "_" +
               ::testing::UnitTest::GetInstance()->current_test_info()->name())) {
    if (const char* before = std::getenv("TENDRIL_STATE_DIR")) before_ = before;
    std::filesystem::remove_all(path_);
    ::setenv("TENDRIL_STATE_DIR", path_.c_str(), 1);
  }
  ScopedStateDir(const ScopedStateDir&) = delete;
  ScopedStateDir& operator=(const ScopedStateDir&) = delete;
  ~ScopedStateDir() {
    if (before_)
      ::setenv("TENDRIL_STATE_DIR", before_->c_str(), 1);
    else
      ::unsetenv("TENDRIL_STATE_DIR");
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  const std::filesystem::path& path() const noexcept { return path_; }

 private:
  std::filesystem::path path_;
  std::optional<std::string> before_;
};

// Stores the SIMULATED tracker's true H_B^G and H_U^M ("robot") and the SIMULATED scanner's true H_I^U
// with its pixel scales ("us") as calibrations, and makes the arm use them.
inline void store_true_calibrations(SerialArm& arm) {
  CalibrationRecord truth;
  truth.kind = "robot";
  truth.method = "test fixture: the SIMULATED tracker's true H_B^G";
  truth.transforms["H_B^G"] = arm.tracker_settings()->global_T_base;
  truth.transforms["H_U^M"] = arm.tracker_settings()->marker_T_probe;
  truth.valid = true;
  truth.summary = "the truth";
  arm.calibrations()->store().save(truth);
  const auto& image = arm.ultrasound_calibrations()->simulation().true_image;
  CalibrationRecord us;
  us.kind = "us";
  us.method = "test fixture: the SIMULATED scanner's true H_I^U and pixel scales";
  us.transforms["H_I^U"] = image.image_in_probe;
  us.values["s_u_mm_per_px"] = image.s_u;
  us.values["s_v_mm_per_px"] = image.s_v;
  us.valid = true;
  us.summary = "the truth";
  arm.calibrations()->store().save(us);
  arm.publish_calibration_in_use();
}

}  // namespace tendril::server::testing
