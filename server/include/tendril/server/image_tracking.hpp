// BiplaneTipTracker: the catheter tip seen in the images, per plane and in 3D (Abah 2022, §4.8–4.9).
//
// Per plane and frame (on that plane's imaging thread): the catheter is segmented against the plane's
// empty-vessel roadmap (perception::FluoroscopySegmenter), and its tip pose [x, y, θ] — in mm at the
// isocentre's scale in the plane (x along the image columns, y up the image) — is filtered by the tip
// EKF (perception::TipEkf). The EKF's process needs the insertion increment ds and the curvature κ
// over it: here both come from the imaged robot's model backbone projected onto the plane (its tip's
// displacement along its tangent since the plane's last frame, and the turn of its tangent over the
// last 3 mm) — the dissertation drives the same filter with the planned ds and the vessel's κ(s); the model's
// projection is that prior where no plan runs. With both planes' tips from frames at most 1.5 frame
// periods apart, the two X-rays through them are intersected (closest point) into a 3D tip.
//
// Safety: when the 3D tip from the raw segmentations lies farther than `disagreement_mm` from the
// model's tip on `disagreement_frames` consecutive evaluations, the operator is warned (and again when
// they agree). In the SIMULATION the image is rendered from the model's own backbone, so a
// disagreement there means a segmentation error — unless the robot's simulated plant differs from its
// model (ImageFeedback::imaged_backbone, e.g. a catheter's true_catheter); with a real image source it
// is the plant leaving the model (buckling, slip, a wrong calibration).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/drivers/sim/simulated_fluoroscope.hpp"
#include "tendril/safety/safety_types.hpp"
#include "tendril/server/image_feedback.hpp"
#include "tendril/teleop/perception/fluoroscopy_segmenter.hpp"
#include "tendril/teleop/perception/tip_ekf.hpp"

namespace tendril::server {

struct TrackingConfig {
  bool enabled = true;
  double disagreement_mm = 3.0;  // imaged vs model tip, 3D
  int disagreement_frames = 3;   // consecutive evaluations before a warning (one bad segmentation is not one)
  bool vessel_scale_noise = false;  // the EKF's R: (4.43) fine scale (σ 0.25 mm), or (4.44) (σ 2 mm)
  teleop::perception::BiplaneSegmentationParameters segmentation;
};

// The "tracking" object inside "imaging": {"enabled", "disagreement_mm", "disagreement_frames",
// "noise": "fine"|"vessel", "segmentation": {"ap": {…}, "lateral": {…}}}; null = defaults. Throws
// ConfigError naming the file and key.
TrackingConfig parse_tracking_config(const nlohmann::json& tracking,
                                     const std::filesystem::path& server_file);

// One plane's latest result (pixels of the frame, row 0 at the top).
struct PlaneTrack {
  bool found = false;
  std::string reason;                                     // why nothing was found (empty when found)
  Eigen::Vector2d tip_px = Eigen::Vector2d::Zero();       // segmented
  Eigen::Vector2d filtered_px = Eigen::Vector2d::Zero();  // EKF
  double heading_rad = 0.0;                               // EKF heading, image up = +π/2
  double quality = 0.0;
  bool filtered = false;                     // the EKF has started
  std::vector<Eigen::Vector2d> backbone_px;  // segmented spline, insertion side to tip
  std::uint64_t capture_ns = 0;
};

// A warning for the imaged robot's operator.
using TrackingWarning = std::function<void(safety::FaultCode code, const std::string& text)>;
// Each bi-plane evaluation's 3D tip (once per pair of new frames, found or not), on the thread of the
// plane whose frame completed the pair, outside the tracker's lock.
using TipListener = std::function<void(const ImagedTip& tip)>;

class BiplaneTipTracker {
 public:
  // `planes`: the two planes' fluoroscopes (AP, lateral), for their geometry (project, ray; read-only
  // and safe from any thread) and, for a simulated plane, to render its roadmap now. `simulated`: per
  // plane, whether its images are the simulator's; a plane fed by a source (video, files) has no
  // roadmap until one is taken from its own frames (request_roadmap). `period_s`: the frame period.
  // Throws SegmentationParameterError / TipEkfConfigError on bad parameters.
  BiplaneTipTracker(const TrackingConfig& config, std::array<sim::SimulatedFluoroscope*, 2> planes,
                    double period_s, TrackingWarning warn, std::array<bool, 2> simulated = {true, true});
  ~BiplaneTipTracker();
  BiplaneTipTracker(const BiplaneTipTracker&) = delete;
  BiplaneTipTracker& operator=(const BiplaneTipTracker&) = delete;

  // A plane's frame (8-bit grey, the detector size) and the model backbone (world mm) at its capture.
  // Called from that plane's thread only. Returns the plane's result, valid until its next call.
  const PlaneTrack& track(int plane, teleop::perception::GreyImageView frame,
                          const std::vector<Eigen::Vector3d>& model_backbone, std::uint64_t capture_ns);

  // Where each evaluation's 3D tip goes (a robot closing a loop on the image). Call before tracking.
  void set_tip_listener(TipListener listener) { listener_ = std::move(listener); }

  // The newest /imaging/tracking message and its version (0: none yet). Any thread.
  std::shared_ptr<const std::string> latest(std::uint64_t& version, std::uint64_t& time_ns) const;
  static std::string schema();

  // Live edits of the segmentation (the console's editor), from any thread. They are only recorded
  // here; the plane's own thread applies them at its next frame (apply_requests), so the segmenter is
  // never touched from two threads. request_parameters applies the keys of `changes` (partial) to the
  // plane's latest requested parameters and validates them against the frame: throws
  // SegmentationParameterError naming the field, and then changes nothing. Returns the new parameters.
  teleop::perception::FluoroscopySegmentationParameters request_parameters(int plane,
                                                                           const nlohmann::json& changes);
  // A new empty-vessel roadmap for the plane at its next frame.
  void request_roadmap(int plane);
  // The plane's thread, before its frame: applies the parameters and takes the roadmap asked for.
  // A simulated plane's roadmap is its exposure rendered without the instrument (noiseless, as an
  // averaged acquisition would be): in a lab the catheter is pulled back out of the field first. A
  // plane fed by a source takes `frame`, the frame it is about to track, as its roadmap (the operator
  // pulls the catheter back out of the field, as for the dissertation's roadmap, and then asks for it).
  void apply_requests(int plane, std::uint64_t now_ns,
                      const teleop::perception::GreyImageView* frame = nullptr);
  // Per plane: the parameters asked for, whether the plane applies them yet, its roadmap.
  nlohmann::json segmentation_state() const;
  // The newest /imaging/segmentation message (the parameters and roadmaps in effect; version ≥ 1).
  std::shared_ptr<const std::string> latest_segmentation(std::uint64_t& version,
                                                         std::uint64_t& time_ns) const;
  static std::string segmentation_schema();

 private:
  struct PlaneState;
  Eigen::Vector2d to_plane_mm(int plane, const Eigen::Vector2d& px) const;
  Eigen::Vector2d to_pixels(int plane, const Eigen::Vector2d& mm) const;
  void fuse(int plane, const std::vector<Eigen::Vector3d>& model_backbone, std::uint64_t capture_ns);

  TrackingConfig config_;
  std::array<sim::SimulatedFluoroscope*, 2> planes_;
  std::uint64_t max_skew_ns_;
  teleop::perception::TipEkf ekf_;
  TrackingWarning warn_;
  TipListener listener_;
  std::array<std::unique_ptr<PlaneState>, 2> state_;
  std::array<bool, 2> simulated_;

  mutable std::mutex fuse_mutex_;  // the planes' published results, the disagreement count, the message
  std::array<PlaneTrack, 2> shared_;
  int disagreeing_ = 0, agreeing_ = 0;
  std::array<std::uint64_t, 2> updates_{}, evaluated_at_{};  // results per plane; at the last evaluation
  bool warned_ = false;
  std::shared_ptr<const std::string> message_;
  std::uint64_t version_ = 0, message_ns_ = 0;

  // The live edits (request_mutex_; never held while segmenting or rendering).
  struct Requests {
    teleop::perception::FluoroscopySegmentationParameters requested, applied;
    bool roadmap_pending = false;
    std::uint64_t roadmaps = 1;  // the one taken at construction counts (a source plane: 0, none yet)
    std::uint64_t roadmap_ns = 0;
  };
  void publish_segmentation(std::uint64_t time_ns);  // caller holds request_mutex_
  mutable std::mutex request_mutex_;
  std::array<Requests, 2> requests_;
  std::shared_ptr<const std::string> segmentation_message_;
  std::uint64_t segmentation_version_ = 0, segmentation_ns_ = 0;
};

}  // namespace tendril::server
