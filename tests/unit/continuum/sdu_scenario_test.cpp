// Scenario in stepped time (100 Hz, the dissertation's continuum-robot loop): a SIMULATED arm (an
// upright 50.8 mm rod, the dissertation's wrist) approaches the segment's top disk at 20 mm/s; the operator
// commands the tip towards it at 50 mm/s. The disks' samples travel as CAN frames through the assembler into
// the supervisor; the commanded speed scales down with the distance and the contact stops the segment in the
// cycle it is felt. Run with the disks at 100 Hz (tendril's CAN layout) and at the dissertation's 4.26 Hz;
// the stopping distance and time are printed (teleop/sdu_continuum/README.md).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "tendril/continuum/sdu_frames.hpp"
#include "tendril/continuum/sdu_safety.hpp"
#include "tendril/continuum/sdu_simulation.hpp"

namespace tendril::continuum {
namespace {

struct ScenarioResult {
  double first_slow_s = -1, touch_s = -1, contact_s = -1, stop_s = -1;
  double speed_at_touch = 0.0, force_at_stop = 0.0, stop_distance = 0.0;
  bool stopped_in_contact_cycle = false;
  int unbias_cycles = 0, contact_disk = -1, contact_slot = -1;
  std::uint64_t incomplete = 0;
  std::vector<std::pair<double, double>> speed_by_gap;  // (true gap mm, commanded speed mm/s)
};

// The disks sample every sense_every control cycles (1: 100 Hz; 23: the dissertation's 4.26 Hz).
ScenarioResult run_scenario(int sense_every, const SduSupervisorParameters& params) {
  const SduSegmentModel model;
  ScenarioResult r;
  SduSupervisor supervisor(model, kSdusPerSegment, params);
  SduFrameAssembler bus(kSdusPerSegment);
  std::vector<SimulatedSduNode> nodes;
  for (std::size_t i = 0; i < kSdusPerSegment; ++i)
    nodes.emplace_back(model, TofModel{}, HallModel{}, 40 + i);

  Scene scene;
  const double rod_radius = 25.4, rest_gap = 40.0;
  // An upright forearm beside the segment: a vertical rod from the floor to 600 mm.
  const double z_arm = 300.0;
  double arm_y = 79 + rod_radius + 250;
  const std::size_t arm =
      scene.add(SceneCylinder{Eigen::Vector3d(0, arm_y, z_arm), Eigen::Vector3d::UnitZ(), rod_radius, 300.0});
  const double arm_rest_y = 79 + rod_radius + rest_gap;

  SegmentConfiguration q{0.0, 0.0, M_PI / 2};  // bends towards +y, the arm's side
  constexpr double dt = 0.01;
  std::int64_t now_ns = 1'000'000'000;
  std::array<SduSample, kSdusPerSegment> samples{};
  Eigen::Vector3d tip_at_touch = Eigen::Vector3d::Zero(), tip_at_stop = Eigen::Vector3d::Zero();
  double previous_speed = 0.0;

  for (int k = 0; k < 6000 && r.stop_s < 0; ++k) {
    const double t = k * dt;
    now_ns += 10'000'000;
    // The arm moves in at 20 mm/s once the robot is unbiased, and stops 40 mm from the sleeve.
    if (supervisor.decision().state != SduSafetyState::kUnbiasing && arm_y > arm_rest_y) {
      arm_y = std::max(arm_rest_y, arm_y - 20.0 * dt);
      scene.move_cylinder(arm, Eigen::Vector3d(0, arm_y, z_arm));
    }
    const auto poses = disk_poses(model, q);
    double true_force = 0.0;
    for (std::size_t i = 0; i < kSdusPerSegment; ++i) {
      const auto s = nodes[i].sense(scene, poses[i], t);
      for (double f : nodes[i].true_force()) true_force = std::max(true_force, f);
      if (k % sense_every != 0) continue;  // this disk sends nothing this cycle
      for (const auto& frame : encode_sdu_sample(i, s)) bus.handle(frame, now_ns);
      samples[i] = bus.latest(i);
    }
    const auto& d = supervisor.step(now_ns, poses, samples);
    if (d.state == SduSafetyState::kUnbiasing) {
      ++r.unbias_cycles;
      continue;
    }
    // The operator asks for 50 mm/s of the tip along its bending direction.
    const Eigen::Vector3d dtip = tip_position_per_bending(model, q);
    const Eigen::Vector3d v = apply_sdu_safety(d, params, 50.0 * dtip.normalized());
    const double speed = v.dot(dtip.normalized());  // only motion along the bending direction is possible
    const Eigen::Vector3d tip = poses.back().translation();
    const Eigen::Vector3d rim =
        poses.back() * Eigen::Vector3d(0, 79, 0);  // the sleeve's point facing the arm
    const double gap = Eigen::Vector2d(rim.x(), rim.y() - arm_y).norm() - rod_radius;
    if (r.first_slow_s < 0 && speed < 50.0 - 1e-9) r.first_slow_s = t;
    if (k % 10 == 0) r.speed_by_gap.emplace_back(gap, speed);
    if (k % 100 == 0 && std::getenv("SDU_SCENARIO_TRACE"))
      std::printf("t %.1f theta %.3f tip %.1f %.1f %.1f gap %.1f speed %.2f d_e %.1f state %s\n", t,
                  q.bending_rad, tip.x(), tip.y(), tip.z(), gap, speed, d.nearest_d_e_mm, to_string(d.state));
    if (r.touch_s < 0 && true_force > 0.0) {
      r.touch_s = t;
      tip_at_touch = tip;
      r.speed_at_touch = previous_speed;
    }
    if (r.contact_s < 0 && d.state == SduSafetyState::kContact) {
      r.contact_s = t;
      r.stopped_in_contact_cycle = v.norm() == 0.0;  // the same cycle's command is already zero
      r.contact_disk = d.disk;
      r.contact_slot = d.slot;
    }
    if (r.contact_s >= 0 && speed == 0.0) {
      r.stop_s = t;
      tip_at_stop = tip;
      r.force_at_stop = d.value;
    }
    q.bending_rad = std::clamp(q.bending_rad + speed / dtip.norm() * dt, 0.0, model.max_bending_rad);
    previous_speed = speed;
  }
  r.stop_distance = (tip_at_stop - tip_at_touch).norm();
  r.incomplete = bus.counters().incomplete;
  return r;
}

void print(const char* name, const ScenarioResult& r) {
  std::printf("scenario (%s): unbiased in %d cycles; slowing began at t = %.2f s; speed by gap to the arm:",
              name, r.unbias_cycles, r.first_slow_s);
  for (const auto& [g, s] : r.speed_by_gap)
    if (g < 130 && static_cast<int>(g) % 10 < 2) std::printf(" %.0f mm: %.2f mm/s;", g, s);
  std::printf(
      "\nscenario (%s): touch at t = %.2f s at %.2f mm/s; contact detected at t = %.2f s (%.2f N), command "
      "zero in that cycle; stopping distance %.3f mm, stopping time %.0f ms after the first touch\n",
      name, r.touch_s, r.speed_at_touch, r.contact_s, r.force_at_stop, r.stop_distance,
      (r.stop_s - r.touch_s) * 1000);
}

TEST(SduScenario, ApproachingArmSlowsThenStopsTheSegmentOnTouch) {
  const auto r = run_scenario(1, SduSupervisorParameters{});
  print("disks at 100 Hz", r);
  ASSERT_GT(r.touch_s, 0.0) << "the arm was never touched";
  ASSERT_GT(r.contact_s, 0.0) << "the contact was never detected";
  ASSERT_GT(r.stop_s, 0.0);
  EXPECT_TRUE(r.stopped_in_contact_cycle);
  EXPECT_EQ(r.stop_s, r.contact_s);
  EXPECT_EQ(r.contact_disk, 4);                                               // the top disk
  EXPECT_TRUE(r.contact_slot == 1 || r.contact_slot == 2) << r.contact_slot;  // 67.5° or 112.5°, beside +y
  EXPECT_GT(r.first_slow_s, 0.0);
  EXPECT_LT(r.speed_at_touch, 1.0);  // the proximity law brought it near v_min before the touch
  EXPECT_LT(r.stop_distance, 0.05);  // one cycle at about v_min
  EXPECT_LT(r.stop_s - r.touch_s, 0.0201);
  EXPECT_EQ(r.incomplete, 0U);
}

// The dissertation's 4.26 Hz for 5 disks (one sample every 23 cycles of 10 ms; the stale bound widened to 300
// ms so that the robot may move at all): the segment still stops, but later and farther.
TEST(SduScenario, AtTheDissertations426HzTheSameApproachStopsLaterAndFarther) {
  SduSupervisorParameters slow;
  slow.stale_after_ns = 300'000'000;
  slow.unbias_samples = 10;
  const auto fast = run_scenario(1, SduSupervisorParameters{});
  const auto r = run_scenario(23, slow);
  print("disks at 4.26 Hz", r);
  ASSERT_GT(r.contact_s, 0.0);
  ASSERT_GT(r.stop_s, 0.0);
  EXPECT_TRUE(r.stopped_in_contact_cycle);
  EXPECT_LE(r.stop_s - r.touch_s, 0.23 + 0.0101);  // at most one sample period and one cycle
  EXPECT_GE(r.stop_distance, fast.stop_distance);
}

}  // namespace
}  // namespace tendril::continuum
