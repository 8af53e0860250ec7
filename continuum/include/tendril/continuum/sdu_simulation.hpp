// SIMULATED sensing disk units: a scene of planes, boxes and cylinders (a cylinder stands for a human
// arm), ray-cast time-of-flight sensors with the dissertation's error characteristics (§3.3.2) and Hall
// sensors under a compliant sleeve with the dissertation's response (§3.3.1). A SimulatedSduNode produces
// what one disk's microcontroller would put on the bus. Nothing here is a model of real hardware timing
// beyond what is stated; it is a simulation for tests, scenarios and the plug-in's simulated robot.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <optional>
#include <random>
#include <vector>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_segment.hpp"

namespace tendril::continuum {

// ToF error depends on the target's finish (Abah 2022, §3.3.2): matte objects are seen within ±16.5° with up
// to 12.5 mm error at the cone's edge, glossy ones within ±11.9° with up to 15.6 mm.
enum class SurfaceFinish : std::uint8_t { kMatte, kGlossy };

struct ScenePlane {  // an infinite plane; the half-space behind the normal is solid
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  SurfaceFinish finish = SurfaceFinish::kMatte;
};
struct SceneBox {  // a solid box: pose of its centre, half extents along its own axes
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  Eigen::Vector3d half_extent_mm = Eigen::Vector3d::Constant(50.0);
  SurfaceFinish finish = SurfaceFinish::kMatte;
};
struct SceneCylinder {  // a solid finite cylinder (its end caps are not hit by rays)
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis = Eigen::Vector3d::UnitX();  // unit
  double radius_mm = 25.4;                          // the dissertation's 50.8 mm wrist rod
  double half_length_mm = 300.0;
  SurfaceFinish finish = SurfaceFinish::kMatte;
};

struct RayHit {
  double distance_mm = 0.0;
  SurfaceFinish finish = SurfaceFinish::kMatte;
};

class Scene {
 public:
  // Each add throws std::invalid_argument for a non-finite value, a zero normal or axis, or a
  // non-positive size. Returns the index of the object within its kind.
  std::size_t add(const ScenePlane& plane);
  std::size_t add(const SceneBox& box);
  std::size_t add(const SceneCylinder& cylinder);
  // Moves a cylinder (the approaching arm); throws std::out_of_range for an unknown index.
  void move_cylinder(std::size_t index, const Eigen::Vector3d& centre);
  const std::vector<SceneCylinder>& cylinders() const noexcept { return cylinders_; }
  const std::vector<ScenePlane>& planes() const noexcept { return planes_; }
  const std::vector<SceneBox>& boxes() const noexcept { return boxes_; }

  // Nearest hit along the ray (direction unit) within (0, max_range].
  std::optional<RayHit> cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                             double max_range_mm) const noexcept;
  // Depth (≥ 0) by which the point lies inside a solid; 0 outside every object.
  double penetration(const Eigen::Vector3d& point) const noexcept;

 private:
  std::vector<ScenePlane> planes_;
  std::vector<SceneBox> boxes_;
  std::vector<SceneCylinder> cylinders_;
};

struct TofModel {
  double max_range_mm = 130.0;  // detected accurately up to 130 mm (Abah 2022, §3.3.2); beyond: no target
  double matte_half_angle_rad = 0.28797932657906439;   // 16.5°
  double glossy_half_angle_rad = 0.20769418099607317;  // 11.9°
  double matte_on_axis_error_mm = 0.01;
  double matte_edge_error_mm = 12.5;
  double glossy_on_axis_error_mm = 0.019;
  double glossy_edge_error_mm = 15.6;
  // The dissertation gives mean errors, no spread; tendril's choice: 0.5 mm standard deviation.
  double noise_sd_mm = 0.5;
  int rings = 3;  // rays on cones at 1/3, 2/3 and 3/3 of the matte half angle, plus the axis
  int rays_per_ring = 8;
};

// A sensor reads the nearest surface inside its cone. Where the dissertation gives only the error on the axis
// and at the edge, the error grows with the square of the off-axis angle, and the sensor reads long
// (a weak return from the cone's edge crosses the detector's threshold late) — the side that makes an
// object look farther, so the safety tests see the pessimistic case.
double tof_error_mm(const TofModel& model, SurfaceFinish finish, double off_axis_rad) noexcept;

struct HallModel {
  double slope_mT_per_N = 0.26;  // ᾱ (Abah 2022, §3.3.1)
  double f_linearity = 0.0452;   // 4.52 %: a smooth bow over the calibration range
  double calibration_range_N = 10.0;
  // Not in the dissertation: 5 µT, so that the bow and the noise together give the dissertation's F-linearity
  // over a 0–10 N calibration (4.8 % measured, tests/unit/continuum).
  double noise_sd_mT = 0.005;
  // Not in the dissertation: the Shore 2A sleeve's stiffness over a Hall window (how far a probe sinks per
  // newton) and the sector a magnet feels (half the slot pitch each side, linearly weaker off-centre).
  double sleeve_stiffness_N_per_mm = 5.0;
  double footprint_half_angle_rad = 0.39269908169872414;  // 22.5°
  double drift_mT_per_s = 0.0;                            // baseline drift (a fault to detect), on z
};

// B_z change (mT) for a normal force F (N) under the model's bow: F + 6·lin·F_cal·x(1 − x), x = F/F_cal
// in [0, 1], times the slope. The 6 makes the least-squares line's largest deviation lin·F_cal, i.e. the
// the dissertation's F-linearity (3.2).
double hall_field_change_mT(const HallModel& model, double force_n) noexcept;

// One SIMULATED disk node: what its sensors read at a disk pose in a scene.
class SimulatedSduNode {
 public:
  // Throws std::invalid_argument for non-positive ranges, slopes or stiffness, or negative noise.
  SimulatedSduNode(const SduSegmentModel& segment, TofModel tof, HallModel hall, std::uint64_t seed);
  // Readings at time t (s, for the drift) with the disk at disk_pose in the scene.
  SduSample sense(const Scene& scene, const Eigen::Isometry3d& disk_pose, double t_s);
  // Readings with given normal forces on the Hall windows (the calibration rig's probe), no scene.
  SduSample sense_forces(const std::array<double, kHallPerSdu>& force_n, double t_s);
  // The true normal force on each Hall window in the last sense() (N), for tests.
  const std::array<double, kHallPerSdu>& true_force() const noexcept { return true_force_; }
  // The magnets' rest field (the bias the start-up unbiasing must find), mT.
  const std::array<std::array<double, 3>, kHallPerSdu>& rest_field() const noexcept { return rest_field_; }
  HallModel& hall() noexcept { return hall_; }

 private:
  void fill_hall(SduSample& s, double t_s);
  SduSegmentModel segment_;
  TofModel tof_;
  HallModel hall_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> unit_{0.0, 1.0};
  std::array<std::array<double, 3>, kHallPerSdu> rest_field_{};
  std::array<double, kHallPerSdu> true_force_{};
};

}  // namespace tendril::continuum
