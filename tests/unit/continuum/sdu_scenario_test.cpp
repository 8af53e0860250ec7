// Scenario in stepped time (100 Hz, the seed's continuum-robot loop): a SIMULATED arm (a 50.8 mm rod, the
// seed's wrist) approaches the segment's top disk and stops 40 mm short; the operator commands the tip
// towards it at 50 mm/s. The disks' samples travel as CAN frames through the assembler into the
// supervisor; the commanded speed scales down with the distance and the contact stops the segment in
// the cycle it is felt. The stopping distance and time are printed (README, issue 16).
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

TEST(SduScenario, ApproachingArmSlowsThenStopsTheSegmentOnTouch) {
  const SduSegmentModel model;
  const SduSupervisorParameters params;
  SduSupervisor supervisor(model, kSdusPerSegment, params);
  SduFrameAssembler bus(kSdusPerSegment);
  std::vector<SimulatedSduNode> nodes;
  for (std::size_t i = 0; i < kSdusPerSegment; ++i)
    nodes.emplace_back(model, TofModel{}, HallModel{}, 40 + i);

  Scene scene;
  const double rod_radius = 25.4, rest_gap = 40.0;
  // An upright forearm beside the segment: a vertical rod from the floor to 600 mm.
  const double z_arm = 300.0;
  const std::size_t arm = scene.add(SceneCylinder{Eigen::Vector3d(0, 79 + rod_radius + 250, z_arm),
                                                  Eigen::Vector3d::UnitZ(), rod_radius, 300.0});
  double arm_y = 79 + rod_radius + 250;
  const double arm_rest_y = 79 + rod_radius + rest_gap;

  SegmentConfiguration q{0.0, 0.0, M_PI / 2};  // bends towards +y, the arm's side
  constexpr double dt = 0.01;
  std::int64_t now_ns = 1'000'000'000;
  std::array<SduSample, kSdusPerSegment> samples{};

  double first_slow_s = -1, touch_s = -1, contact_s = -1, stop_s = -1;
  Eigen::Vector3d tip_at_touch = Eigen::Vector3d::Zero(), tip_at_stop = Eigen::Vector3d::Zero();
  double speed_at_touch = 0.0, force_at_stop = 0.0;
  double previous_speed = 0.0;
  std::vector<std::pair<double, double>> speed_by_gap;  // (true gap mm, commanded speed mm/s)
  bool stopped_in_contact_cycle = false;
  int unbias_cycles = 0;

  for (int k = 0; k < 3000 && stop_s < 0; ++k) {
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
      for (const auto& frame : encode_sdu_sample(i, s)) bus.handle(frame, now_ns);
      samples[i] = bus.latest(i);
    }
    const auto& d = supervisor.step(now_ns, poses, samples);
    if (d.state == SduSafetyState::kUnbiasing) {
      ++unbias_cycles;
      continue;
    }
    // The operator asks for 50 mm/s of the tip along its bending direction.
    const Eigen::Vector3d dtip = tip_position_per_bending(model, q);
    const Eigen::Vector3d v_cmd = 50.0 * dtip.normalized();
    const Eigen::Vector3d v = apply_sdu_safety(d, params, v_cmd);
    const double speed = v.dot(dtip.normalized());  // only motion along the bending direction is possible
    const Eigen::Vector3d tip = poses.back().translation();
    const Eigen::Vector3d rim =
        poses.back() * Eigen::Vector3d(0, 79, 0);  // the sleeve's point facing the arm
    const double gap = Eigen::Vector2d(rim.x(), rim.y() - arm_y).norm() - rod_radius;
    if (first_slow_s < 0 && speed < 50.0 - 1e-9) first_slow_s = t;
    if (k % 10 == 0) speed_by_gap.emplace_back(gap, speed);
    if (k % 100 == 0 && std::getenv("SDU_SCENARIO_TRACE"))
      std::printf("t %.1f theta %.3f tip %.1f %.1f %.1f gap %.1f speed %.2f d_e %.1f state %s\n", t,
                  q.bending_rad, tip.x(), tip.y(), tip.z(), gap, speed, d.nearest_d_e_mm, to_string(d.state));
    if (touch_s < 0 && true_force > 0.0) {
      touch_s = t;
      tip_at_touch = tip;
      speed_at_touch = previous_speed;
    }
    if (contact_s < 0 && d.state == SduSafetyState::kContact) {
      contact_s = t;
      stopped_in_contact_cycle = v.norm() == 0.0;  // the same cycle's command is already zero
    }
    if (contact_s >= 0 && speed == 0.0) {
      stop_s = t;
      tip_at_stop = tip;
      force_at_stop = d.value;
    }
    q.bending_rad = std::clamp(q.bending_rad + speed / dtip.norm() * dt, 0.0, model.max_bending_rad);
    previous_speed = speed;
  }
  ASSERT_GT(touch_s, 0.0) << "the arm was never touched";
  ASSERT_GT(contact_s, 0.0) << "the contact was never detected";
  ASSERT_GT(stop_s, 0.0);
  EXPECT_TRUE(stopped_in_contact_cycle);
  EXPECT_EQ(stop_s, contact_s);
  EXPECT_EQ(supervisor.decision().disk, 4);  // the top disk
  const int slot = supervisor.decision().slot;
  EXPECT_TRUE(slot == 1 || slot == 2) << slot;  // the windows at 67.5° and 112.5°, either side of +y
  EXPECT_GT(first_slow_s, 0.0);
  EXPECT_LT(speed_at_touch, 1.0);  // the proximity law brought it near v_min before the touch
  const double stop_distance = (tip_at_stop - tip_at_touch).norm();
  const double stop_time = stop_s - touch_s;
  EXPECT_LT(stop_distance, 0.05);  // one cycle at about v_min
  EXPECT_EQ(bus.counters().incomplete, 0U);
  std::printf("scenario: unbiased in %d cycles; slowing began at t = %.2f s; speed by gap to the arm:",
              unbias_cycles, first_slow_s);
  for (const auto& [g, s] : speed_by_gap)
    if (g < 130 && static_cast<int>(g) % 10 < 2) std::printf(" %.0f mm: %.2f mm/s;", g, s);
  std::printf(
      "\nscenario: touch at t = %.2f s at %.2f mm/s; contact detected at t = %.2f s (%.2f N), command zero "
      "in "
      "that cycle; stopping distance %.3f mm, stopping time %.0f ms after the first touch\n",
      touch_s, speed_at_touch, contact_s, force_at_stop, stop_distance, stop_time * 1000);
}

}  // namespace
}  // namespace tendril::continuum
