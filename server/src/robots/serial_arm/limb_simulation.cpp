// The SIMULATED limb: skin height map, artery, PLM, tracker and pre-operative clouds (see the header).
#include "serial_arm/limb_simulation.hpp"

#include <chrono>
#include <cmath>
#include <numbers>
#include <random>
#include <utility>

namespace tendril::server {

namespace {

std::array<double, 16> to_array16(const Eigen::Isometry3d& pose) noexcept {
  std::array<double, 16> out{};
  Eigen::Map<Eigen::Matrix4d>(out.data()) = pose.matrix();
  return out;
}

double fourier(const FourierTerms& c, double w, double t) noexcept {
  return c[0] + c[1] * std::cos(w * t) + c[2] * std::sin(w * t) + c[3] * std::cos(2 * w * t) +
         c[4] * std::sin(2 * w * t);
}

double fourier_rate(const FourierTerms& c, double w, double t) noexcept {
  return -c[1] * w * std::sin(w * t) + c[2] * w * std::cos(w * t) - c[3] * 2 * w * std::sin(2 * w * t) +
         c[4] * 2 * w * std::cos(2 * w * t);
}

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

bool finite(const FourierTerms& c) {
  for (double v : c)
    if (!std::isfinite(v)) return false;
  return true;
}

}  // namespace

void validate(const LimbParameters& p) {
  require(p.rest_pose.matrix().allFinite(), "rest_pose: expected a finite pose");
  require(std::isfinite(p.cylinder_radius) && p.cylinder_radius > 0, "cylinder_radius_mm: expected > 0");
  for (const auto& b : p.bumps)
    require(std::isfinite(b.x) && std::isfinite(b.y) && std::isfinite(b.height) && std::isfinite(b.sigma) &&
                b.sigma > 0,
            "bumps: expected finite x, y, height and a sigma > 0 (mm)");
  require(std::isfinite(p.stiffness) && p.stiffness > 0, "stiffness_n_per_mm: expected > 0");
  require(std::isfinite(p.damping) && p.damping >= 0, "damping_n_s_per_mm: expected >= 0");
  require(std::isfinite(p.artery_x_start) && std::isfinite(p.artery_x_end) &&
              p.artery_x_end - p.artery_x_start >= 10.0,
          "artery.x_range_mm: expected at least 10 mm of artery");
  require(std::isfinite(p.artery_radius) && p.artery_radius > 0, "artery.radius_mm: expected > 0");
  require(std::isfinite(p.artery_lateral) && std::isfinite(p.artery_dip), "artery: expected finite bends");
  require(std::isfinite(p.artery_depth) && p.artery_depth > p.artery_radius + 1.0,
          "artery.depth_mm: expected the tube (radius included) under the skin");
  require(std::abs(p.artery_lateral) + p.artery_radius < p.cylinder_radius,
          "artery.lateral_mm: expected the tube inside the limb's cylinder");
  require(std::isfinite(p.period) && p.period > 0, "motion.period_s: expected > 0");
  require(finite(p.y) && finite(p.z) && finite(p.rx), "motion: expected finite Fourier terms");
  require(std::isfinite(p.tracker_rate) && p.tracker_rate > 0, "tracker.rate_hz: expected > 0");
  require(std::isfinite(p.tracker_latency) && p.tracker_latency >= 0, "tracker.latency_ms: expected >= 0");
  require(std::isfinite(p.tracker_noise) && p.tracker_noise >= 0 && p.tracker_noise <= 5,
          "tracker.noise_mm: expected 0 to 5 mm");
  require(p.ct_T_limb.matrix().allFinite(), "ct: expected a finite misregistration");
  require(std::isfinite(p.ct_noise) && p.ct_noise >= 0 && std::isfinite(p.scan_noise) && p.scan_noise >= 0,
          "noise: expected >= 0");
}

LimbSimulation::LimbSimulation(LimbParameters parameters)
    : parameters_(std::move(parameters)), tracker_rng_(parameters_.seed ^ 0x7472616b65ULL) {
  validate(parameters_);
  // Every millimetre along the artery (integer steps: a float counter would drift).
  const int artery_steps =
      static_cast<int>(std::floor(parameters_.artery_x_end - parameters_.artery_x_start + 1e-9));
  for (int i = 0; i <= artery_steps; ++i) {
    const double x = parameters_.artery_x_start + i * 1.0;
    artery_.points.push_back(artery_point(x));
    artery_.radii.push_back(parameters_.artery_radius);
  }
  LimbPoseSample s;
  s.pose = to_array16(pose_at(0.0));
  s.valid = true;
  truth_.store(s);
  tracked_.store(s);
}

double LimbSimulation::height(double x, double y) const noexcept {
  const double r = parameters_.cylinder_radius;
  // The half-cylinder's top is z = 0; past its flanks the skin falls away (a steep wall at −r).
  const double ay = std::abs(y);
  double h = ay < r ? std::sqrt(r * r - ay * ay) - r : -r - (ay - r);
  for (const auto& b : parameters_.bumps) {
    const double dx = x - b.x, dy = y - b.y;
    h += b.height * std::exp(-(dx * dx + dy * dy) / (2.0 * b.sigma * b.sigma));
  }
  return h;
}

Eigen::Vector3d LimbSimulation::artery_point(double x) const noexcept {
  const auto& p = parameters_;
  const double s = 2.0 * (x - p.artery_x_start) / (p.artery_x_end - p.artery_x_start) - 1.0;  // [-1, 1]
  const double y = p.artery_lateral * 1.5 * (s - s * s * s / 3.0);              // a gentle S, |y| ≤ lateral
  const double z = -p.artery_depth - p.artery_dip * (1 - s * s) * (1 - s * s);  // deepest mid-limb
  return {x, y, z};
}

Eigen::Vector3d LimbSimulation::offsets(double t) const noexcept {
  const double w = 2.0 * std::numbers::pi / parameters_.period;
  return {fourier(parameters_.y, w, t), fourier(parameters_.z, w, t), fourier(parameters_.rx, w, t)};
}

Eigen::Isometry3d LimbSimulation::pose_at(double t) const noexcept {
  const Eigen::Vector3d o = offsets(t);
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  motion.translation() = Eigen::Vector3d(0.0, o.x(), o.y());
  motion.linear() = Eigen::AngleAxisd(o.z(), Eigen::Vector3d::UnitX()).toRotationMatrix();
  return parameters_.rest_pose * motion;
}

Eigen::Vector3d LimbSimulation::velocity_at(double t) const noexcept {
  const double w = 2.0 * std::numbers::pi / parameters_.period;
  const Eigen::Vector3d local(0.0, fourier_rate(parameters_.y, w, t), fourier_rate(parameters_.z, w, t));
  return parameters_.rest_pose.linear() * local;
}

void LimbSimulation::advance(double t) noexcept {
  LimbPoseSample s;
  s.t = t;
  s.pose = to_array16(pose_at(t));
  s.valid = true;
  truth_.store(s);
  if (t + 1e-12 >= next_track_) {
    const double period = 1.0 / parameters_.tracker_rate;
    LimbPoseSample k;
    k.t = t - parameters_.tracker_latency;
    Eigen::Isometry3d reported = pose_at(k.t);
    if (parameters_.tracker_noise > 0.0) {
      const double sigma = parameters_.tracker_noise;
      const double sigma_rad = sigma / parameters_.cylinder_radius;
      const Eigen::Vector3d dp(sigma * tracker_noise_(tracker_rng_), sigma * tracker_noise_(tracker_rng_),
                               sigma * tracker_noise_(tracker_rng_));
      const Eigen::Vector3d dr(sigma_rad * tracker_noise_(tracker_rng_),
                               sigma_rad * tracker_noise_(tracker_rng_),
                               sigma_rad * tracker_noise_(tracker_rng_));
      reported.translation() += dp;
      if (dr.norm() > 0.0)
        reported.linear() = reported.linear() * Eigen::AngleAxisd(dr.norm(), dr.normalized());
    }
    k.pose = to_array16(reported);
    k.valid = true;
    tracked_.store(k);
    while (next_track_ <= t + 1e-12) next_track_ += period;
  }
}

std::vector<Eigen::Vector3d> LimbSimulation::ct_wall_cloud() const {
  const auto& p = parameters_;
  std::mt19937_64 rng(p.seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<Eigen::Vector3d> out;
  constexpr int kRing = 24;
  const int rings = static_cast<int>(std::floor((p.artery_x_end - p.artery_x_start) / 2.0 + 1e-9));
  for (int i = 0; i <= rings; ++i) {
    const double x = p.artery_x_start + i * 2.0;  // a ring every 2 mm
    const Eigen::Vector3d c = artery_point(x);
    const Eigen::Vector3d tangent = (artery_point(x + 0.5) - artery_point(x - 0.5)).normalized();
    const Eigen::Vector3d u = tangent.cross(Eigen::Vector3d::UnitZ()).normalized();
    const Eigen::Vector3d v = tangent.cross(u);
    for (int k = 0; k < kRing; ++k) {
      const double a = 2.0 * std::numbers::pi * k / kRing;
      const Eigen::Vector3d wall = c + p.artery_radius * (std::cos(a) * u + std::sin(a) * v);
      out.push_back(p.ct_T_limb * wall + p.ct_noise * Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
    }
  }
  return out;
}

std::vector<Eigen::Vector3d> LimbSimulation::skin_scan(double spacing) const {
  const auto& p = parameters_;
  std::mt19937_64 rng(p.seed + 2);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<Eigen::Vector3d> out;
  const double half = 0.5 * p.cylinder_radius;
  const double x0 = p.artery_x_start - 5.0;
  const int nx = static_cast<int>(std::floor((p.artery_x_end + 5.0 - x0) / spacing + 1e-9));
  const int ny = static_cast<int>(std::floor(2.0 * half / spacing + 1e-9));
  for (int i = 0; i <= nx; ++i)
    for (int j = 0; j <= ny; ++j) {
      const double x = x0 + i * spacing;
      const double y = -half + j * spacing;
      out.emplace_back(x, y, height(x, y) + p.scan_noise * noise(rng));
    }
  return out;
}

namespace {
// Points on the stick's three rods (limb frame) every `step` mm along each rod, 12 around it.
std::vector<Eigen::Vector3d> stick_points(double step, double corner_y) {
  const Eigen::Vector3d corner(-75.0, corner_y, 3.0);
  const std::array<std::pair<Eigen::Vector3d, double>, 3> rods = {
      {{Eigen::Vector3d::UnitX(), 40.0}, {Eigen::Vector3d::UnitY(), 25.0}, {Eigen::Vector3d::UnitZ(), 15.0}}};
  std::vector<Eigen::Vector3d> out;
  constexpr double kRadius = 3.0;
  for (const auto& [axis, length] : rods) {
    const Eigen::Vector3d u = axis.unitOrthogonal();
    const Eigen::Vector3d v = axis.cross(u);
    const int n = static_cast<int>(std::floor(length / step + 1e-9));
    for (int i = 0; i <= n; ++i)
      for (int k = 0; k < 12; ++k) {
        const double s = i * step;
        const double a = 2.0 * std::numbers::pi * k / 12;
        out.push_back(corner + s * axis + kRadius * (std::cos(a) * u + std::sin(a) * v));
      }
  }
  return out;
}
}  // namespace

std::vector<Eigen::Vector3d> LimbSimulation::stick_model() const {
  return stick_points(1.0, parameters_.cylinder_radius * 0.7);
}

std::vector<Eigen::Vector3d> LimbSimulation::ct_stick_cloud() const {
  const auto& p = parameters_;
  std::mt19937_64 rng(p.seed + 3);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<Eigen::Vector3d> out;
  for (const auto& q : stick_points(2.0, p.cylinder_radius * 0.7))
    out.push_back(p.ct_T_limb * q + p.ct_noise * Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
  return out;
}

// ---- LimbMotion -------------------------------------------------------------------------------------

LimbMotion::LimbMotion(LimbSimulation& limb, sim::ContactSurface& surface, std::string name)
    : limb_(limb), surface_(surface), name_(std::move(name)) {}

LimbMotion::~LimbMotion() {
  stop_.store(true);
  if (thread_ && thread_->joinable()) thread_->join();
}

void LimbMotion::move(double t) noexcept {
  limb_.advance(t);
  surface_.move_to(limb_.pose_at(t), limb_.velocity_at(t));
}

void LimbMotion::configure(const std::function<void()>& idle) {
  (void)idle;
  t_ = 0.0;
  move(0.0);
}

void LimbMotion::activate(bool realtime_priority) {
  (void)realtime_priority;  // a simulation of the patient: no real-time priority needed
  if (thread_) return;
  stop_.store(false);
  thread_ = std::make_unique<std::thread>([this] {
    const auto start = Clock::now();
    auto next = start;
    while (!stop_.load()) {
      next += std::chrono::milliseconds(1);
      move(std::chrono::duration<double>(Clock::now() - start).count());
      std::this_thread::sleep_until(next);
    }
  });
}

void LimbMotion::deactivate(std::chrono::milliseconds timeout, const std::function<void()>& idle) {
  (void)timeout;
  (void)idle;
  stop_.store(true);
  if (thread_ && thread_->joinable()) thread_->join();
  thread_.reset();
}

void LimbMotion::step(Clock::time_point now, double period, bool after_control) {
  (void)now;
  if (after_control) return;
  t_ += period;
  move(t_);
}

}  // namespace tendril::server
