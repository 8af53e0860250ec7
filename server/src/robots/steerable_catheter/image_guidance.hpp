// The imaging half of the catheter's image_guided mode (Abah 2022, §4.11, the high-level controller):
// on every bi-plane evaluation of the tracked tip (an imaging thread, never the control thread) the
// measured tip and the measured insertion go to teleop::ImageGuidedReplanner, and its configuration
// target goes to the control thread through a lock-free latest-value slot. The control thread
// (CatheterController, image_guided) feeds roll and bends to the configuration controller with
// coupling compensation and keeps insertion with the operator.
//
// It is also the catheter's ImageFeedback: a SIMULATED fluoroscope images the true catheter
// (catheter.simulation.true_catheter) rather than the model.
//
// Measured insertion (the arc length of the tip inside the vessel): the tracked tip's closest point on
// the plan's centerline, bounded by the drive: at most kLeadMm ahead of the insertion drive (the
// catheter cannot be further in than it was pushed, beyond the image's noise) and at most kLagMm behind
// it (more than that is taken as a bad fix, not slip). Without a fix, the drive's.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>

#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/server/image_feedback.hpp"
#include "tendril/server/robot_service.hpp"
#include "tendril/teleop/image_guided_replanner.hpp"

namespace tendril::server {

class SteerableCatheter;

// Imaging thread → control thread (trivially copyable).
struct ImageGuidedTarget {
  std::uint64_t sequence = 0;   // 0: none yet; each new replanned target counts up
  std::array<double, 4> psi{};  // ψ = [insertion, roll, θ_L1, θ_L2]; the controller uses roll and bends
};

enum class ImageGuidanceState : std::uint8_t {
  kInactive,  // the mode is not active (or not prepared)
  kWaiting,   // active, no evaluation yet
  kTracking,  // the last evaluation replanned a target
  kNotFound,  // the last evaluation found no tip in a plane
  kRefused,   // the replanner refused the last fix (outlier, out of range)
};
const char* to_string(ImageGuidanceState state) noexcept;

// For the API's operating_state "image_guidance" (any thread).
struct ImageGuidanceStatus {
  ImageGuidanceState state = ImageGuidanceState::kInactive;
  std::uint64_t replans = 0;
  std::uint64_t last_fix_ns = 0;  // wall clock of the last exposure that replanned (0: none)
  double drive_insertion_mm = 0.0;
  double image_insertion_mm = 0.0;     // the fix's arc length on the centerline (without the drive's bound)
  double measured_insertion_mm = 0.0;  // what the replanner got
  std::array<double, 4> target{};      // the last replanned ψ
  std::array<double, 3> tip_mm{};      // the last fix (world)
  std::string reason;                  // why the last evaluation did not replan (empty when it did)
};

class ImageGuidance final : public ImageFeedback {
 public:
  static constexpr double kLeadMm = 2.0;
  static constexpr double kLagMm = 15.0;
  static constexpr double kReplanStepMm = 1.0;

  explicit ImageGuidance(SteerableCatheter& robot) : robot_(robot) {}

  // ImageFeedback (imaging threads)
  void tracking_attached(std::function<void(bool wanted)> demand) override;
  void on_tip(const ImagedTip& tip) override;
  bool imaged_backbone(std::vector<Eigen::Vector3d>& out) const override;

  // Whether the imaging tracks this robot's tip (imaging and its tracking are on).
  bool tracking() const noexcept { return attached_.load(std::memory_order_acquire); }
  // Network thread, on entering the mode: a replanner on the loaded plan's vessel (world mm, as
  // RobotService::path_following has it), and the imaging asked to track. The error when unusable.
  std::optional<ServiceError> prepare(const std::vector<Eigen::Vector3d>& plan_vessel_world);
  // The control thread's slot (read-only there).
  const hardware::LatestValue<ImageGuidedTarget>& target() const noexcept { return target_; }
  ImageGuidanceStatus status() const;

 private:
  SteerableCatheter& robot_;
  std::atomic<bool> attached_{false};
  std::function<void(bool)> demand_;
  hardware::LatestValue<ImageGuidedTarget> target_;

  mutable std::mutex mutex_;  // the replanner, its state and the status (imaging and network threads)
  std::unique_ptr<teleop::ImageGuidedReplanner> replanner_;
  std::unique_ptr<teleop::ReplannerState> state_;
  Eigen::Isometry3d to_insertion_ = Eigen::Isometry3d::Identity();  // world → the plan's insertion frame
  bool demanded_ = false;
  std::uint64_t sequence_ = 0;
  ImageGuidanceStatus status_;
};

}  // namespace tendril::server
