// The sensing-disk continuum robot (Abah 2022, ch. 3) as a robot type ("sdu_continuum"): one
// constant-curvature continuum segment on a rotary stage (three joints: stage roll, bending angle θ,
// bending plane δ) carrying five sensing disk units (SDU) with 8 ToF range sensors and 8 Hall sensors
// each, read over CAN at 100 Hz (tendril::continuum).
//
// Safety path: every motion of every mode (the core's move_jp and servo_jv included) passes the type's
// RobotController::limit_step, which caps the speed of the segment's sensor windows at the proximity
// law's limit (Abah 2022, eq. 3.4: 50 mm/s to 0.25 mm/s over d_max); the SduSupervisor's hold causes
// (contact, a silent disk, an unusable Hall reading, a drifting Hall baseline, unbiasing) hold the robot in
// the same control cycle, an unusable ToF reading slows it to the safe speed. Ways out of a contact hold: the
// contact-based guidance yielding to the push and the 1-DoF no-slip roll (eq. 3.6).
//
// Modes: the core's joint mode, guidance (the HRI laws of eqs. 3.8–3.9 on the top disk) and tip (CRTK
// servo_cv of the top disk's position).
//
// Hardware: the joints are CiA 402 drives on the robot file's bus; the disks are CAN nodes on the same
// bus (frames 0x680–0x6A7, sdu_frames.hpp). On a virtual bus the drives are the core's SIMULATED
// drives and the disks are SIMULATED disk nodes (SduSimulation) that ray-cast a configurable scene
// (planes, boxes, a cylinder standing for a human arm that the API can move).
//
// Threads: the bus thread reassembles the disks' frames and hands the newest samples over a
// LatestValue (single writer, never waits); the control thread runs SduController and publishes
// SduSnapshot; the mapping thread (SduMapper) builds the voxel map and planes and publishes /sdu/map
// and /sdu/planes; network threads read settings, the snapshot and the mapper (sdu_api.cpp).
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <Eigen/Geometry>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_perception.hpp"
#include "tendril/continuum/sdu_safety.hpp"
#include "tendril/continuum/sdu_segment.hpp"
#include "tendril/continuum/sdu_simulation.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/server/robot_type.hpp"

namespace tendril::server {

class SduContinuum;

// Joint order of an sdu_continuum robot file.
inline constexpr std::size_t kStageRoll = 0, kBending = 1, kBendingPlane = 2, kSduJoints = 3;
inline constexpr std::size_t kSdus = continuum::kSdusPerSegment;

// The type's modes after the core's joint mode: the top disk moves by the selected HRI law (guidance),
// or by the operator's CRTK servo_cv of the tip (tip).
inline constexpr ModeId kGuidanceMode = kFirstPluginMode;
inline constexpr ModeId kTipMode = kFirstPluginMode + 1;

enum class SduCommand : std::uint16_t { hri_mode, roll, unbias, servo_cv };

struct SduSceneArm {  // the SIMULATED cylinder standing for a human arm
  Eigen::Vector3d axis = Eigen::Vector3d::UnitX();
  double radius_mm = 25.4;
  double half_length_mm = 300.0;
  Eigen::Vector3d start = Eigen::Vector3d(0.0, -300.0, 250.0);
  Eigen::Vector3d end = Eigen::Vector3d(0.0, -120.0, 250.0);
  double speed_mm_s = 20.0;
};

struct SduSimulationSettings {
  std::uint64_t seed = 1;
  continuum::TofModel tof;
  continuum::HallModel hall;
  std::vector<continuum::ScenePlane> planes;
  std::vector<continuum::SceneBox> boxes;
  std::optional<SduSceneArm> arm;
};

struct SduSettings {
  continuum::SduSegmentModel model;
  std::string bus;  // the bus of the disk nodes (the drives' bus)
  double rate_hz = 100.0;
  continuum::SduSupervisorParameters supervisor;
  continuum::GuidanceParameters guidance;
  continuum::GuidancePair guidance_pair;
  // Mapping (the plug-in's own thread).
  double voxel_mm = 10.0;
  std::size_t map_capacity = 100'000;
  continuum::RansacParameters ransac;
  continuum::BracingParameters bracing;
  std::size_t max_planes = 4;
  double map_publish_period_s = 0.5;
  double extract_period_s = 2.0;
  SduSimulationSettings simulation;
};

// Parses the robot file's "continuum" section against its joints (throws ConfigError naming file and key).
SduSettings parse_sdu_settings(const RobotConfig& config);

// Where the segment is for given joint values (stage roll, θ, δ).
continuum::SegmentConfiguration segment_configuration(std::span<const double> q) noexcept;

// The newest sample of every disk, handed from the bus thread to the control and mapping threads.
struct SduSamples {
  std::array<continuum::SduSample, kSdus> disk{};
  std::uint64_t frames = 0, samples = 0, incomplete = 0, malformed = 0;
};

// What the control thread publishes every tick for the API and the mapper (trivially copyable).
struct SduSnapshot {
  std::uint64_t tick = 0;
  std::int64_t now_ns = 0;
  std::array<double, kSduJoints> q{};  // measured joint values
  continuum::SduSafetyState state = continuum::SduSafetyState::kUnbiasing;
  continuum::SduCause cause = continuum::SduCause::kUnbiasing;
  int cause_disk = -1, cause_slot = -1;
  double cause_value = 0.0;
  double speed_limit_mm_s = 0.0;
  double nearest_mm = 0.0;          // nearest effective distance (d_max when nothing is near)
  double step_kept = 1.0;           // fraction of the last commanded step the filter kept
  double surface_speed_mm_s = 0.0;  // the fastest sensor window's commanded speed after the filter
  bool contact = false;
  int contact_disk = -1, contact_slot = -1;
  double contact_force_n = 0.0;
  continuum::GuidanceMode hri = continuum::GuidanceMode::kOff;
  double guidance_mm_s = 0.0;
  bool rolling = false;
  std::array<bool, kSdus> fresh{};
  std::array<std::array<double, 8>, kSdus> forces_n{};
  std::array<std::int64_t, kSdus> age_ns{};
  char reason[160] = {};
};

// Planes of the map, handed from the mapping thread to the control thread (supervisor's (3.5)).
struct SduPlaneSet {
  std::size_t count = 0;
  std::array<std::array<double, 4>, continuum::SduSupervisor::kMaxPlanes> plane{};  // n, offset
  double inlier_mm = 40.0;
};

// The type's part of the control cycle (control thread only): no allocation, no locks.
class SduController final : public RobotController {
 public:
  explicit SduController(SduContinuum& robot);
  void sense(ControlContext& ctx) noexcept override;
  void control(ControlContext& ctx) noexcept override;
  bool while_held(ControlContext& ctx) noexcept override;
  void apply(ControlContext& ctx, const PluginCommand& command) noexcept override;
  bool moving(const ControlContext& ctx) const noexcept override;
  bool hold_cleared(const ControlContext& ctx, char* why, std::size_t why_size) const noexcept override;
  double limit_step(ControlContext& ctx, std::span<const double> before) noexcept override;
  void publish(const ControlContext& ctx) noexcept override;

 private:
  // Joint rates that move the top disk's centre (or a disk frame's twist) as asked, by damped least
  // squares on the numerical Jacobian of the disk pose.
  Eigen::Vector3d rates_for_velocity(std::span<const double> q, std::size_t disk,
                                     const Eigen::Vector3d& v) const noexcept;
  Eigen::Vector3d rates_for_twist(std::span<const double> q, std::size_t disk,
                                  const Eigen::Matrix<double, 6, 1>& twist) const noexcept;
  // Fastest sensor-window displacement between two joint vectors (mm).
  double max_window_step(std::span<const double> a, std::span<const double> b) const noexcept;
  void integrate(ControlContext& ctx, const Eigen::Vector3d& rates) noexcept;

  SduContinuum& robot_;
  continuum::SduSupervisor supervisor_;
  SduSamples samples_{};
  std::array<Eigen::Isometry3d, kSdus> poses_{};
  std::uint64_t planes_version_ = 0;
  continuum::GuidanceMode hri_ = continuum::GuidanceMode::kOff;
  double guidance_mm_s_ = 0.0;
  double roll_rate_ = 0.0;
  double roll_until_ = -1.0;
  Eigen::Vector3d tip_velocity_ = Eigen::Vector3d::Zero();  // servo_cv, mm/s in {0}
  double last_stream_ = -1.0;
  double step_kept_ = 1.0;
  double surface_speed_ = 0.0;
  std::uint64_t tick_ = 0;
};

// The backbone (shape) and the top disk (tip) for the API and the scene.
class SduKinematics final : public RobotKinematics {
 public:
  SduKinematics(const continuum::SduSegmentModel& model, std::string frame)
      : model_(model), frame_(std::move(frame)) {}
  std::string frame() const override { return frame_; }
  std::vector<Eigen::Vector3d> shape(std::span<const double> q) const override;
  Pose tip(std::span<const double> q) const override;

 private:
  continuum::SduSegmentModel model_;
  std::string frame_;
};

// The SIMULATED disk nodes on a virtual bus: each 1/rate_hz, at the disk poses the SIMULATED drives'
// true joint positions give, every disk reads the scene and sends its 7 frames on its own endpoint.
// Faults for tests (any thread): a silent disk, a corrupt ToF or Hall reading, a Hall baseline drift.
class SduSimulation final : public sim::Plant {
 public:
  SduSimulation(const SduSettings& settings, std::array<sim::SimulatedCia402Drive*, kSduJoints> drives,
                std::array<std::unique_ptr<can::Bus>, kSdus> endpoints);
  void step(double dt) noexcept override;

  enum class ArmAction : int { hold = 0, approach = 1, retreat = 2 };
  // Moves the SIMULATED arm (network thread): towards its end point, back to its start, or to its start at
  // once.
  void arm_command(ArmAction action, double speed_mm_s) noexcept;
  void arm_reset() noexcept {
    action_.store(static_cast<int>(ArmAction::hold));
    reset_.store(true);
  }
  bool has_arm() const noexcept { return arm_index_.has_value(); }
  Eigen::Vector3d arm_centre() const noexcept {
    const auto c = arm_centre_.load();
    return {c[0], c[1], c[2]};
  }
  ArmAction arm_action() const noexcept { return static_cast<ArmAction>(action_.load()); }

  void set_silent(std::size_t disk, bool silent) noexcept;
  // A ToF reading replaced by `mm` (NaN: not finite, sent as the sensor-error code); NaN slot < 0 clears.
  void set_tof_fault(std::size_t disk, int slot, double mm) noexcept;
  void set_hall_fault(std::size_t disk, int slot) noexcept;  // slot < 0 clears
  void set_hall_drift(std::size_t disk, double mT_per_s) noexcept;
  // The largest true force on any Hall window in the last sample (N), for tests.
  double true_max_force() const noexcept { return true_force_.load(); }
  std::uint64_t samples_sent() const noexcept { return sent_.load(); }  // disk samples taken

 private:
  SduSettings settings_;
  std::array<sim::SimulatedCia402Drive*, kSduJoints> drives_;
  std::array<std::unique_ptr<can::Bus>, kSdus> endpoints_;
  continuum::Scene scene_;
  std::vector<continuum::SimulatedSduNode> nodes_;
  std::optional<std::size_t> arm_index_;
  double t_ = 0.0;
  std::array<double, kSdus> next_sample_{};
  std::array<double, kSdus> strongest_{};
  Eigen::Vector3d arm_ = Eigen::Vector3d::Zero();
  hardware::LatestValue<std::array<double, 3>> arm_centre_;
  std::atomic<int> action_{0};
  std::atomic<double> arm_speed_{20.0};
  std::atomic<bool> reset_{false};
  std::array<std::atomic<bool>, kSdus> silent_{};
  std::array<std::atomic<int>, kSdus> tof_fault_slot_{};
  std::array<std::atomic<double>, kSdus> tof_fault_mm_{};
  std::array<std::atomic<int>, kSdus> hall_fault_slot_{};
  std::array<std::atomic<double>, kSdus> hall_drift_{};
  std::atomic<double> true_force_{0.0};
  std::atomic<std::uint64_t> sent_{0};
};

// The mapping thread: ToF ranges to points in {0} through the disk poses, the voxel map, RANSAC planes
// and the bracing verdict, and the /sdu/map and /sdu/planes topics.
class SduMapper final : public TopicSource {
 public:
  SduMapper(SduContinuum& robot, const SduSettings& settings);
  ~SduMapper() override;
  void start();  // the thread (not in stepped simulation: tests call poll())
  void stop();
  // One pass: new samples into the map; the cloud and the planes when due. Mapping thread or tests.
  void poll(double now_s);

  struct Extraction {
    bool ok = false;
    std::string error;  // for a person, when not ok
    std::string error_code;
    std::size_t points = 0;
    std::vector<continuum::PlaneFit> planes;
    continuum::BracingResult bracing;
  };
  Extraction extract();  // fits planes now and publishes them (any thread but the control thread)
  void clear();          // forgets the map (planes too)
  struct Status {
    std::size_t points = 0, planes = 0;
    std::uint64_t points_in = 0, refused_full = 0;
    bool extracted = false, admissible = false;
    std::string reason;
    double points_per_s = 0.0;
  };
  Status status() const;

  std::vector<TopicInfo> topics() const override;
  std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const override;
  void set_ready_callback(std::function<void()> ready) override;

 private:
  void publish_cloud(const std::vector<Eigen::Vector3d>& points);
  void publish_planes(const Extraction& e, const std::vector<Eigen::Vector3d>& points);
  void put(const std::string& topic, std::string payload);

  SduContinuum& robot_;
  const SduSettings& settings_;
  std::mutex extract_mutex_;  // extract() and clear(): one at a time
  mutable std::mutex mutex_;  // the map, the verdict and the payloads
  continuum::VoxelMap map_;
  std::array<std::int64_t, kSdus> last_stamp_{};
  Status status_{};
  std::vector<Eigen::Vector3d> scratch_ = std::vector<Eigen::Vector3d>(continuum::kTofPerSdu);
  double next_cloud_ = 0.0, next_extract_ = 0.0;
  std::size_t published_points_ = 0;
  double rate_window_start_ = -1.0;
  std::uint64_t rate_window_points_ = 0;
  struct Slot {
    std::shared_ptr<const std::string> payload;
    std::uint64_t version = 0;
    std::uint64_t log_time_ns = 0;
  };
  Slot cloud_, planes_;
  std::function<void()> ready_;
  std::thread thread_;
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
};

class SduContinuum final : public RobotPlugin {
 public:
  SduContinuum(const RobotConfig& config, RobotAssembly& assembly);
  ~SduContinuum() override;

  const RobotKinematics& kinematics() const override { return kinematics_; }
  std::vector<ModeInfo> modes() const override;
  RobotController& controller() override { return controller_; }
  std::optional<ServiceError> resume_refusal(const OperatingStateView& state) const override;
  // CRTK servo_cv of the tip (the top disk) in mode tip; its three joints place the tip, so the angular
  // part must be zero. move_cp and servo_cp are not offered.
  bool cartesian() const override { return true; }
  Result<std::pair<PluginCommand, double>> cartesian_command(CartesianKind kind, const CartesianPose& pose,
                                                             const CartesianTwist& twist,
                                                             const OperatingStateView& state) const override;
  void start() override;
  void stop() override;
  std::vector<std::shared_ptr<TopicSource>> topic_sources() override { return {mapper_}; }
  std::unique_ptr<RobotApiExtension> api(RobotService& service,
                                         std::function<bool(const PluginCommand&)> post) override;

  const RobotConfig& config() const noexcept { return config_; }
  const SduSettings& settings() const noexcept { return settings_; }
  SduSnapshot snapshot() const noexcept { return published_.load(); }
  SduSamples samples() const noexcept { return samples_.load(); }
  SduSimulation* simulation() noexcept { return simulation_.get(); }
  SduMapper& mapper() noexcept { return *mapper_; }
  const continuum::SduBusLoad& bus_load() const noexcept { return bus_load_; }

 private:
  friend class SduController;
  friend class SduMapper;
  RobotConfig config_;
  SduSettings settings_;
  SduKinematics kinematics_;
  continuum::SduFrameAssembler assembler_;  // bus thread only
  continuum::SduBusLoad bus_load_;
  hardware::LatestValue<SduSamples> samples_;
  hardware::LatestValue<SduPlaneSet> planes_;
  hardware::LatestValue<SduSnapshot> published_;
  // The SDU robots' disk buses in this process (a second SDU robot on one bus is refused).
  static std::mutex& buses_mutex();
  static std::vector<std::pair<std::string, std::string>>& buses_in_use();  // bus, robot
  std::string bus_key() const;
  bool registered_ = false;
  bool stepped_ = false;
  std::unique_ptr<SduSimulation> simulation_;
  std::shared_ptr<SduMapper> mapper_;
  SduController controller_{*this};
};

std::unique_ptr<RobotApiExtension> make_sdu_api(SduContinuum& robot,
                                                std::function<bool(const PluginCommand&)> post);

}  // namespace tendril::server
