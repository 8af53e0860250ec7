// The SIMULATED limb under the ultrasound arm (Heunis et al. 2021, §3.1; the simulated set-up follows its
// §4): a tissue surface with bumps, an artery inside it, periodic limb movements (PLMs) and the 120 Hz
// tracker that reports the limb's pose; plus the pre-operative data a plan is made from (a CT of the artery
// wall and of the skin, in a CT frame that is deliberately misregistered, and a depth scan of the skin).
//
// Frames (mm, rad): the limb frame {P} ("tissue") has z out of the skin (up) and x along the limb; its
// rest pose in the arm's base frame is `rest_pose`. The skin is a half-cylinder of radius
// `cylinder_radius` along x whose top is z = 0, plus Gaussian bumps — the height map the contact
// surface (sim::ContactSurface, a spring and a damper) presses against. The artery is a tube of
// `artery_radius` whose centerline is a quartic in x at `artery_depth` below the top.
//
// PLM (Heunis et al. 2021, §3.1; our model, a MATLAB fourier2 form): for each of y, z (mm) and the rotation
// about x (rad), q(t) = a0 + a1·cos ωt + b1·sin ωt + a2·cos 2ωt + b2·sin 2ωt, ω = 2π/T; the limb's pose at t
// is rest_pose · Trans(0, q_y, q_z) · Rot_x(q_rx). The tracker samples that pose at 120 Hz and reports the
// sample taken `tracker_latency` ago (sample-and-hold): the motion compensation sees the limb up to
// one tracker period plus the latency late, as with a real motion-capture stream.
//
// Threads: advance() runs on the simulation's side (LimbMotion's own thread, or the runtime's step in
// stepped simulation); truth() and tracked() are seqlock reads for any thread, the control thread
// included. height() is const, allocation-free and lock-free (the contact surface's hook).
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "tendril/drivers/hardware/joint_interface.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::server {

struct LimbBump {
  double x = 0.0, y = 0.0;  // centre (mm, limb frame)
  double height = 0.0;      // mm (negative: a dip)
  double sigma = 10.0;      // mm (Gaussian width)
};

// Two-term Fourier series of one degree of freedom: a0, a1, b1, a2, b2.
using FourierTerms = std::array<double, 5>;

struct LimbParameters {
  Eigen::Isometry3d rest_pose = Eigen::Isometry3d::Identity();  // {P} in the arm's base frame
  double cylinder_radius = 60.0;                                // mm
  std::vector<LimbBump> bumps;
  double stiffness = 0.5;  // N/mm
  double damping = 0.005;  // N·s/mm
  // The artery: centerline z = −artery_depth + quartic, y = quartic, over x in [x_start, x_end].
  double artery_x_start = -62.5, artery_x_end = 62.5;
  double artery_depth = 30.0;   // mm below the top at the middle
  double artery_radius = 5.0;   // mm (10 mm inner diameter, the article's silicone tube)
  double artery_lateral = 3.0;  // mm: the y bow of the centerline
  double artery_dip = 3.0;      // mm: the z sag of the centerline
  // PLM.
  double period = 30.0;  // s
  FourierTerms y{}, z{}, rx{};
  // Tracker.
  double tracker_rate = 120.0;   // Hz
  double tracker_latency = 0.0;  // s, on top of the sample-and-hold
  // Measurement noise of each report (our choice: "0.3 mm-equivalent"): Gaussian, σ = tracker_noise (mm)
  // on each axis of the position and σ = tracker_noise / cylinder_radius (rad) about each axis of the
  // orientation — a rotation that moves a point on the skin's far side by the same amount. 0: exact.
  double tracker_noise = 0.0;
  // Pre-operative data (SIMULATED).
  Eigen::Isometry3d ct_T_limb = Eigen::Isometry3d::Identity();  // the CT frame's misregistration
  double ct_noise = 0.2;                                        // mm (our choice)
  double scan_noise = 0.5;                                      // mm, the skin depth scan (our choice)
  std::uint64_t seed = 17;
};

// Throws std::invalid_argument naming the parameter (non-finite values, radius ≤ 0, an artery outside
// the limb, a tracker rate ≤ 0, a period ≤ 0).
void validate(const LimbParameters& parameters);

struct LimbPoseSample {           // trivially copyable, for LatestValue
  double t = 0.0;                 // simulated time the pose belongs to (s)
  std::array<double, 16> pose{};  // world_T_limb, 4×4 column-major
  bool valid = false;
};

class LimbSimulation final : public sim::SurfaceHeightMap {
 public:
  explicit LimbSimulation(LimbParameters parameters);  // throws std::invalid_argument

  const LimbParameters& parameters() const noexcept { return parameters_; }

  // Skin height above the limb frame's z = 0 at (x, y); the cylinder's flank below y = ±radius.
  double height(double x, double y) const noexcept override;

  // The PLM offsets (y, z mm; rx rad) and the limb's true pose at simulated time t.
  Eigen::Vector3d offsets(double t) const noexcept;
  Eigen::Isometry3d pose_at(double t) const noexcept;
  Eigen::Vector3d velocity_at(double t) const noexcept;  // of the limb frame's origin (mm/s)

  // Simulation side: the limb at time t (monotonic), and the tracker's sample when one is due.
  void advance(double t) noexcept;
  LimbPoseSample truth() const noexcept { return truth_.load(); }
  LimbPoseSample tracked() const noexcept { return tracked_.load(); }

  // The artery centerline in the limb frame, every 1 mm, with its radius (for the B-mode simulation).
  const teleop::CenterlinePolyline& artery() const noexcept { return artery_; }

  // Pre-operative data (SIMULATED, deterministic for the seed): the artery wall (a ring of points every
  // 2 mm) in the CT frame with CT noise; and the skin as a depth scan in the limb frame with scan noise
  // (grid spacing in mm).
  std::vector<Eigen::Vector3d> ct_wall_cloud() const;
  std::vector<Eigen::Vector3d> skin_scan(double spacing = 1.5) const;
  // The calibration stick fixed to the limb (Heunis et al. 2021, §2.4): three rods of 40, 25 and 15 mm
  // (radius 3 mm) along x, y and z from a corner beside the skin — asymmetric, so one pose fits. Its model in
  // the limb frame (exact, every 1 mm: the tracker's rigid body defines {P}) and its CT image (CT frame,
  // CT noise, every 2 mm). ICP of the one onto the other gives the CT → {P} registration.
  std::vector<Eigen::Vector3d> stick_model() const;
  std::vector<Eigen::Vector3d> ct_stick_cloud() const;

 private:
  Eigen::Vector3d artery_point(double x) const noexcept;

  LimbParameters parameters_;
  teleop::CenterlinePolyline artery_;
  hardware::LatestValue<LimbPoseSample> truth_;
  hardware::LatestValue<LimbPoseSample> tracked_;
  double next_track_ = 0.0;      // simulation side only
  std::mt19937_64 tracker_rng_;  // the tracker's noise (simulation side only)
  std::normal_distribution<double> tracker_noise_{0.0, 1.0};
};

// The HardwareComponent that moves the limb: it advances the LimbSimulation and moves the contact
// surface to the limb's pose, at 1 kHz in its own thread or once per control period in stepped
// simulation (before the control cycle, so that the force sensor — stepped after it — sees the limb
// where it is now). The limb and the surface must outlive it.
class LimbMotion final : public hardware::HardwareComponent {
 public:
  LimbMotion(LimbSimulation& limb, sim::ContactSurface& surface, std::string name);
  ~LimbMotion() override;
  std::string name() const override { return name_; }
  void configure(const std::function<void()>& idle) override;
  void activate(bool realtime_priority) override;
  void deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) override;
  void step(Clock::time_point now, double period, bool after_control) override;

 private:
  void move(double t) noexcept;

  LimbSimulation& limb_;
  sim::ContactSurface& surface_;
  std::string name_;
  double t_ = 0.0;  // stepped simulated time
  std::atomic<bool> stop_{false};
  std::unique_ptr<std::thread> thread_;
};

}  // namespace tendril::server
