// The sdu_continuum robot type and the building of one robot: its settings, kinematics, the disk nodes
// on the drives' CAN bus (frames reassembled on the bus thread), the SIMULATED disk nodes on a virtual
// bus, and the mapping thread. The control cycle is in sdu_controller.cpp, the mapping in
// sdu_mapper.cpp, the API in sdu_api.cpp.
#include "sdu_continuum/sdu_robot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

#include "sdu_continuum/sdu_continuum_schema.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"
#include "tendril/server/config_reader.hpp"
#include "tendril/server/robot_api_extension.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {

namespace {

using detail::Reader;
using detail::vector3;
namespace cont = tendril::continuum;

class SduContinuumType final : public RobotType {
 public:
  std::string kind() const override { return "sdu_continuum"; }
  std::string description() const override {
    return "continuum segment on a rotary stage with five sensing disk units (Abah 2022, ch. 3): proximity "
           "speed scaling, stop on contact, HRI guidance, ToF mapping; disks on CAN (SIMULATED on a "
           "virtual bus)";
  }
  nlohmann::json settings_schema() const override {
    static const nlohmann::json schema = nlohmann::json::parse(schema_files::k_sdu_continuum);
    return schema;
  }
  std::unique_ptr<RobotPlugin> create(const RobotConfig& config, RobotAssembly& assembly) const override {
    return std::make_unique<SduContinuum>(config, assembly);
  }
};

cont::SurfaceFinish finish(const Reader& r) {
  const std::string f = r.string_or("finish", "matte");
  if (f == "matte") return cont::SurfaceFinish::kMatte;
  if (f == "glossy") return cont::SurfaceFinish::kGlossy;
  r.fail("finish", "\"matte\" or \"glossy\"", r.raw("finish"));
  return cont::SurfaceFinish::kMatte;
}

}  // namespace

void register_sdu_continuum(RobotTypes& types) { types.add(std::make_unique<SduContinuumType>()); }

cont::SegmentConfiguration segment_configuration(std::span<const double> q) noexcept {
  cont::SegmentConfiguration c;
  if (q.size() < kSduJoints) return c;
  c.stage_roll_rad = q[kStageRoll];
  c.bending_rad = std::max(0.0, q[kBending]);
  c.bending_plane_rad = q[kBendingPlane];
  return c;
}

SduSettings parse_sdu_settings(const RobotConfig& rc) {
  const std::string file = rc.file.string();
  SduSettings s;
  static const char* names[] = {"stage_roll", "bending", "bending_plane"};
  if (rc.joints.size() != kSduJoints)
    throw ConfigError(file +
                      ": joints: expected 3 joints for an sdu_continuum (stage_roll, bending, "
                      "bending_plane), got " +
                      std::to_string(rc.joints.size()));
  for (std::size_t i = 0; i < kSduJoints; ++i) {
    if (rc.joints[i].name() != names[i])
      throw ConfigError(file + ": joints[" + std::to_string(i) + "].name: expected \"" + names[i] +
                        "\" (the order the segment model uses), got \"" + rc.joints[i].name() + "\"");
    if (rc.joints[i].unit() != "rad")
      throw ConfigError(file + ": joints[" + std::to_string(i) + "].unit: expected \"rad\", got \"" +
                        rc.joints[i].unit() + "\"");
  }
  if (rc.joints[kBending].limit.lower < 0.0)
    throw ConfigError(file +
                      ": joints[1].lower: expected at least 0 (the bending angle θ is not signed; the "
                      "bending plane δ gives the direction)");

  const nlohmann::json empty = nlohmann::json::object();
  const auto it = rc.settings.find("continuum");
  const Reader c(it != rc.settings.end() ? *it : empty, file, "continuum");
  if (c.has("segment")) {
    const Reader g = c.child("segment");
    s.model.length_mm = g.positive_or("length_mm", s.model.length_mm);
    s.model.disk_radius_mm = g.positive_or("disk_radius_mm", s.model.disk_radius_mm);
    if (g.has("disk_arc_mm")) {
      const auto& a = g.array("disk_arc_mm", true);
      if (a.size() != kSdus) g.fail("disk_arc_mm", "five arc lengths (mm), one per disk", a);
      for (std::size_t i = 0; i < kSdus; ++i) {
        if (!a[i].is_number()) g.fail("disk_arc_mm", "five numbers", a);
        s.model.disk_arc_mm[i] = a[i].get<double>();
      }
    }
    s.model.max_bending_rad = g.positive_or("max_bending_rad", s.model.max_bending_rad);
  }
  try {
    s.model.validate();
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": continuum.segment: " + e.what());
  }
  if (rc.joints[kBending].limit.upper > s.model.max_bending_rad)
    throw ConfigError(file + ": joints[1].upper: expected at most continuum.segment.max_bending_rad (" +
                      std::to_string(s.model.max_bending_rad) + " rad)");

  const Reader d = c.child("disks");
  s.bus = d.string("bus");
  s.rate_hz = d.positive_or("rate_hz", s.rate_hz);
  if (s.rate_hz > 1000.0) d.fail("rate_hz", "at most 1000 (the simulation steps at 1 kHz)", d.raw("rate_hz"));

  auto& p = s.supervisor;
  if (c.has("safety")) {
    const Reader f = c.child("safety");
    p.proximity.v_max_mm_s = f.positive_or("v_max_mm_s", p.proximity.v_max_mm_s);
    p.proximity.v_min_mm_s = f.positive_or("v_min_mm_s", p.proximity.v_min_mm_s);
    p.proximity.d_max_mm = f.positive_or("d_max_mm", p.proximity.d_max_mm);
    if (p.proximity.v_min_mm_s >= p.proximity.v_max_mm_s)
      f.fail("v_min_mm_s", "less than v_max_mm_s", f.raw("v_min_mm_s"));
    p.stale_after_ns = static_cast<std::int64_t>(f.positive_or("stale_ms", 30.0) * 1e6);
    p.unbias_samples = static_cast<std::size_t>(
        f.integer_in_or("unbias_samples", 1, 10000, static_cast<long>(p.unbias_samples)));
    p.contact_threshold_n = f.positive_or("contact_threshold_n", p.contact_threshold_n);
    p.contact_release_n = f.positive_or("contact_release_n", p.contact_release_n);
    if (p.contact_release_n >= p.contact_threshold_n)
      f.fail("contact_release_n", "less than contact_threshold_n", f.raw("contact_release_n"));
    p.drift_bound_mT = f.positive_or("drift_bound_mT", p.drift_bound_mT);
    p.drift_time_s = f.positive_or("drift_time_s", p.drift_time_s);
    p.retreat_speed_mm_s = f.positive_or("retreat_speed_mm_s", p.retreat_speed_mm_s);
  }
  if (static_cast<double>(p.stale_after_ns) * 1e-9 < 1.5 / s.rate_hz)
    throw ConfigError(file +
                      ": continuum.safety.stale_ms: expected at least 1.5 sample periods of "
                      "continuum.disks.rate_hz, or every disk reads as silent");
  if (c.has("guidance")) {
    const Reader g = c.child("guidance");
    s.guidance.gain = g.positive_or("gain_mm_s_per_mm", s.guidance.gain);
    s.guidance.contact_gain = g.positive_or("contact_gain_mm_s_per_mT", s.guidance.contact_gain);
    s.guidance.deadband_mm = g.non_negative_or("deadband_mm", s.guidance.deadband_mm);
    s.guidance.contact_deadband_mT = g.non_negative_or("contact_deadband_mT", s.guidance.contact_deadband_mT);
    s.guidance.max_speed_mm_s = g.positive_or("max_speed_mm_s", s.guidance.max_speed_mm_s);
  }
  if (c.has("mapping")) {
    const Reader m = c.child("mapping");
    s.voxel_mm = m.positive_or("voxel_mm", s.voxel_mm);
    s.map_capacity = static_cast<std::size_t>(m.integer_in_or("capacity", 1, 10'000'000, 100'000));
    s.ransac.inlier_distance_mm = m.positive_or("inlier_distance_mm", s.ransac.inlier_distance_mm);
    s.ransac.min_inliers = static_cast<std::size_t>(m.integer_in_or("min_inliers", 3, 1'000'000, 30));
    s.max_planes = static_cast<std::size_t>(m.integer_in_or("max_planes", 1, 8, 4));
    s.bracing.patch_side_mm = m.positive_or("bracing_patch_mm", s.bracing.patch_side_mm);
    s.map_publish_period_s = m.positive_or("publish_period_s", s.map_publish_period_s);
    s.extract_period_s = m.positive_or("extract_period_s", s.extract_period_s);
    if (m.has("reference_normal")) s.ransac.reference_normal = vector3(m, "reference_normal", {});
  }

  if (c.has("simulation")) {
    const Reader sim = c.child("simulation");
    auto& x = s.simulation;
    x.seed = static_cast<std::uint64_t>(sim.integer_in_or("seed", 0, 1L << 40, 1));
    x.tof.noise_sd_mm = sim.non_negative_or("tof_noise_sd_mm", x.tof.noise_sd_mm);
    x.hall.noise_sd_mT = sim.non_negative_or("hall_noise_sd_mT", x.hall.noise_sd_mT);
    x.hall.sleeve_stiffness_N_per_mm =
        sim.positive_or("sleeve_stiffness_n_per_mm", x.hall.sleeve_stiffness_N_per_mm);
    if (sim.has("planes"))
      for (std::size_t i = 0; i < sim.array("planes", false).size(); ++i) {
        const Reader e = sim.element("planes", i);
        cont::ScenePlane plane;
        plane.point = vector3(e, "point_mm", plane.point);
        plane.normal = vector3(e, "normal", plane.normal);
        if (plane.normal.norm() < 1e-9) e.fail("normal", "a non-zero vector", e.raw("normal"));
        plane.normal.normalize();
        plane.finish = finish(e);
        x.planes.push_back(plane);
      }
    if (sim.has("boxes"))
      for (std::size_t i = 0; i < sim.array("boxes", false).size(); ++i) {
        const Reader e = sim.element("boxes", i);
        cont::SceneBox box;
        box.pose.translation() = vector3(e, "centre_mm", Eigen::Vector3d::Zero());
        box.pose.linear() =
            Eigen::AngleAxisd(e.number_or("yaw_rad", 0.0), Eigen::Vector3d::UnitZ()).toRotationMatrix();
        box.half_extent_mm = vector3(e, "half_extent_mm", box.half_extent_mm);
        if ((box.half_extent_mm.array() <= 0.0).any())
          e.fail("half_extent_mm", "three positive half extents", e.raw("half_extent_mm"));
        box.finish = finish(e);
        x.boxes.push_back(box);
      }
    if (sim.has("arm")) {
      const Reader a = sim.child("arm");
      SduSceneArm arm;
      arm.axis = vector3(a, "axis", arm.axis);
      if (arm.axis.norm() < 1e-9) a.fail("axis", "a non-zero vector", a.raw("axis"));
      arm.axis.normalize();
      arm.radius_mm = a.positive_or("radius_mm", arm.radius_mm);
      arm.half_length_mm = a.positive_or("half_length_mm", arm.half_length_mm);
      arm.start = vector3(a, "start_mm", arm.start);
      arm.end = vector3(a, "end_mm", arm.end);
      arm.speed_mm_s = a.positive_or("speed_mm_s", arm.speed_mm_s);
      x.arm = arm;
    }
  }
  return s;
}

// ---- kinematics -------------------------------------------------------------------------------------

std::vector<Eigen::Vector3d> SduKinematics::shape(std::span<const double> q) const {
  std::vector<Eigen::Vector3d> points;
  if (q.size() < kSduJoints) return points;
  const auto config = segment_configuration(q);
  constexpr int kPoints = 38;  // every 10 mm of the 370 mm segment
  for (int k = 0; k <= kPoints; ++k)
    points.push_back(cont::backbone_pose(model_, config, model_.length_mm * k / kPoints).translation());
  return points;
}

Pose SduKinematics::tip(std::span<const double> q) const {
  Pose p;
  if (q.size() < kSduJoints) return p;
  const auto t = cont::backbone_pose(model_, segment_configuration(q), model_.length_mm);
  p.position = t.translation();
  p.orientation = Eigen::Quaterniond(t.linear());
  return p;
}

// ---- the SIMULATED disk nodes ----------------------------------------------------------------------

SduSimulation::SduSimulation(const SduSettings& settings,
                             std::array<sim::SimulatedCia402Drive*, kSduJoints> drives,
                             std::array<std::unique_ptr<can::Bus>, kSdus> endpoints)
    : settings_(settings), drives_(drives), endpoints_(std::move(endpoints)) {
  const auto& x = settings_.simulation;
  for (const auto& p : x.planes) scene_.add(p);
  for (const auto& b : x.boxes) scene_.add(b);
  if (x.arm) {
    cont::SceneCylinder cylinder;
    cylinder.centre = x.arm->start;
    cylinder.axis = x.arm->axis;
    cylinder.radius_mm = x.arm->radius_mm;
    cylinder.half_length_mm = x.arm->half_length_mm;
    arm_index_ = scene_.add(cylinder);
    arm_ = x.arm->start;
    arm_speed_.store(x.arm->speed_mm_s);
  }
  arm_centre_.store({arm_.x(), arm_.y(), arm_.z()});
  nodes_.reserve(kSdus);
  for (std::size_t i = 0; i < kSdus; ++i)
    nodes_.emplace_back(settings_.model, x.tof, x.hall, x.seed + 7919 * i);
  for (std::size_t i = 0; i < kSdus; ++i) {
    tof_fault_slot_[i].store(-1);
    hall_fault_slot_[i].store(-1);
    next_sample_[i] = static_cast<double>(i) / (static_cast<double>(kSdus) * settings_.rate_hz);
  }
}

void SduSimulation::arm_command(ArmAction action, double speed_mm_s) noexcept {
  if (std::isfinite(speed_mm_s) && speed_mm_s > 0.0) arm_speed_.store(speed_mm_s);
  action_.store(static_cast<int>(action));
}

void SduSimulation::set_silent(std::size_t disk, bool silent) noexcept {
  if (disk < kSdus) silent_[disk].store(silent);
}
void SduSimulation::set_tof_fault(std::size_t disk, int slot, double mm) noexcept {
  if (disk >= kSdus) return;
  tof_fault_mm_[disk].store(mm);
  tof_fault_slot_[disk].store(slot);
}
void SduSimulation::set_hall_fault(std::size_t disk, int slot) noexcept {
  if (disk < kSdus) hall_fault_slot_[disk].store(slot);
}
void SduSimulation::set_hall_drift(std::size_t disk, double mT_per_s) noexcept {
  if (disk < kSdus) hall_drift_[disk].store(mT_per_s);
}

void SduSimulation::step(double dt) noexcept {
  if (!(dt > 0.0)) return;
  t_ += dt;
  // Frames other nodes send reach these endpoints too: drop them (the disks listen to nothing).
  for (auto& e : endpoints_)
    while (e->receive(std::chrono::nanoseconds(0))) {
    }
  // The arm: a person's forearm moving at a steady speed towards the segment or away.
  if (arm_index_ && settings_.simulation.arm) {
    const auto& a = *settings_.simulation.arm;
    bool moved = false;
    if (reset_.exchange(false)) {  // arm_reset() stopped it already; a later command may move it on
      arm_ = a.start;
      moved = true;
    }
    const auto action = static_cast<ArmAction>(action_.load());
    if (action != ArmAction::hold) {
      moved = true;
      const Eigen::Vector3d target = action == ArmAction::approach ? a.end : a.start;
      const Eigen::Vector3d to = target - arm_;
      const double step = arm_speed_.load() * dt;
      if (to.norm() <= step) {
        arm_ = target;
        action_.store(static_cast<int>(ArmAction::hold));
      } else {
        arm_ += to.normalized() * step;
      }
    }
    if (moved) {
      scene_.move_cylinder(*arm_index_, arm_);
      arm_centre_.store({arm_.x(), arm_.y(), arm_.z()});
    }
  }
  // Each disk's microcontroller runs its own 100 Hz timer, the five staggered over the period (their
  // clocks are not synchronised); it also spreads the ray casting over the simulation's 1 kHz steps,
  // so that no one step of the bus thread carries all five disks.
  const double period = 1.0 / settings_.rate_hz;
  bool any = false;
  for (std::size_t i = 0; i < kSdus; ++i) any = any || t_ + 1e-9 >= next_sample_[i];
  if (!any) return;
  // The disks read where the segment truly is: the SIMULATED drives' load positions.
  std::array<double, kSduJoints> q{};
  for (std::size_t j = 0; j < kSduJoints; ++j) q[j] = drives_[j]->truth().position;
  const auto poses = cont::disk_poses(settings_.model, segment_configuration(q));
  for (std::size_t i = 0; i < kSdus; ++i) {
    if (t_ + 1e-9 < next_sample_[i]) continue;
    next_sample_[i] += period;
    if (next_sample_[i] < t_) next_sample_[i] = t_ + period;
    nodes_[i].hall().drift_mT_per_s = hall_drift_[i].load();
    cont::SduSample sample = nodes_[i].sense(scene_, poses[i], t_);
    strongest_[i] = 0.0;
    for (double f : nodes_[i].true_force()) strongest_[i] = std::max(strongest_[i], f);
    sent_.fetch_add(1);
    if (silent_[i].load()) continue;
    if (const int slot = tof_fault_slot_[i].load(); slot >= 0 && slot < static_cast<int>(cont::kTofPerSdu)) {
      const double mm = tof_fault_mm_[i].load();
      sample.tof_mm[static_cast<std::size_t>(slot)] = mm;
      // A value the wire cannot carry is what a broken sensor sends: its error code.
      sample.tof_status[static_cast<std::size_t>(slot)] = std::isfinite(mm) && mm >= 0.0 && mm <= 253.0
                                                              ? cont::TofStatus::kValid
                                                              : cont::TofStatus::kSensorError;
    }
    if (const int slot = hall_fault_slot_[i].load();
        slot >= 0 && slot < static_cast<int>(cont::kHallPerSdu)) {
      sample.hall_ok[static_cast<std::size_t>(slot)] = false;
      sample.hall_mT[static_cast<std::size_t>(slot)][2] = std::numeric_limits<double>::quiet_NaN();
    }
    for (const auto& frame : cont::encode_sdu_sample(i, sample)) endpoints_[i]->send(frame);
  }
  true_force_.store(*std::max_element(strongest_.begin(), strongest_.end()));
}

// ---- the robot --------------------------------------------------------------------------------------

SduContinuum::SduContinuum(const RobotConfig& rc, RobotAssembly& assembly)
    : config_(rc),
      settings_(parse_sdu_settings(rc)),
      kinematics_(settings_.model, rc.name + "_base"),
      assembler_(kSdus, static_cast<std::int64_t>(0.8e9 / settings_.rate_hz)) {
  const std::string file = rc.file.string();
  if (!assembly.joints())
    throw ConfigError(file +
                      ": joints: an sdu_continuum's joints are CiA 402 drives; give each a \"drive\" "
                      "section on continuum.disks.bus");
  for (std::size_t j = 0; j < kSduJoints; ++j)
    if (assembly.joint_bus(j) != settings_.bus)
      throw ConfigError(file + ": continuum.disks.bus: expected the bus of the drives ('" +
                        assembly.joint_bus(j) + "'), got '" + settings_.bus + "'");
  stepped_ = assembly.stepped();
  auto bus = assembly.bus(settings_.bus);
  try {
    // The disks send on their own timer, not on the CANopen SYNC: the master's SYNC is counted already.
    std::uint32_t bitrate = 1'000'000;
    for (const auto& b : rc.buses)
      if (b.name == settings_.bus) bitrate = b.bitrate;
    bus_load_ = cont::estimate_sdu_bus_load(bitrate, settings_.rate_hz, kSdus, false);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": continuum.disks: " + e.what());
  }
  bus.add_load(bus_load_.bits_per_second,
               "5 sensing disk units at " + std::to_string(settings_.rate_hz) + " Hz");
  bus.listen([this](const can::Frame& frame, std::chrono::steady_clock::time_point now) {
    const std::int64_t now_ns =
        std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
    const auto before = assembler_.counters().samples;
    if (!assembler_.handle(frame, now_ns) || assembler_.counters().samples == before) return;
    SduSamples out;
    for (std::size_t i = 0; i < kSdus; ++i) out.disk[i] = assembler_.latest(i);
    const auto& k = assembler_.counters();
    out.frames = k.frames;
    out.samples = k.samples;
    out.incomplete = k.incomplete;
    out.malformed = k.malformed;
    samples_.store(out);
  });
  if (bus.simulated) {
    std::array<sim::SimulatedCia402Drive*, kSduJoints> drives{};
    for (std::size_t j = 0; j < kSduJoints; ++j) {
      drives[j] = assembly.simulated_drive(j);
      if (!drives[j])
        throw ConfigError(file + ": joints[" + std::to_string(j) +
                          "].drive: the SIMULATED disks need the SIMULATED drives on the virtual bus");
    }
    std::array<std::unique_ptr<can::Bus>, kSdus> endpoints;
    for (std::size_t i = 0; i < kSdus; ++i)
      endpoints[i] = bus.attach("sim:" + rc.name + "/sdu" + std::to_string(i));
    try {
      simulation_ = std::make_unique<SduSimulation>(settings_, drives, std::move(endpoints));
    } catch (const std::invalid_argument& e) {
      throw ConfigError(file + ": continuum.simulation: " + e.what());
    }
    bus.add_plant(simulation_.get());
  }
  // On a real bus the disks' own microcontrollers send the same frames (sdu_frames.hpp).
  try {
    mapper_ = std::make_shared<SduMapper>(*this, settings_);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(file + ": continuum.mapping: " + e.what());
  }
  SduSnapshot initial;
  for (std::size_t j = 0; j < kSduJoints; ++j) initial.q[j] = rc.joints[j].initial_position;
  published_.store(initial);
  // The disks' frame ids depend on the disk index only: two SDU robots on one bus would read each
  // other's disks as their own. Refused here (the last step, so that a refusal leaves nothing claimed).
  std::lock_guard lock(buses_mutex());
  for (const auto& [name, robot] : buses_in_use())
    if (name == bus_key()) {
      std::string message = file;
      message += ": continuum.disks.bus: robot '";
      message += robot;
      message += "' has its sensing disks on bus '";
      message += settings_.bus;
      message +=
          "' already; the disks' frame ids (0x680 + 8 x disk) would clash: give each SDU robot a bus "
          "of its own";
      throw ConfigError(message);
    }
  buses_in_use().emplace_back(bus_key(), rc.name);
  registered_ = true;
}

SduContinuum::~SduContinuum() {
  if (mapper_) mapper_->stop();
  if (!registered_) return;
  std::lock_guard lock(buses_mutex());
  auto& in_use = buses_in_use();
  for (auto it = in_use.begin(); it != in_use.end(); ++it)
    if (it->first == bus_key() && it->second == config_.name) {
      in_use.erase(it);
      break;
    }
}

std::mutex& SduContinuum::buses_mutex() {
  static std::mutex m;
  return m;
}
std::vector<std::pair<std::string, std::string>>& SduContinuum::buses_in_use() {
  static std::vector<std::pair<std::string, std::string>> in_use;
  return in_use;
}
std::string SduContinuum::bus_key() const {
  // One server per process: the bus names of the robots alive now (a runtime destroys its robots before
  // the next one is built, as tests do).
  return settings_.bus;
}

void SduContinuum::start() {
  // In stepped simulation nothing runs on its own clock: tests call mapper().poll().
  if (!stepped_) mapper_->start();
}
void SduContinuum::stop() { mapper_->stop(); }

std::vector<ModeInfo> SduContinuum::modes() const {
  return {
      {"guidance",
       "the top disk moves by the selected HRI law (hri_mode): contactless v = γ(d_r − d_l) or contact-based "
       "v = γ(ΔB_z,r − ΔB_z,l); proximity scaling and stop on contact apply as in every mode"},
      {"tip",
       "CRTK servo_cv of the tip (the top disk), linear mm/s in the base frame, resolved by damped least "
       "squares; proximity scaling and stop on contact apply as in every mode"}};
}

Result<std::pair<PluginCommand, double>> SduContinuum::cartesian_command(
    CartesianKind kind, const CartesianPose& pose, const CartesianTwist& twist,
    const OperatingStateView& state) const {
  (void)pose;
  const std::string& robot = config_.name;
  if (kind != CartesianKind::servo_cv)
    return ServiceError{ErrorKind::not_supported, "not_supported",
                        "robot '" + robot +
                            "' takes servo_cv only: its three joints place the tip, they cannot also hold an "
                            "orientation, so move_cp and servo_cp poses are not offered"};
  if (state.mode != "tip")
    return ServiceError{ErrorKind::conflict, "wrong_mode",
                        "robot '" + robot + "' is in " + state.mode +
                            " mode; switch to tip mode (POST /api/v1/robots/" + robot +
                            "/mode {\"mode\": \"tip\"}) for servo_cv"};
  if (!twist.linear.allFinite() || !twist.angular.allFinite())
    return ServiceError{ErrorKind::invalid, "bad_twist", "servo_cv: the twist must be finite"};
  if (twist.angular.norm() > 0.0)
    return ServiceError{ErrorKind::invalid, "bad_twist",
                        "servo_cv: robot '" + robot +
                            "' steers its tip's position only (three joints); send angular [0, 0, 0]"};
  PluginCommand c;
  c.id = static_cast<std::uint16_t>(SduCommand::servo_cv);
  c.count = 3;
  for (Eigen::Index i = 0; i < 3; ++i) c.values[static_cast<std::size_t>(i)] = twist.linear[i];
  return std::pair{c, 0.0};
}

std::optional<ServiceError> SduContinuum::resume_refusal(const OperatingStateView& state) const {
  if (state.state != safety::OperatingState::kPaused) return std::nullopt;
  const auto s = snapshot();
  using cont::SduSafetyState;
  if (s.state == SduSafetyState::kClear || s.state == SduSafetyState::kSlowed) return std::nullopt;
  std::string next;
  switch (s.cause) {
    case cont::SduCause::kContact:
      next = "move the object away, or roll along it (POST /api/v1/robots/" + config_.name +
             "/roll), then resume";
      break;
    case cont::SduCause::kBaselineDrift:
      next = "take the sleeve clear of every object and re-zero the Hall sensors (POST /api/v1/robots/" +
             config_.name + "/unbias), then resume";
      break;
    case cont::SduCause::kUnbiasing:
      next = "wait until the Hall baseline is collected (half a second at rest), then resume";
      break;
    default:
      next = "check the disk's cable and sensors; resume once it reads again";
      break;
  }
  return ServiceError{ErrorKind::conflict, "hold_not_cleared",
                      "cannot resume robot '" + config_.name + "': " + s.reason + "; " + next};
}

std::unique_ptr<RobotApiExtension> SduContinuum::api(RobotService& service,
                                                     std::function<bool(const PluginCommand&)> post) {
  (void)service;
  return make_sdu_api(*this, std::move(post));
}

}  // namespace tendril::server
