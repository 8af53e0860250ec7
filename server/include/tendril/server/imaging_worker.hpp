// ImagingWorker: tendrild's bi-plane imaging, published as WebSocket topics. Each plane's frames come
// from its source: the SIMULATED fluoroscope (the default), a video capture device or video file, or a
// folder of image files replayed at a set rate (imaging::ImageSource).
//
// Two threads (one per plane, AP and lateral) run only while the plane's topic has a subscriber
// (set_demand; an unwatched plane sleeps and costs nothing). A simulated plane exposes on a common
// schedule at `fps`: it reads the robot's backbone through RobotService::shape (the runtime snapshot;
// never the RT thread) and renders it with sim::SimulatedFluoroscope; another plane takes its source's
// frames as they come. Each frame is JPEG-encoded and put, as a serialised foxglove.CompressedImage,
// into a latest-value slot that the front end shares with every subscriber:
//   /imaging/ap, /imaging/lateral  foxglove.CompressedImage (JSON, data base64), frame_id imaging_ap|lateral
//   /maps/vessel                   foxglove.PointCloud of the vessel wall (float32 x,y,z), frame "world"
//   /imaging/tracking              tendril.TipTracking (BiplaneTipTracker): each simulated plane's
//                                  segmented and EKF-filtered tip, the 3D tip from both, the model's tip
//                                  and their disagreement; tracking runs only while this topic has a
//                                  subscriber or the imaged robot demands it (set_image_feedback), and
//                                  makes both simulated planes render
// Each image message also carries "overlay": {"robot": [[column, row], …], "plan": [[column, row], …],
// "segmented": [[column, row], …], "tip": [column, row] or null} (the last two while the tracking runs),
// the imaged robot's model backbone and the plan's path projected with the plane's own geometry
// (pixels of the frame, row 0 at the top), so a console draws them over the image without knowing
// the projection (foxglove.CompressedImage readers ignore the extra field).
// For a source other than the simulator the overlay uses the configured geometry: it lies on the
// image only when that geometry is the C-arm's (calibrate it; a replay of tendril's own simulated
// frames matches by construction).
// A watchdog thread warns the imaged robot's operator (set_warning_sink) when a watched plane's frames
// stop for longer than `stale_after_s`, when they come again, when frames are dropped (at most one
// warning a second, with the count) and when a replay ends. Imaging never waits on control, nor
// control on imaging: the warnings go through the robot's command mailbox.
// The message's timestamp is the capture time: the wall-clock instant the exposure started (the
// backbone was sampled), or for other sources the instant the frame was received. The WebSocket message
// header carries the log time: when the encoded frame was ready to send (their difference is the render +
// encode time).
#pragma once

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/drivers/imaging/image_source.hpp"
#include "tendril/drivers/sim/simulated_fluoroscope.hpp"
#include "tendril/safety/safety_types.hpp"
#include "tendril/server/control_api.hpp"
#include "tendril/server/image_feedback.hpp"
#include "tendril/server/image_tracking.hpp"
#include "tendril/server/imaging_control.hpp"
#include "tendril/server/robot_service.hpp"
#include "tendril/server/topic_source.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {

enum class ImageSourceKind : std::uint8_t {
  kSimulated,  // sim::SimulatedFluoroscope renders the imaged robot's backbone
  kVideo,      // imaging::open_video_capture: a V4L2 device (/dev/videoN) or a video file
  kFiles,      // imaging::open_image_files: a folder of images (or one image) replayed at `fps`
};

// Where one plane's frames come from: imaging.sources.ap / imaging.sources.lateral.
struct PlaneSourceConfig {
  ImageSourceKind kind = ImageSourceKind::kSimulated;
  std::filesystem::path path;  // kVideo, kFiles
  double fps = 0.0;            // kVideo: 0 = the file's own rate; kFiles: the replay rate
  bool loop = true;            // replays start again at their end
};

struct ImagingConfig {
  bool enabled = false;
  std::string robot;  // whose backbone is imaged; empty = the first robot
  double fps = 15.0;
  int jpeg_quality = 80;
  sim::FluoroscopeOptions
      fluoroscope;  // geometry (width, height, SID, SOD, pixel spacing, isocentre), physics
  std::vector<sim::VesselTube> vessels;      // contrast-filled branches, world frame (mm)
  std::string vessel_source;                 // where the vessel came from, for the start-up message
  std::array<PlaneSourceConfig, 2> sources;  // [0] AP, [1] lateral
  double stale_after_s = 1.0;                // a watched plane without a frame for longer is stale
  TrackingConfig tracking;                   // imaging.tracking: segmentation, tip EKF, 3D tip
};

// Reads the "imaging" object of the server file (`imaging` may be null: imaging off). Relative paths
// resolve against the server file's folder. The vessel is load_scene_vessel's with no "scene" (tendrild
// then replaces it with the scene's, placed at the imaged robot's vessel entry). Throws ConfigError
// naming the file and key.
ImagingConfig parse_imaging_config(const nlohmann::json& imaging, const std::filesystem::path& server_file);

// The one vessel of a server's world: contact, imaging, the vessel map and the 3D view all use it.
struct SceneVessel {
  std::vector<teleop::CenterlinePolyline> branches;  // in the vessel file's own frame (mm); empty = none
  std::string source;                                // where it came from, for messages
  std::string robot;                                 // whose vessel entry places it; empty = the first
};
// Reads the server file's "scene": {"vessel": CSV (x,y,z[,r] mm) or false, "robot": name}. Without
// "scene", the older "imaging.vessel" key; without either, <config>/vessels/synthetic_ica.csv when it
// exists, else teleop::make_synthetic_ica(1) generated here. Throws ConfigError naming the file and key.
SceneVessel load_scene_vessel(const nlohmann::json& scene, const nlohmann::json& imaging,
                              const std::filesystem::path& server_file);
// Contrast-filled tubes for the fluoroscope from centerline branches (2 mm where a branch has no radii).
std::vector<sim::VesselTube> vessel_tubes(const std::vector<teleop::CenterlinePolyline>& branches);

// "simulated", "video" or "files".
const char* source_kind_name(ImageSourceKind kind) noexcept;

// A warning for the imaged robot's operator: the cause and a message for a person.
using ImagingWarningSink = std::function<void(safety::FaultCode code, const std::string& text)>;

// Fills `out` with the imaged robot's backbone (world mm, base to tip); false when unavailable.
// Called from the imaging threads.
using BackboneReader = std::function<bool(std::vector<Eigen::Vector3d>& out)>;

// The backbone of `robot` (empty: the first robot) through ControlApi::shape, i.e. the runtime's
// latest snapshot. Throws ConfigError for an unknown robot.
BackboneReader backbone_from(const RobotService& service, std::string robot);

class ImagingWorker final : public TopicSource, public ImagingControl {
 public:
  // Throws sim::FluoroscopeError for an unusable geometry, ConfigError for a source that cannot be
  // opened (naming imaging.sources.<plane> and why).
  ImagingWorker(BackboneReader read_backbone, ImagingConfig config);
  ~ImagingWorker() override;
  ImagingWorker(const ImagingWorker&) = delete;
  ImagingWorker& operator=(const ImagingWorker&) = delete;

  // What is drawn over the images besides the imaged robot's backbone: the plan's path (world mm, e.g.
  // the planned tip of each step of the loaded path; false or empty = none). Call before start().
  void set_plan_reader(BackboneReader read_plan) { read_plan_ = std::move(read_plan); }
  // Where the watchdog's warnings go (stale, dropped, ended). Call before start().
  void set_warning_sink(ImagingWarningSink sink) { warn_ = std::move(sink); }
  // The imaged robot's use of the images (null: none): it receives every 3D tip of the tracking, may
  // demand tracking, and a simulated plane renders its imaged_backbone() (the simulated plant's true
  // shape) where it has one, while the overlay and the tracker's model stay the model's. Call before
  // start(). Without tracking (imaging.tracking.enabled false) only the rendering applies.
  void set_image_feedback(ImageFeedback* feedback);
  // Where each plane's frames come from, for the start-up message.
  std::string describe_sources() const;

  void start();
  void stop();  // joins the threads; safe to call twice

  std::vector<TopicInfo> topics() const override;
  // The vessel wall points of /maps/vessel (mm, world frame); empty without a configured vessel.
  const std::vector<Eigen::Vector3f>& vessel_wall() const noexcept { return vessel_wall_; }
  std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const override;
  void set_ready_callback(std::function<void()> ready) override;
  // A plane renders only while wanted; when it stops being wanted its last frame is dropped, so that a
  // later subscriber never gets an old exposure as if it were current.
  void set_demand(const std::string& topic, bool wanted) override;
  std::string metrics() const override;

  // Renders and publishes one frame of each simulated plane now (tests; the threads need not run).
  void capture_once();

  // The segmentation editor and roadmaps (ImagingControl); 503 when the tracking is off, 409 for a
  // plane fed by a source (it is not tracked). Changes are applied by the plane's thread at its next
  // frame and then published on /imaging/segmentation.
  std::string imaged_robot() const override { return config_.robot; }
  ApiResult segmentation() const override;
  ApiResult set_segmentation(const std::string& plane, const nlohmann::json& changes) override;
  ApiResult take_roadmap(const std::string& plane) override;

 private:
  struct Plane;
  void run_simulated(Plane& plane, std::chrono::steady_clock::time_point first);
  void run_source(Plane& plane);
  void watch();
  void capture(Plane& plane, std::uint64_t capture_ns);
  void publish(Plane& plane, std::uint64_t capture_ns, const std::vector<std::uint8_t>& jpeg, bool shape_ok,
               double render_s, double encode_s, const PlaneTrack* track);
  void update_wanted();  // caller holds run_mutex_
  void read_overlay(Plane& plane, bool& shape_ok);
  void warn(safety::FaultCode code, const std::string& text) const;
  void announce();

  BackboneReader read_backbone_;
  BackboneReader read_plan_;
  ImagingWarningSink warn_;
  std::unique_ptr<BiplaneTipTracker> tracker_;  // null: tracking off
  bool tracking_wanted_ = false;                // guarded by run_mutex_: /imaging/tracking has a subscriber
  bool feedback_wanted_ = false;                // guarded by run_mutex_: the imaged robot demands tracking
  ImageFeedback* feedback_ = nullptr;
  ImagingConfig config_;
  std::array<std::unique_ptr<Plane>, 2> planes_;
  std::vector<Eigen::Vector3f> vessel_wall_;  // set in the constructor, then constant
  std::shared_ptr<const std::string> vessel_cloud_;
  std::uint64_t vessel_time_ns_ = 0;

  mutable std::mutex ready_mutex_;  // held while calling ready_ (see HttpServer::start)
  std::function<void()> ready_;

  std::mutex run_mutex_;
  std::condition_variable run_wake_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

// Standard base64 (RFC 4648, with padding), appended to `out`.
void append_base64(const std::uint8_t* data, std::size_t size, std::string& out);

}  // namespace tendril::server
