#include "tendril/drivers/sim/simulated_force_sensor.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <new>
#include <numbers>
#include <thread>

#include "allocation_counter.hpp"
#include "tendril/drivers/sim/contact_surface.hpp"
#include "tendril/drivers/sim/simulated_velocity_arm.hpp"

namespace tendril::sim {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDt = 0.002;

// ---- the contact surface ----

TEST(ContactSurface, ForceAlongTheNormalIsProportionalToPenetration) {
  const ContactSurface plane(ContactSurfaceParameters{.stiffness = 0.5, .damping = 0.0});
  for (const double depth : {0.1, 1.0, 2.5, 8.0}) {
    const ContactSample c = plane.contact({30.0, -40.0, -depth}, Eigen::Vector3d::Zero());
    EXPECT_TRUE(c.in_contact);
    EXPECT_NEAR(c.penetration, depth, 1e-12);
    EXPECT_NEAR((c.force - Eigen::Vector3d(0, 0, 0.5 * depth)).norm(), 0.0, 1e-12);
  }
  // Free space: nothing.
  const ContactSample above = plane.contact({0.0, 0.0, 0.01}, Eigen::Vector3d(0, 0, -100));
  EXPECT_FALSE(above.in_contact);
  EXPECT_TRUE(above.force.isZero());
}

TEST(ContactSurface, TiltedPlanePushesAlongItsOwnNormal) {
  ContactSurfaceParameters p;
  p.pose = Eigen::Translation3d(100.0, 0.0, 50.0) * Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitX());
  p.damping = 0.0;
  const ContactSurface plane(p);
  const Eigen::Vector3d n = p.pose.linear().col(2);
  const Eigen::Vector3d inside = p.pose * Eigen::Vector3d(10.0, 20.0, -3.0);
  const ContactSample c = plane.contact(inside, Eigen::Vector3d::Zero());
  EXPECT_NEAR(c.penetration, 3.0, 1e-12);
  EXPECT_NEAR((c.force - 1.5 * n).norm(), 0.0, 1e-12);
  EXPECT_NEAR((c.normal - n).norm(), 0.0, 1e-12);
}

TEST(ContactSurface, DampingAddsToPressingAndNeverPulls) {
  const ContactSurface plane(ContactSurfaceParameters{.stiffness = 0.5, .damping = 0.005});
  // Pressing in at 10 mm/s, 1 mm deep: 0.5 + 0.05 N.
  EXPECT_NEAR(plane.contact({0, 0, -1.0}, {0, 0, -10.0}).force.z(), 0.55, 1e-12);
  // Withdrawing at 200 mm/s, 1 mm deep: the damper would pull; the tissue does not stick.
  EXPECT_EQ(plane.contact({0, 0, -1.0}, {0, 0, 200.0}).force.z(), 0.0);
  // Sliding along the surface does not change the force.
  EXPECT_NEAR(plane.contact({0, 0, -1.0}, {30.0, -20.0, 0.0}).force.z(), 0.5, 1e-12);
}

TEST(ContactSurface, BoxPushesOutOfItsNearestFace) {
  ContactSurfaceParameters p;
  p.shape = ContactShape::box;
  p.half_length = 50.0;
  p.half_width = 30.0;
  p.depth = 40.0;
  p.damping = 0.0;
  const ContactSurface box(p);
  ContactSample c = box.contact({0.0, 0.0, -2.0}, Eigen::Vector3d::Zero());  // under the top face
  EXPECT_NEAR((c.force - Eigen::Vector3d(0, 0, 1.0)).norm(), 0.0, 1e-12);
  c = box.contact({49.0, 0.0, -20.0}, Eigen::Vector3d::Zero());  // 1 mm inside the +x side
  EXPECT_NEAR((c.force - Eigen::Vector3d(0.5, 0, 0)).norm(), 0.0, 1e-12);
  c = box.contact({0.0, -29.5, -20.0}, Eigen::Vector3d::Zero());  // the −y side
  EXPECT_NEAR((c.force - Eigen::Vector3d(0, -0.25, 0)).norm(), 0.0, 1e-12);
  c = box.contact({0.0, 0.0, -39.0}, Eigen::Vector3d::Zero());  // the bottom
  EXPECT_NEAR((c.force - Eigen::Vector3d(0, 0, -0.5)).norm(), 0.0, 1e-12);
  EXPECT_FALSE(box.contact({51.0, 0.0, -2.0}, Eigen::Vector3d::Zero()).in_contact);  // beside it
  EXPECT_FALSE(box.contact({0.0, 0.0, -41.0}, Eigen::Vector3d::Zero()).in_contact);  // below it
}

// The hook issue 17 uses for tissue: a height map.
struct Ridge final : SurfaceHeightMap {
  double height(double x, double) const noexcept override { return 4.0 * std::sin(x / 20.0); }
};

TEST(ContactSurface, HeightMapMakesTheSurfaceUneven) {
  const Ridge ridge;
  const ContactSurface tissue(
      ContactSurfaceParameters{.stiffness = 1.0, .damping = 0.0, .height_map = &ridge});
  // At x = 10π the ridge peaks at 4 mm: a point at z = 3 is 1 mm inside, the normal is vertical.
  ContactSample c = tissue.contact({10.0 * kPi, 0.0, 3.0}, Eigen::Vector3d::Zero());
  EXPECT_NEAR(c.penetration, 1.0, 1e-4);
  EXPECT_NEAR(c.normal.z(), 1.0, 1e-6);
  // At x = 0 the slope is 4/20: the normal leans back, n = (−0.2, 0, 1)/√1.04, and the vertical depth
  // 2 mm becomes 2·n_z along it.
  c = tissue.contact({0.0, 0.0, -2.0}, Eigen::Vector3d::Zero());
  const Eigen::Vector3d n = Eigen::Vector3d(-0.2, 0.0, 1.0).normalized();
  EXPECT_NEAR((c.normal - n).norm(), 0.0, 1e-4);
  EXPECT_NEAR(c.penetration, 2.0 * n.z(), 1e-4);
  EXPECT_NEAR((c.force - c.penetration * n).norm(), 0.0, 1e-4);
  // Above the trough nothing.
  EXPECT_FALSE(tissue.contact({-10.0 * kPi, 0.0, -3.9}, Eigen::Vector3d::Zero()).in_contact);
}

TEST(ContactSurface, MovingTheSurfaceMovesTheContact) {
  ContactSurface plane(ContactSurfaceParameters{.stiffness = 0.5, .damping = 0.005});
  EXPECT_FALSE(plane.contact({0, 0, 1.0}, Eigen::Vector3d::Zero()).in_contact);
  Eigen::Isometry3d raised = Eigen::Isometry3d::Identity();
  raised.translation().z() = 3.0;
  plane.move_to(raised, Eigen::Vector3d(0, 0, 10.0));  // rising at 10 mm/s into a still tool
  const ContactSample c = plane.contact({0, 0, 1.0}, Eigen::Vector3d::Zero());
  EXPECT_NEAR(c.force.z(), 0.5 * 2.0 + 0.005 * 10.0, 1e-12);
  Eigen::Isometry3d bad = raised;
  bad.linear() *= 2.0;
  plane.move_to(bad);  // ignored
  EXPECT_TRUE(plane.pose().isApprox(raised));
  EXPECT_THROW(ContactSurface(ContactSurfaceParameters{.stiffness = 0.0}), SimulationSetupError);
}

// ---- the sensor on the arm ----

// A probe pointing straight down (the arm's tool z = −z of the base) over a floor at a given height.
struct Bench {
  explicit Bench(SimulatedForceSensorParameters sp = {}, double floor_below_tool = 5.0,
                 double stiffness = 0.5)
      : arm(ur5_simulated_arm(probe_down())),
        kinematics(teleop::ur5_parameters()),
        floor(floor_parameters(floor_below_tool, stiffness)),
        sensor(arm, kinematics, floor, std::move(sp)) {
    arm.configure({});
    sensor.configure({});
  }
  static std::array<double, 6> probe_down() { return {0.0, -1.2, 1.6, -kPi / 2 + 1.2 - 1.6, -kPi / 2, 0.0}; }
  ContactSurfaceParameters floor_parameters(double below, double stiffness) const {
    teleop::SerialArmData d = kinematics.make_data();
    teleop::ArmVector q = Eigen::Map<const teleop::ArmVector>(probe_down().data());
    kinematics.forward_kinematics(q, d);
    ContactSurfaceParameters p;
    p.pose = Eigen::Translation3d(0.0, 0.0, d.tool.translation().z() - below) * Eigen::Isometry3d::Identity();
    p.stiffness = stiffness;
    p.damping = 0.0;
    return p;
  }
  // Puts the floor `below_tool` mm under the tool point (negative: above it, the probe inside).
  void move_floor_to(double below_tool) {
    Eigen::Isometry3d pose = floor.pose();
    pose.translation().z() = tool_height() - below_tool;
    floor.move_to(pose);
  }
  double tool_height() const {
    teleop::SerialArmData d = kinematics.make_data();
    const ArmTruth t = arm.truth();
    kinematics.forward_kinematics(Eigen::Map<const teleop::ArmVector>(t.position.data()), d);
    return d.tool.translation().z();
  }
  void cycle() {
    now += std::chrono::microseconds(2000);
    arm.step(now, kDt, false);
    sensor.step(now, kDt, false);
  }
  SimulatedVelocityArm arm;
  teleop::SerialArmKinematics kinematics;
  ContactSurface floor;
  SimulatedForceSensor sensor;
  Clock::time_point now = Clock::time_point{} + std::chrono::hours(1);
};

SimulatedForceSensorParameters quiet() {
  SimulatedForceSensorParameters p;
  p.noise = {0.0, 0.0, 0.0};
  return p;
}

TEST(SimulatedForceSensor, ReadsThePressingForceAlongTheProbeAxis) {
  for (const double depth : {0.4, 1.0, 3.0}) {
    Bench b(quiet(), -depth);  // the floor `depth` above the tool point: the probe is in it
    b.cycle();
    b.cycle();
    const hardware::ForceReading r = b.sensor.read();
    ASSERT_TRUE(r.valid);
    // The floor pushes up (+z of the base) = −z of the downward probe: F_n = −f_z = k·depth.
    EXPECT_NEAR(-r.force_n[2], 0.5 * depth, 1e-9);
    EXPECT_NEAR(r.force_n[0], 0.0, 1e-9);
    EXPECT_NEAR(r.force_n[1], 0.0, 1e-9);
    EXPECT_TRUE(b.sensor.truth().in_contact);
    EXPECT_NEAR(b.sensor.truth().penetration, depth, 1e-9);
  }
}

TEST(SimulatedForceSensor, ReadsNothingInFreeSpace) {
  Bench b(quiet(), 5.0);
  for (int k = 0; k < 10; ++k) b.cycle();
  const hardware::ForceReading r = b.sensor.read();
  ASSERT_TRUE(r.valid);
  EXPECT_EQ(r.force_n[0], 0.0);
  EXPECT_EQ(r.force_n[1], 0.0);
  EXPECT_EQ(r.force_n[2], 0.0);
  EXPECT_FALSE(b.sensor.truth().in_contact);
}

TEST(SimulatedForceSensor, NoiseAndBiasHaveTheConfiguredStatistics) {
  SimulatedForceSensorParameters p;
  p.noise = {0.01, 0.02, 0.005};
  p.bias = {0.03, -0.02, 0.1};
  Bench b(p, 5.0);  // free space: the reading is bias + noise
  constexpr int n = 20000;
  std::array<double, 3> sum{}, sum2{};
  std::int64_t last_stamp = 0;
  int readings = 0;
  for (int k = 0; k < n; ++k) {
    b.cycle();
    const hardware::ForceReading r = b.sensor.read();
    if (!r.valid || r.stamp_ns == last_stamp) continue;
    last_stamp = r.stamp_ns;
    ++readings;
    for (std::size_t i = 0; i < 3; ++i) {
      sum[i] += r.force_n[i];
      sum2[i] += r.force_n[i] * r.force_n[i];
    }
  }
  ASSERT_GT(readings, n - 5);
  for (std::size_t i = 0; i < 3; ++i) {
    const double mean = sum[i] / readings, sd = std::sqrt(sum2[i] / readings - mean * mean);
    EXPECT_NEAR(mean, p.bias[i], 4.0 * p.noise[i] / std::sqrt(readings)) << "axis " << i;
    EXPECT_NEAR(sd, p.noise[i], 0.03 * p.noise[i]) << "axis " << i;
  }
}

TEST(SimulatedForceSensor, SaturatesAtItsRange) {
  SimulatedForceSensorParameters p = quiet();
  p.range = 2.0;
  Bench b(p, -10.0);  // 10 mm in: 5 N
  b.cycle();
  b.cycle();
  EXPECT_EQ(b.sensor.read().force_n[2], -2.0);
  EXPECT_NEAR(b.sensor.truth().force_sensor[2], -5.0, 1e-9);
}

// A step in the contact shows up `latency` after it happened, stamped with the time it was sampled.
TEST(SimulatedForceSensor, ReadingsArriveAfterTheLatencyWithTheirSamplingTime) {
  for (const double latency : {0.002, 0.005}) {
    SimulatedForceSensorParameters p = quiet();
    p.latency = latency;
    Bench b(p, 5.0);
    for (int k = 0; k < 10; ++k) b.cycle();
    ASSERT_EQ(b.sensor.read().force_n[2], 0.0);
    const auto stamp_ns = [](Clock::time_point t) {
      return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
    };
    EXPECT_EQ(b.sensor.read().stamp_ns,
              stamp_ns(b.now) - static_cast<std::int64_t>(std::llround(latency * 1e9)));
    b.move_floor_to(-1.0);  // the floor jumps 6 mm up, into the probe, between two cycles
    const auto jumped = b.now;
    int cycles = 0;
    while (b.sensor.read().force_n[2] == 0.0 && cycles < 20) {
      b.cycle();
      ++cycles;
    }
    // Samples are taken at 1 kHz on the 2 ms cycle; the first one after the jump (1 ms after it) is
    // visible at the first cycle its latency has passed: 4 ms (2 cycles) for 2 ms, 6 ms (3) for 5 ms.
    EXPECT_EQ(cycles, latency < 0.003 ? 2 : 3) << "latency " << latency;
    EXPECT_GT(b.sensor.read().stamp_ns, stamp_ns(jumped));
    EXPECT_NEAR(-b.sensor.read().force_n[2], 0.5, 1e-9);
  }
}

TEST(SimulatedForceSensor, SilentSensorGoesStale) {
  Bench b(quiet(), 5.0);
  b.cycle();
  const std::int64_t before = b.sensor.read().stamp_ns;
  b.sensor.set_silent(true);
  for (int k = 0; k < 10; ++k) b.cycle();
  EXPECT_EQ(b.sensor.read().stamp_ns, before);
  b.sensor.set_silent(false);
  b.cycle();
  EXPECT_GT(b.sensor.read().stamp_ns, before);
}

TEST(SimulatedForceSensor, SamplingDoesNotAllocate) {
  Bench b(SimulatedForceSensorParameters{}, -1.0);
  b.cycle();
  const long before = tendril::testing::allocation_count.load();
  double sink = 0.0;
  for (int k = 0; k < 2000; ++k) {
    b.cycle();
    sink += b.sensor.read().force_n[2];
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  ::operator delete(::operator new(16));  // the counter sees allocations, so the check above can fail
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

TEST(SimulatedForceSensor, RunsInItsOwnThreadWhenActivated) {
  Bench b(quiet(), -2.0);
  b.sensor.activate(false);
  bool valid = false;
  for (int k = 0; k < 5000 && !valid; ++k) {
    valid = b.sensor.read().valid;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  EXPECT_TRUE(valid);
  EXPECT_NEAR(-b.sensor.read().force_n[2], 1.0, 1e-9);
  b.sensor.deactivate(std::chrono::milliseconds(100), {});
  EXPECT_FALSE(b.sensor.read().valid);
  EXPECT_FALSE(b.sensor.running());
}

}  // namespace
}  // namespace tendril::sim
