// The us_arm's ultrasound imaging and reconstruction topics (issue 17, Heunis et al. 2021, Fig. 7): a
// TopicSource with its own worker thread (never the control thread) that reads the probe state the sweep
// publishes (ultrasound_probe_state.hpp, SerialArm::probe_state()), feeds an
// ultrasound::UltrasoundReconstructionSession and publishes
//   /{robot}/ultrasound/image        foxglove.CompressedImage, PNG, base64 in JSON; the SIMULATED B-mode
//                                    slice while the probe is in contact, only while someone watches;
//   /{robot}/ultrasound/annotations  foxglove.ImageAnnotations (JSON): the fitted ellipse (LINE_LOOP),
//                                    its centre and a text line, in that image's pixels;
//   /{robot}/reconstruction          foxglove.SceneUpdate in frame "tissue" (the limb's frame, so the view
//                                    is tissue-stabilised): surface, ct_centerline, via_points, probe,
//                                    contours, artery_mesh, catheter, contacts, curvature_warnings;
//   /tf                              foxglove.FrameTransforms: world→{robot}_base,
//   {robot}_base→{robot}_probe,
//                                    world→tissue, {robot}_probe→{robot}_image, world→fbg.
// Message layouts are in teleop/ultrasound_arm/README.md ("Imaging and reconstruction topics").
//
// Acquisitions are never missed: a light poller thread reads the probe state every 10 ms and latches
// the first state of each acquisition (gate open at a via-point), which the worker then images and
// stores even when a step took longer than the gate stays open (rendering in a sanitized build).
//
// Threads: the worker (and the poller) run at a lower CPU priority (nice +10), so that on a loaded
// machine the imaging yields to the control and simulation threads. The worker owns the session; the sweep
// (any thread) hands it a plan or a reset through set_plan()/reset(), which the worker picks up at its next
// step; the front end reads the newest serialised messages through latest() (one mutex, held only to swap a
// shared pointer).
#pragma once

#include <Eigen/Geometry>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "serial_arm/ultrasound_probe_state.hpp"
#include "tendril/server/topic_source.hpp"
#include "tendril/ultrasound/reconstruction_session.hpp"

namespace tendril::server {

struct UltrasoundTopicsSettings {
  std::string robot = "us_arm";  // topic prefix and frame names
  double image_hz = 15.0;        // worker steps: images, annotations and /tf (the contract's 10–20 Hz)
  double catheter_hz = 5.0;      // FBG frames
  double scene_hz = 2.0;         // /reconstruction while watched (at once, too, on a new slice or plan)
  Eigen::Isometry3d world_T_base = Eigen::Isometry3d::Identity();  // the arm's base in the world
  // Polled at each /tf (optional): the arm's base in the world now (the us_arm: the calibrated H_B^G of
  // the robot calibration in use); when set it replaces world_T_base.
  std::function<Eigen::Isometry3d()> world_T_base_reader;
  std::size_t max_surface_points = 600;  // the scene's skin cloud, evenly thinned to this many
  bool own_thread = true;                // false: the caller drives step() (tests)
  // Polled by the worker at each step (optional): a plan pointer it has not seen is set (and the
  // slices of the previous plan are forgotten: a new plan is a new sweep). The alternative to set_plan().
  std::function<std::shared_ptr<const ultrasound::SweepPlan>()> plan_reader;
  // Polled by the worker at each step (optional): the image-to-probe calibration (H_I^U, s_u, s_v) and
  // the catheter's H_F^C in use, each with its version; a version it has not applied is handed to the
  // session (slices from then on are mapped with it; the stored ones stay as they were mapped).
  std::function<std::optional<std::pair<int, ultrasound::ImageCalibration>>()> image_calibration_reader;
  std::function<std::optional<std::pair<int, Eigen::Isometry3d>>()> fiber_calibration_reader;
};

class UltrasoundTopics final : public TopicSource {
 public:
  using ProbeStateReader = std::function<std::optional<UltrasoundProbeState>()>;

  // Throws ultrasound::UltrasoundSetupError for a session that cannot be set up and std::invalid_argument
  // for rates that are not positive and finite or a reader that is empty.
  UltrasoundTopics(ultrasound::ReconstructionSessionConfig session, UltrasoundTopicsSettings settings,
                   ProbeStateReader probe_state);
  ~UltrasoundTopics() override;
  UltrasoundTopics(const UltrasoundTopics&) = delete;
  UltrasoundTopics& operator=(const UltrasoundTopics&) = delete;

  // A new plan (sweep "plan"): seeds, CT centerline, via-points and surface of the scene. Throws
  // ultrasound::PlanningInputError for a plan the session refuses (checked here, on the caller's thread).
  void set_plan(ultrasound::SweepPlan plan);
  // Forget the slices, mesh and catheter (a new sweep).
  void reset();

  // One worker step at wall-clock `now_ns`: read the probe state, image/segment/store, the catheter,
  // and publish what is due. The worker thread calls it; tests call it directly (own_thread = false).
  void step(std::uint64_t now_ns);
  // What the poller does every 10 ms: read the probe state and latch it if it opens an acquisition
  // (tests call it directly).
  void poll_once();

  std::vector<TopicInfo> topics() const override;
  std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const override;
  void set_ready_callback(std::function<void()> ready) override;
  void set_demand(const std::string& topic, bool wanted) override;
  std::string metrics() const override;

  // For tests and the sweep's state: slices stored so far and the last refusal's sentence.
  std::size_t slices() const noexcept { return slices_.load(std::memory_order_relaxed); }
  // The calibration versions the session maps with (0: the configured ones), for tests and the state.
  int image_calibration_version() const noexcept { return image_version_.load(std::memory_order_relaxed); }
  int fiber_calibration_version() const noexcept { return fiber_version_.load(std::memory_order_relaxed); }
  // The session's newest stored slice centroid in the tissue frame (tests: the calibration in use shows
  // there); nullopt before the first.
  std::optional<Eigen::Vector3d> last_slice_centroid() const;
  std::string last_message() const;

  // Topic names.
  std::string image_topic() const { return "/" + settings_.robot + "/ultrasound/image"; }
  std::string annotations_topic() const { return "/" + settings_.robot + "/ultrasound/annotations"; }
  std::string scene_topic() const { return "/" + settings_.robot + "/reconstruction"; }
  static std::string tf_topic() { return "/tf"; }

 private:
  void run();
  void poll();
  void latch(const UltrasoundProbeState& state);
  void apply_calibrations();  // worker: the readers' new versions into the session
  void publish(const std::string& topic, std::string message, std::uint64_t now_ns);
  bool wanted(const std::string& topic) const;
  std::string image_message(const ultrasound::SessionFrame& frame, std::uint64_t now_ns) const;
  std::string annotations_message(const ultrasound::SessionFrame& frame, std::uint64_t now_ns) const;
  std::string scene_message(const UltrasoundProbeState& state, std::uint64_t now_ns) const;
  std::string tf_message(const UltrasoundProbeState& state, std::uint64_t now_ns) const;

  UltrasoundTopicsSettings settings_;
  ProbeStateReader probe_state_;
  ultrasound::UltrasoundReconstructionSession session_;  // the worker's alone

  // Hand-over from set_plan()/reset() to the worker.
  std::mutex pending_mutex_;
  std::optional<ultrasound::SweepPlan> pending_plan_;
  bool pending_reset_ = false;
  std::vector<UltrasoundProbeState> pending_acquisitions_;  // latched, in order
  int last_latched_via_point_ = -1;                         // −1: none since the last plan or reset

  // Published messages and demand (front end and worker).
  mutable std::mutex topics_mutex_;
  std::map<std::string, TopicPayload> latest_;
  std::map<std::string, bool> demand_;
  std::function<void()> ready_;
  std::string last_message_;
  std::uint64_t images_ = 0, refusals_ = 0;
  double last_step_s_ = 0.0;

  // Worker state.
  std::shared_ptr<const ultrasound::SweepPlan> seen_plan_;
  std::uint64_t next_catheter_ns_ = 0, next_scene_ns_ = 0, scene_revision_ = ~0ULL;
  std::uint64_t last_frame_stamp_ = 0;
  std::atomic<std::size_t> slices_{0};
  std::atomic<int> image_version_{0}, fiber_version_{0};
  std::optional<Eigen::Vector3d> last_centroid_;  // guarded by topics_mutex_
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
  std::thread worker_;
  std::thread poller_;
};

class SerialArm;
// The us_arm's topics (helper usimg's hook-up, called from SerialArm::topic_sources()): the session
// images the SIMULATED limb's artery, with a SIMULATED catheter lying along it (a 200 mm straight
// lead-in, then the artery's centerline); the probe state and the plan come from the arm. Null without
// the file's "ultrasound" section. The arm must outlive the topics (tendrild stops its front end, which
// holds them, before the runtime).
std::shared_ptr<UltrasoundTopics> make_us_arm_topics(const SerialArm& arm);

}  // namespace tendril::server
