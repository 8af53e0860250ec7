// ImageFeedback: the seam between the bi-plane imaging (ImagingWorker, its own threads) and a robot
// type that closes a loop on what the images show (e.g. a catheter replanning from its imaged tip).
// The core names no robot: a RobotPlugin offers this interface (RobotPlugin::image_feedback) and the
// imaging calls it. Every method but tracking_attached runs on an imaging thread — never the control
// thread — so an implementation may allocate and lock there, but must hand results to its controller
// through lock-free slots (hardware::LatestValue).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <vector>

namespace tendril::server {

// One bi-plane evaluation of the tip: both planes' frames of one exposure, triangulated.
struct ImagedTip {
  bool found = false;  // false: a plane did not find the tip (or the two frames were not in step)
  // World mm: the triangulation of this exposure's two segmented tips. A loop closes on this one: the
  // EKF-filtered tip lags behind a plant that differs from the model (its process runs on the model's
  // backbone), and fed back it made the catheter swing (measured: 2.4 mm RMS off the centerline with
  // it, 0.22–0.53 mm between the raw tip and the true one).
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  bool has_filtered = false;                           // both planes' EKFs run
  Eigen::Vector3d filtered = Eigen::Vector3d::Zero();  // world mm: the EKF-filtered tip, for display
  std::uint64_t capture_ns = 0;                        // wall clock of the exposure
};

class ImageFeedback {
 public:
  virtual ~ImageFeedback() = default;
  // Set-up (before any thread starts): the imaging tracks this robot's tip and will call on_tip.
  // `demand(true)` (any thread but the control thread) makes the imaging track, and render both
  // simulated planes, whether or not anyone subscribes to /imaging/tracking; demand(false) ends that.
  virtual void tracking_attached(std::function<void(bool wanted)> demand) = 0;
  // Every bi-plane evaluation while tracking runs (found or not). Imaging thread.
  virtual void on_tip(const ImagedTip& tip) = 0;
  // What a SIMULATED fluoroscope should render: the simulated plant's true backbone (world mm, base to
  // tip) when the robot's simulation differs from its model; false: image the model's backbone.
  virtual bool imaged_backbone(std::vector<Eigen::Vector3d>& out) const = 0;
};

}  // namespace tendril::server
