// The serial arm's robot type and the building of one arm: settings, model, the SIMULATED arm, force
// sensor and tissue at the hardware seam, and the network-thread side of its Cartesian commands
// (checks, the move_cp dry run). The control cycle is in serial_arm_controller.cpp, the API in
// serial_arm_api.cpp.
#include "serial_arm/serial_arm_robot.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <utility>

#include "serial_arm/force_topic.hpp"
#include "serial_arm/serial_arm_schema.hpp"
#include "serial_arm/ultrasound_topics.hpp"
#include "tendril/server/config_reader.hpp"
#include "tendril/server/robot_api_extension.hpp"
#include "tendril/server/robot_types.hpp"
#include "tendril/ultrasound/hand_eye.hpp"

namespace tendril::server {

namespace {

using detail::Reader;
using detail::vector3;

class SerialArmType final : public RobotType {
 public:
  std::string kind() const override { return "serial_arm"; }
  std::string description() const override {
    return "six-joint serial arm (UR5 geometry, Heunis et al. 2021): velocity-commanded joints, CRTK "
           "Cartesian "
           "commands, "
           "3-axis force sensor; SIMULATED (a real UR5 would be RTDE over Ethernet)";
  }
  nlohmann::json settings_schema() const override {
    static const nlohmann::json schema = nlohmann::json::parse(schema_files::k_serial_arm);
    return schema;
  }
  std::unique_ptr<RobotPlugin> create(const RobotConfig& config, RobotAssembly& assembly) const override {
    return std::make_unique<SerialArm>(config, assembly);
  }
};

std::string format(const char* fmt, double a, double b = 0.0) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, a, b);
  return buf;
}

}  // namespace

void register_serial_arm(RobotTypes& types) { types.add(std::make_unique<SerialArmType>()); }

const char* to_string(ArmMotion motion) noexcept {
  switch (motion) {
    case ArmMotion::none:
      return "none";
    case ArmMotion::move_cp:
      return "move_cp";
    case ArmMotion::servo_cp:
      return "servo_cp";
    case ArmMotion::servo_cv:
      return "servo_cv";
  }
  return "none";
}

ArmSettings parse_arm_settings(const RobotConfig& rc) {
  const std::string file = rc.file.string();
  ArmSettings s;
  if (rc.joints.size() != teleop::kArmJoints)
    throw ConfigError(file + ": joints: expected 6 joints for a serial_arm (base to wrist 3), got " +
                      std::to_string(rc.joints.size()));
  for (std::size_t i = 0; i < rc.joints.size(); ++i)
    if (rc.joints[i].unit() != "rad")
      throw ConfigError(file + ": joints[" + std::to_string(i) +
                        "].unit: expected \"rad\" (a serial_arm's joints are "
                        "revolute), got \"" +
                        rc.joints[i].unit() + "\"");
  const nlohmann::json empty = nlohmann::json::object();
  const auto it = rc.settings.find("arm");
  const Reader arm(it != rc.settings.end() ? *it : empty, file, "arm");
  s.model = arm.string_or("model", "ur5");
  if (s.model != "ur5") arm.fail("model", "\"ur5\" (the one arm geometry tendril knows)", arm.raw("model"));
  s.parameters = teleop::ur5_parameters();
  const teleop::SerialArmParameters hard = s.parameters;  // the arm's own ±360° limits
  s.parameters.tool.translation() = vector3(arm, "tool_offset_mm", Eigen::Vector3d::Zero());
  // The resolver's joint limits are the file's, inside the soft margin, so that the Cartesian modes stop
  // a joint where the core's clamp would (and never make it).
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) {
    const auto& j = rc.joints[i].limit;
    if (j.lower < hard.limits[i].lower || j.upper > hard.limits[i].upper)
      throw ConfigError(file + ": joints[" + std::to_string(i) + "]: expected limits within the UR5's " +
                        format("[%.4f, %.4f] rad", hard.limits[i].lower, hard.limits[i].upper) + ", got " +
                        format("[%.4f, %.4f]", j.lower, j.upper));
    if (j.max_velocity > hard.limits[i].max_velocity)
      throw ConfigError(file + ": joints[" + std::to_string(i) +
                        "].max_velocity: expected at most the UR5's " +
                        format("%.4f rad/s, got %.4f", hard.limits[i].max_velocity, j.max_velocity));
    s.parameters.limits[i] = {.lower = j.lower + j.soft_margin,
                              .upper = j.upper - j.soft_margin,
                              .max_velocity = j.max_velocity,
                              .max_acceleration = j.max_acceleration};
  }

  if (arm.has("cartesian")) {
    const Reader c = arm.child("cartesian");
    s.cartesian.max_linear_speed = c.positive_or("max_linear_speed_mm_s", s.cartesian.max_linear_speed);
    s.cartesian.max_angular_speed = c.positive_or("max_angular_speed_rad_s", s.cartesian.max_angular_speed);
    s.cartesian.max_linear_acceleration =
        c.positive_or("max_linear_acceleration_mm_s2", s.cartesian.max_linear_acceleration);
    s.cartesian.max_angular_acceleration =
        c.positive_or("max_angular_acceleration_rad_s2", s.cartesian.max_angular_acceleration);
    s.servo_cp_max_step_mm = c.positive_or("servo_cp_max_step_mm", s.servo_cp_max_step_mm);
    s.servo_cp_max_step_rad = c.positive_or("servo_cp_max_step_rad", s.servo_cp_max_step_rad);
    s.goal_tolerance_mm = c.positive_or("goal_tolerance_mm", s.goal_tolerance_mm);
    s.goal_tolerance_rad = c.positive_or("goal_tolerance_rad", s.goal_tolerance_rad);
  }
  // The pose law's caps are the Cartesian caps (Table 1 uses the same V_d and ω_d for both).
  s.gains.max_linear_speed = s.cartesian.max_linear_speed;
  s.gains.max_angular_speed = s.cartesian.max_angular_speed;
  if (arm.has("workspace_mm")) {
    const Reader w = arm.child("workspace_mm");
    s.workspace_min = vector3(w, "min", s.workspace_min);
    s.workspace_max = vector3(w, "max", s.workspace_max);
    for (Eigen::Index i = 0; i < 3; ++i)
      if (!(s.workspace_min[i] < s.workspace_max[i]))
        w.fail("max", "each coordinate greater than min's", w.raw("max"));
  }
  if (arm.has("force")) {
    const Reader f = arm.child("force");
    s.force_stale_s = f.positive_or("stale_ms", s.force_stale_s * 1e3) / 1e3;
    s.max_contact_force_n = f.positive_or("max_contact_force_n", s.max_contact_force_n);
    s.resume_contact_force_n = f.positive_or("resume_contact_force_n", 0.5 * s.max_contact_force_n);
    if (s.resume_contact_force_n >= s.max_contact_force_n)
      f.fail("resume_contact_force_n", "less than max_contact_force_n", f.raw("resume_contact_force_n"));
    s.retract_speed_mm_s = f.positive_or("retract_speed_mm_s", s.retract_speed_mm_s);
    if (s.retract_speed_mm_s > s.cartesian.max_linear_speed)
      f.fail("retract_speed_mm_s", "at most arm.cartesian.max_linear_speed_mm_s",
             f.raw("retract_speed_mm_s"));
    s.retract_max_mm = f.positive_or("retract_max_mm", s.retract_max_mm);
  }

  // The hardware. Only the SIMULATED arm exists: a real UR5 needs an RTDE driver (Ethernet), which
  // would provide the same JointInterface and ForceSensor.
  if (!arm.has("simulation"))
    throw ConfigError(
        file +
        ": arm.simulation: expected this section: tendril has no RTDE driver for a real UR5 yet, "
        "so the arm, its force sensor and the tissue are SIMULATED and configured here");
  const Reader sim = arm.child("simulation");
  std::array<double, teleop::kArmJoints> initial{};
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) initial[i] = rc.joints[i].initial_position;
  s.simulated_arm = sim::ur5_simulated_arm(initial);
  s.simulated_arm.name = "SIMULATED UR5 '" + rc.name + "'";
  auto& a = s.simulated_arm;
  a.controller_period = sim.positive_or("controller_period_ms", a.controller_period * 1e3) / 1e3;
  a.latency_periods = static_cast<int>(sim.integer_in_or("latency_periods", 0, 16, a.latency_periods));
  a.watchdog_timeout = sim.positive_or("watchdog_ms", a.watchdog_timeout * 1e3) / 1e3;
  a.switch_on_time = sim.positive_or("switch_on_ms", a.switch_on_time * 1e3) / 1e3;
  a.position_noise = sim.non_negative_or("position_noise_rad", a.position_noise);
  a.velocity_noise = sim.non_negative_or("velocity_noise_rad_s", a.velocity_noise);
  if (a.switch_on_time * 1e3 >= rc.enable_timeout_ms)
    sim.fail("switch_on_ms",
             "less than the file's enable_timeout_ms (" + std::to_string(rc.enable_timeout_ms) + ")",
             sim.raw("switch_on_ms"));
  auto& f = s.simulated_sensor;
  f.name = "SIMULATED force sensor of '" + rc.name + "'";
  const double noise = sim.non_negative_or("force_noise_n", f.noise[0]);
  f.noise = {noise, noise, noise};
  f.sample_rate = sim.positive_or("force_sample_rate_hz", f.sample_rate);
  f.latency = sim.non_negative_or("force_latency_ms", f.latency * 1e3) / 1e3;
  f.range = sim.positive_or("force_range_n", f.range);
  if (sim.has("contact_surface")) {
    const Reader c = sim.child("contact_surface");
    sim::ContactSurfaceParameters p;
    p.pose = Eigen::Isometry3d::Identity();
    p.pose.translation() = Eigen::Vector3d(0.0, 0.0, c.number("height_mm"));  // a level plane: the tissue top
    p.stiffness = c.positive_or("stiffness_n_per_mm", p.stiffness);
    p.damping = c.non_negative_or("damping_n_s_per_mm", p.damping);
    s.surface = p;
  }
  return s;
}

// ---- the display model ------------------------------------------------------------------------------

std::vector<Eigen::Vector3d> ArmDisplayModel::shape(std::span<const double> q) const {
  teleop::SerialArmData d = model_.make_data();
  std::vector<Eigen::Vector3d> points;
  if (q.size() != teleop::kArmJoints ||
      !model_.forward_kinematics(Eigen::Map<const teleop::ArmVector>(q.data()), d))
    return points;
  for (const auto& frame : d.frames) points.push_back(frame.translation());
  points.push_back(d.tool.translation());
  return points;
}

Pose ArmDisplayModel::tip(std::span<const double> q) const {
  teleop::SerialArmData d = model_.make_data();
  Pose p;
  if (q.size() != teleop::kArmJoints ||
      !model_.forward_kinematics(Eigen::Map<const teleop::ArmVector>(q.data()), d))
    return p;
  p.position = d.tool.translation();
  p.orientation = Eigen::Quaterniond(d.tool.linear());
  return p;
}

// ---- the robot --------------------------------------------------------------------------------------

SerialArm::SerialArm(const RobotConfig& rc, RobotAssembly& assembly)
    : config_(rc),
      settings_(parse_arm_settings(rc)),
      ultrasound_(parse_ultrasound_settings(rc)),
      model_([&] {
        try {
          teleop::validate(settings_.cartesian);
          teleop::validate(settings_.gains);
          return teleop::SerialArmKinematics(settings_.parameters);
        } catch (const std::invalid_argument& e) {
          throw ConfigError(rc.file.string() + ": arm: " + e.what());
        }
      }()),
      display_(model_, rc.name + "_base") {
  const std::string file = rc.file.string();
  if (assembly.joints())
    throw ConfigError(file +
                      ": joints: a serial_arm's joints have no CANopen drive (a UR5 is commanded over RTDE); "
                      "remove their \"drive\" sections");
  // Free space is a plane 10 m below the base: the sensor always has a surface to ask, and never meets it.
  sim::ContactSurfaceParameters surface;
  surface.pose = Eigen::Isometry3d::Identity();
  surface.pose.translation().z() = -10'000.0;
  if (settings_.surface) surface = *settings_.surface;
  if (ultrasound_) {
    // The SIMULATED limb is the tissue: its skin (a height map in the limb frame) is the contact surface,
    // moved with the limb by LimbMotion.
    if (settings_.surface)
      throw ConfigError(file +
                        ": arm.simulation.contact_surface: remove it: with an \"ultrasound\" section the "
                        "SIMULATED limb (ultrasound.limb) is the tissue");
    try {
      limb_ = std::make_unique<LimbSimulation>(ultrasound_->limb);
      sweep_ = std::make_unique<UltrasoundSweep>(*ultrasound_, settings_.gains, settings_.cartesian);
    } catch (const std::invalid_argument& e) {
      throw ConfigError(file + ": ultrasound: " + e.what());
    }
    surface = sim::ContactSurfaceParameters{};
    surface.pose = ultrasound_->limb.rest_pose;
    surface.stiffness = ultrasound_->limb.stiffness;
    surface.damping = ultrasound_->limb.damping;
    surface.height_map = limb_.get();
  }
  try {
    surface_ = std::make_unique<sim::ContactSurface>(surface);
    auto arm = std::make_unique<sim::SimulatedVelocityArm>(settings_.simulated_arm);
    auto sensor =
        std::make_unique<sim::SimulatedForceSensor>(*arm, model_, *surface_, settings_.simulated_sensor);
    arm_ = arm.get();
    sensor_ = sensor.get();
    sensor_name_ = sensor_->name();
    assembly.provide_joints(*arm_);
    // The limb first: in stepped simulation the force sensor then samples the skin where it is now.
    if (limb_)
      assembly.add_component(
          std::make_unique<LimbMotion>(*limb_, *surface_, "SIMULATED limb of '" + rc.name + "'"));
    // The arm before the sensor: in stepped simulation the sensor then samples the arm's new state.
    assembly.add_component(std::move(arm));
    // The SIMULATED sensor samples in the control thread, right before each cycle: in a thread of its
    // own, starved for 20 ms on a loaded shared host, it went silent and held a moving arm (a cold CI
    // run's sweep, two sanitized servers' calibrations) — a silence the real sensor, on its own
    // electronics, does not have. Its watchdog still holds on set_silent() (failure injection).
    assembly.add_component_in_control_thread(std::move(sensor));
  } catch (const sim::SimulationSetupError& e) {
    throw ConfigError(file + ": arm.simulation: " + e.what());
  }
  ArmSnapshot initial;
  for (std::size_t i = 0; i < teleop::kArmJoints; ++i) initial.setpoint[i] = rc.joints[i].initial_position;
  published_.store(initial);
  if (ultrasound_) set_up_calibrations();
}

namespace {

Eigen::Isometry3d pose_rpy(const Eigen::Vector3d& position, const Eigen::Vector3d& rpy) {
  Eigen::Isometry3d h = Eigen::Isometry3d::Identity();
  h.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  h.translation() = position;
  return h;
}

}  // namespace

void SerialArm::set_up_calibrations() {
  // The SIMULATED optical tracker defines {G} (ultrasound.simulation.tracker). Defaults: the arm's base
  // 1.2 m from its origin, turned 35° about the vertical and tilted 1–2° (a camera rig's frame is never
  // level with a robot's), the marker rigid body 60 mm behind the probe face, turned 10° (our choices:
  // the article gives none), and the errors of Heunis et al. 2021, §4.3.
  OpticalTrackerSettings t;
  t.global_T_base = pose_rpy({850.0, -620.0, 540.0}, {0.02, -0.03, 0.61});
  t.marker_T_probe = pose_rpy({5.0, -40.0, 60.0}, {0.1, 0.05, 0.17});
  const auto u = config_.settings.find("ultrasound");
  if (u != config_.settings.end() && u->contains("simulation") && (*u)["simulation"].contains("tracker")) {
    const Reader r = Reader(*u, config_.file.string(), "ultrasound").child("simulation").child("tracker");
    auto pose = [&](const char* key, const Eigen::Isometry3d& fallback) {
      if (!r.has(key)) return fallback;
      const Reader p = r.child(key);
      return pose_rpy(vector3(p, "position_mm", fallback.translation()),
                      vector3(p, "rpy_rad", Eigen::Vector3d::Zero()));
    };
    auto pair = [&](const char* key, double& mean, double& spread) {
      if (!r.has(key)) return;
      const auto& v = r.raw(key);
      if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number() ||
          v[0].get<double>() < 0 || v[1].get<double>() < 0)
        r.fail(key, "two numbers ≥ 0 (mean, spread)", v);
      mean = v[0].get<double>();
      spread = v[1].get<double>();
    };
    t.global_T_base = pose("base_in_global", t.global_T_base);
    t.marker_T_probe = pose("probe_in_marker", t.marker_T_probe);
    t.rate_hz = r.positive_or("rate_hz", t.rate_hz);
    pair("triangulation_error_mm", t.triangulation_mean_mm, t.triangulation_sd_mm);
    pair("robot_error_mm", t.robot_error_mean_mm, t.robot_error_sd_mm);
    t.rotation_noise_deg = r.non_negative_or("rotation_noise_deg", t.rotation_noise_deg);
    t.seed = static_cast<std::uint64_t>(r.integer_in_or("seed", 0, 1L << 40, static_cast<long>(t.seed)));
  }
  tracker_settings_ = t;
  tracker_ = std::make_unique<SimulatedOpticalTracker>(t);
  // Dwell 0.3 s at each pose (the arm's joints settle within it); the tracker may be silent 100 ms.
  calibration_motion_ = std::make_unique<CalibrationMotion>(settings_.cartesian, settings_.gains, 0.3, 0.1);
  try {
    store_ = std::make_unique<CalibrationStore>(default_calibration_directory(config_.name), config_.name);
    runner_ = std::make_unique<CalibrationRunner>(*store_);
    runner_->add(
        {"robot",
         "robot–world (hand-eye): H_B^G, the arm's base in the tracker's frame, and the marker→probe "
         "transform, from 12 poses near the current one",
         "POST /api/v1/robots/" + config_.name + "/calibrate {\"kind\":\"robot\"}", true},
        [this](const OperatingStateView& state) { return start_robot_calibration(state); });
    // The image-to-probe ("us", required by the sweep) and catheter mold calibrations (helper uscal).
    us_calibrations_ = std::make_unique<UltrasoundCalibrations>(
        config_.name, *runner_, UltrasoundCalibrationSimulation::standard(),
        [this]() -> std::optional<std::string> {
          const SweepPhase phase = sweep_snapshot().phase;
          if (phase == SweepPhase::idle || phase == SweepPhase::planned || phase == SweepPhase::done ||
              phase == SweepPhase::aborted)
            return std::nullopt;
          return std::string("calibrate: the sweep is using the probe (phase ") + to_string(phase) +
                 "); abort it (POST …/sweep {\"action\":\"abort\"}) before calibrating the image";
        });
  } catch (const CalibrationStoreError& e) {
    throw ConfigError(config_.file.string() + ": ultrasound: " + e.what());
  }
  for (const auto& problem : store_->problems()) std::fprintf(stderr, "tendrild: %s\n", problem.c_str());
  publish_calibration_in_use();
}

void SerialArm::publish_calibration_in_use() {
  BaseCalibration b;
  if (store_) {
    if (const auto current = store_->current("robot")) {
      const auto it = current->transforms.find("H_B^G");
      if (it != current->transforms.end()) {
        b.valid = true;
        b.global_T_base = to_array(it->second);
      }
    }
  }
  std::lock_guard lock(worker_mutex_);
  base_calibration_.store(b);
}

SerialArm::~SerialArm() {
  stopping_.store(true);
  std::thread worker;
  {
    std::lock_guard lock(worker_mutex_);
    worker = std::move(worker_);
  }
  if (worker.joinable()) worker.join();
}

std::optional<std::string> SerialArm::start_robot_calibration(const OperatingStateView& state) {
  const std::string& robot = config_.name;
  const SweepSnapshot sweep = sweep_published_.load();
  const SweepPhase phase = sweep.phase;
  if (phase == SweepPhase::pre_positioning || phase == SweepPhase::ready ||
      phase == SweepPhase::approaching || phase == SweepPhase::acquiring || phase == SweepPhase::moving ||
      phase == SweepPhase::paused)
    return "calibrate: the sweep is " + std::string(to_string(phase)) +
           "; abort it first (POST /api/v1/robots/" + robot + "/sweep {\"action\":\"abort\"})";
  if (state.state != safety::OperatingState::kEnabled)
    return "calibrate: robot '" + robot + "' is " + std::string(safety::to_string(state.state)) +
           "; enable it (or resume it) first";
  if (!state.drives_ready)
    return "calibrate: robot '" + robot +
           "' is ENABLED but its drives are not ready yet; try again in a moment";
  if (state.mode != "cartesian")
    return "calibrate: robot '" + robot + "' is in " + state.mode +
           " mode; switch to cartesian mode (POST /api/v1/robots/" + robot +
           "/mode {\"mode\": \"cartesian\"}) first: the routine moves the probe through 12 poses near where "
           "it is";
  const ArmSnapshot arm = published_.load();
  if (arm.motion != ArmMotion::none)
    return "calibrate: a Cartesian " + std::string(to_string(arm.motion)) + " is running; wait for it to end";
  const double f = Eigen::Vector3d(arm.force_n[0], arm.force_n[1], arm.force_n[2]).norm();
  if (arm.force_valid && f > 0.3)
    return "calibrate: the probe touches something (" + format("%.2f N", f) +
           "); lift it off the skin first (the routine tilts it by 0.4 rad)";
  // The poses, checked before anything moves: inside the workspace box, and reachable from here.
  const teleop::ArmVector q0 = Eigen::Map<const teleop::ArmVector>(arm.setpoint.data());
  teleop::SerialArmData d = model_.make_data();
  if (!model_.forward_kinematics(q0, d)) return "calibrate: the arm's pose is not known";
  CalibrationPosesData poses;
  calibration_poses(d.tool, 12, 0.4, 10.0, poses);
  for (int i = 0; i < poses.count; ++i) {
    const Eigen::Isometry3d goal = to_isometry(poses.poses[static_cast<std::size_t>(i)]);
    const Eigen::Vector3d p = goal.translation();
    if ((p.array() < settings_.workspace_min.array()).any() ||
        (p.array() > settings_.workspace_max.array()).any())
      return "calibrate: pose " + std::to_string(i + 1) +
             " of the routine leaves the workspace box; move the probe "
             "farther inside it first";
    double duration = 0.0;
    if (auto why = dry_run(d.tool, q0, goal, duration))
      return "calibrate: pose " + std::to_string(i + 1) + " cannot be reached from here (" + why->message +
             "); move the probe to a more open pose first";
  }
  std::lock_guard lock(worker_mutex_);
  if (worker_.joinable()) worker_.join();  // the previous run's worker has finished (the runner allows one)
  poses.run = ++run_;
  calibration_poses_.store(poses);
  PluginCommand c;
  c.id = static_cast<std::uint16_t>(ArmCommand::calibration_start);
  c.count = 1;
  c.values[0] = static_cast<double>(poses.run);
  if (!post_ || !post_(c)) return "calibrate: the control thread's mailbox is full; try again";
  worker_ = std::thread([this, run = poses.run] { robot_calibration_worker(run); });
  return std::nullopt;
}

void SerialArm::robot_calibration_worker(std::uint32_t run) {
  using namespace std::chrono_literals;
  const auto started = std::chrono::steady_clock::now();
  CalibrationSnapshot s;
  for (;;) {
    if (stopping_.load()) {
      runner_->finish(false, 0, "robot calibration: the server is stopping");
      return;
    }
    s = calibration_published_.load();
    if (s.run == run) {
      if (s.phase == CalibrationPhase::collected || s.phase == CalibrationPhase::failed) break;
      runner_->progress(s.pose + 1, s.poses, s.message.data());
    } else if (std::chrono::steady_clock::now() - started > 3s) {
      runner_->finish(false, 0,
                      "robot calibration: the control thread did not start it (the robot's state or mode "
                      "changed before it arrived)");
      return;
    }
    std::this_thread::sleep_for(20ms);
  }
  if (s.phase == CalibrationPhase::failed) {
    runner_->finish(false, 0, std::string(s.message.data()) + "; the previous calibration stays in use");
    return;
  }
  runner_->progress(s.poses, s.poses, "solving A_k X = Y F_k");
  CalibrationPairsData pairs = calibration_pairs_.load();
  for (int tries = 0; pairs.run != run && tries < 100 && !stopping_.load(); ++tries) {
    std::this_thread::sleep_for(10ms);
    pairs = calibration_pairs_.load();
  }
  if (pairs.run != run) {
    runner_->finish(false, 0, "robot calibration: the recorded poses did not arrive");
    return;
  }
  std::vector<ultrasound::HandEyePair> input;
  input.reserve(static_cast<std::size_t>(pairs.count));
  for (int k = 0; k < pairs.count; ++k)
    input.push_back({to_isometry(pairs.tracked[static_cast<std::size_t>(k)]),
                     to_isometry(pairs.kinematic[static_cast<std::size_t>(k)])});
  const auto result = ultrasound::solve_hand_eye(input);
  if (!result.ok) {
    runner_->finish(false, 0, result.message + "; the previous calibration stays in use");
    return;
  }
  // Validation: the residual must stay within twice the error budget's quadrature sum (0.64 mm).
  constexpr double kAcceptRmsMm = 1.3;
  CalibrationRecord record;
  record.kind = "robot";
  record.method =
      "Heunis et al. 2021, §2.3: A_k X = Y F_k over " + std::to_string(result.pairs) +
      " poses (rotation: Park–Martin least squares in Procrustes form; translations: linear least squares; " +
      std::to_string(result.iterations) + " Gauss–Newton iterations); SIMULATED optical tracker";
  record.transforms["H_B^G"] = result.world_T_base;
  record.transforms["H_U^M"] = result.marker_T_probe;
  record.values["pairs"] = result.pairs;
  record.values["rotation_spread_rad"] = result.rotation_spread_rad;
  record.residual_mm = result.rms_position_mm;
  record.residuals = {{"rms_mm", result.rms_position_mm},
                      {"max_mm", result.max_position_mm},
                      {"rms_rotation_deg", result.rms_rotation_rad * 180.0 / M_PI},
                      {"max_rotation_deg", result.max_rotation_rad * 180.0 / M_PI},
                      {"closed_form_rms_mm", result.closed_form_rms_position_mm},
                      {"accept_rms_mm", kAcceptRmsMm}};
  record.valid = result.rms_position_mm <= kAcceptRmsMm;
  record.summary =
      record.valid
          ? "H_B^G from " + std::to_string(result.pairs) + " poses, residual " +
                format("%.2f mm rms", result.rms_position_mm) + format(" (max %.2f)", result.max_position_mm)
          : "rejected: residual " + format("%.2f mm rms", result.rms_position_mm) +
                format(" over %.1f mm", kAcceptRmsMm) + " (did the marker slip, or the arm touch something?)";
  try {
    const auto saved = store_->save(std::move(record));
    if (saved.valid) publish_calibration_in_use();
    runner_->finish(saved.valid, saved.version,
                    "robot calibration version " + std::to_string(saved.version) + ": " + saved.summary +
                        (saved.valid ? "" : "; the previous calibration stays in use"));
  } catch (const CalibrationStoreError& e) {
    runner_->finish(false, 0, std::string(e.what()) + "; the previous calibration stays in use");
  }
}

// The force topic (force_topic.cpp) and the ultrasound imaging and reconstruction topics (helper usimg;
// ultrasound_topics.cpp).
std::vector<std::shared_ptr<TopicSource>> SerialArm::topic_sources() {
  std::vector<std::shared_ptr<TopicSource>> sources{make_arm_force_topic(*this)};
  if (auto topics = make_us_arm_topics(*this)) sources.push_back(std::move(topics));
  return sources;
}

std::vector<ModeInfo> SerialArm::modes() const {
  std::vector<ModeInfo> modes = {
      {"cartesian",
       "CRTK move_cp (straight line, quintic), servo_cp and servo_cv of the tool, through the damped "
       "inverse (Heunis et al. 2021, Appendix A)"}};
  if (ultrasound_)
    modes.push_back({"sweep",
                     "the ultrasound sweep over the via-points of the plan: hybrid position/force control "
                     "(Heunis et al. 2021, Appendix A), the acquisition gate, motion compensation from the "
                     "limb's tracked "
                     "pose; driven by POST sweep {\"action\": ...}"});
  return modes;
}

void SerialArm::set_sweep_plan(std::shared_ptr<const SweepPlan> plan) {
  SweepPlanData data;
  data.count = static_cast<int>(std::min<std::size_t>(plan->via_points.size(), kMaxViaPoints));
  for (int i = 0; i < data.count; ++i)
    Eigen::Map<Eigen::Matrix4d>(data.via_points[static_cast<std::size_t>(i)].data()) =
        plan->via_points[static_cast<std::size_t>(i)].matrix();
  std::lock_guard lock(plan_mutex_);  // the slot has one writer at a time: the network threads queue here
  plan_slot_.store(data);
  plan_ = std::move(plan);
}

std::optional<ServiceError> SerialArm::dry_run(const Eigen::Isometry3d& start, const teleop::ArmVector& q0,
                                               const Eigen::Isometry3d& goal, double& duration) const {
  teleop::CartesianTrajectory trajectory;
  if (!trajectory.plan(start, goal, settings_.cartesian, 0.0))
    return ServiceError{ErrorKind::invalid, "bad_pose",
                        "move_cp: the goal is not a pose (non-finite or not a rotation)"};
  duration = trajectory.duration();
  // Kinematic run of what the controller will do, at a coarser step: the damped inverse, the joint
  // velocity caps and the position limits. A goal it does not reach is refused before anything moves.
  constexpr double kStep = 0.004;
  teleop::SerialArmData d = model_.make_data();
  teleop::ArmVector q = q0;
  const double settle = 1.0;  // s after the trajectory for the pose law to close the last error
  const auto steps = static_cast<int>(std::ceil((duration + settle) / kStep));
  for (int k = 1; k <= steps; ++k) {
    const auto result = teleop::track(model_, d, q, trajectory.sample(k * kStep), settings_.gains,
                                      settings_.cartesian, kStep);
    if (!result.joints.valid)
      return ServiceError{ErrorKind::invalid, "unreachable",
                          "move_cp: the path passes through a singularity the damped inverse cannot resolve"};
    q += result.joints.joint_velocity * kStep;
    if (result.joints.position_limited) {
      for (std::size_t j = 0; j < teleop::kArmJoints; ++j) {
        const auto& l = model_.limit(j);
        const double v = q[static_cast<Eigen::Index>(j)];
        if (v <= l.lower + 1e-6 || v >= l.upper - 1e-6)
          return ServiceError{
              ErrorKind::invalid, "out_of_limits",
              "move_cp: on the straight line to the goal joint '" + config_.joints[j].name() +
                  "' would reach its limit " + format("%.3f rad", v <= l.lower + 1e-6 ? l.lower : l.upper) +
                  "; choose a goal the arm reaches without it, or go there in joint mode (move_jp)"};
      }
    }
  }
  model_.forward_kinematics(q, d);
  const double position_error = (d.tool.translation() - goal.translation()).norm();
  const double angle_error = Eigen::AngleAxisd(d.tool.linear().transpose() * goal.linear()).angle();
  if (position_error > settings_.goal_tolerance_mm || angle_error > settings_.goal_tolerance_rad)
    return ServiceError{ErrorKind::invalid, "unreachable",
                        "move_cp: the arm cannot reach the goal along a straight line: it would end " +
                            format("%.1f mm and %.3f rad from it", position_error, angle_error) +
                            " (out of reach, or through a singularity)"};
  return std::nullopt;
}

Result<std::pair<PluginCommand, double>> SerialArm::cartesian_command(CartesianKind kind,
                                                                      const CartesianPose& pose,
                                                                      const CartesianTwist& twist,
                                                                      const OperatingStateView& state) const {
  static const char* names[] = {"move_cp", "servo_cp", "servo_cv"};
  const char* name = names[static_cast<int>(kind)];
  const std::string& robot = config_.name;
  if (state.mode != "cartesian")
    return ServiceError{ErrorKind::conflict, "wrong_mode",
                        "robot '" + robot + "' is in " + state.mode +
                            " mode; switch to cartesian mode (POST /api/v1/robots/" + robot +
                            "/mode {\"mode\": \"cartesian\"}) for " + name};
  PluginCommand c;
  if (kind == CartesianKind::servo_cv) {
    if (!twist.linear.allFinite() || !twist.angular.allFinite())
      return ServiceError{ErrorKind::invalid, "bad_twist", "servo_cv: the twist must be finite"};
    c.id = static_cast<std::uint16_t>(ArmCommand::servo_cv);
    c.count = 6;
    for (Eigen::Index i = 0; i < 3; ++i) {
      c.values[static_cast<std::size_t>(i)] = twist.linear[i];
      c.values[static_cast<std::size_t>(i) + 3] = twist.angular[i];
    }
    return std::pair{c, 0.0};
  }
  // Poses: inside the workspace box, and near enough (servo_cp) or reachable (move_cp).
  const Eigen::Vector3d& p = pose.position;
  if (!p.allFinite() || !pose.orientation.coeffs().allFinite())
    return ServiceError{ErrorKind::invalid, "bad_pose", std::string(name) + ": the pose must be finite"};
  if ((p.array() < settings_.workspace_min.array()).any() ||
      (p.array() > settings_.workspace_max.array()).any()) {
    const auto& lo = settings_.workspace_min;
    const auto& hi = settings_.workspace_max;
    char box[160];
    std::snprintf(box, sizeof box, "x %.0f..%.0f, y %.0f..%.0f, z %.0f..%.0f mm", lo.x(), hi.x(), lo.y(),
                  hi.y(), lo.z(), hi.z());
    return ServiceError{ErrorKind::invalid, "out_of_workspace",
                        std::string(name) + ": the goal " + format("(%.1f, %.1f, ", p.x(), p.y()) +
                            format("%.1f) mm is outside robot '", p.z()) + robot + "''s workspace box (" +
                            box + ")"};
  }
  Eigen::Isometry3d goal = Eigen::Isometry3d::Identity();
  goal.translation() = p;
  goal.linear() = pose.orientation.normalized().toRotationMatrix();
  const auto s = published_.load();
  const teleop::ArmVector q0 = Eigen::Map<const teleop::ArmVector>(s.setpoint.data());
  teleop::SerialArmData d = model_.make_data();
  model_.forward_kinematics(q0, d);
  double duration = 0.0;
  if (kind == CartesianKind::servo_cp) {
    const double step = (goal.translation() - d.tool.translation()).norm();
    const double turn = Eigen::AngleAxisd(d.tool.linear().transpose() * goal.linear()).angle();
    if (step > settings_.servo_cp_max_step_mm || turn > settings_.servo_cp_max_step_rad)
      return ServiceError{ErrorKind::invalid, "step_too_large",
                          "servo_cp: the goal is " + format("%.1f mm and %.3f rad", step, turn) +
                              " from the setpoint; a servo stream moves at most " +
                              format("%.1f mm and %.3f rad", settings_.servo_cp_max_step_mm,
                                     settings_.servo_cp_max_step_rad) +
                              " away (use move_cp for a goal farther away)"};
    c.id = static_cast<std::uint16_t>(ArmCommand::servo_cp);
  } else {
    if (auto why = dry_run(d.tool, q0, goal, duration)) return *why;
    c.id = static_cast<std::uint16_t>(ArmCommand::move_cp);
  }
  const Eigen::Quaterniond o(goal.linear());
  c.values = {p.x(), p.y(), p.z(), o.x(), o.y(), o.z(), o.w(), duration};
  c.count = 8;
  return std::pair{c, duration};
}

std::optional<CartesianTwist> SerialArm::measured_cv(std::span<const double> q,
                                                     std::span<const double> qd) const {
  if (q.size() != teleop::kArmJoints || qd.size() != teleop::kArmJoints) return std::nullopt;
  teleop::SerialArmData d = model_.make_data();
  teleop::Twist twist;
  if (!teleop::measured_cv(model_, d, Eigen::Map<const teleop::ArmVector>(q.data()),
                           Eigen::Map<const teleop::ArmVector>(qd.data()), twist))
    return std::nullopt;
  CartesianTwist out;
  out.linear = twist.head<3>();
  out.angular = twist.tail<3>();
  return out;
}

std::optional<Eigen::Vector3d> SerialArm::measured_cf() const {
  const auto s = published_.load();
  if (!s.force_valid) return std::nullopt;
  return Eigen::Vector3d(s.force_n[0], s.force_n[1], s.force_n[2]);
}

std::optional<ServiceError> SerialArm::resume_refusal(const OperatingStateView& state) const {
  if (state.state != safety::OperatingState::kPaused) return std::nullopt;
  const auto s = published_.load();
  const std::string& robot = config_.name;
  if (!s.force_fresh)
    return ServiceError{ErrorKind::conflict, "hold_not_cleared",
                        "cannot resume robot '" + robot + "': the force sensor has sent no reading for " +
                            format("%.0f ms", s.force_age_s * 1e3) + " (over " +
                            format("%.0f ms", settings_.force_stale_s * 1e3) +
                            "); check its link and resume once it reads again"};
  const double f = Eigen::Vector3d(s.force_n[0], s.force_n[1], s.force_n[2]).norm();
  if (s.force_hold && f > settings_.resume_contact_force_n)
    return ServiceError{ErrorKind::conflict, "hold_not_cleared",
                        "cannot resume robot '" + robot + "': the contact force is " + format("%.2f N", f) +
                            ", over the resume bound " + format("%.2f N", settings_.resume_contact_force_n) +
                            (s.retracting ? "; the tool is retracting from the contact, wait until it ends"
                                          : "; move the tissue away or disable the arm")};
  return std::nullopt;
}

std::unique_ptr<RobotApiExtension> SerialArm::api(RobotService& service,
                                                  std::function<bool(const PluginCommand&)> post) {
  // The CRTK commands reach the arm through cartesian_command(); the sweep command is the API's.
  post_ = post;  // the calibration routine posts its start too
  return make_serial_arm_api(*this, service, std::move(post));
}

}  // namespace tendril::server
