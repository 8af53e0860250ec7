// The SDU safety laws with the dissertation's numbers, and the supervisor's defined state for every fault:
// a silent disk, an unusable ToF or Hall reading, a drifting baseline; each shown, logged and safe.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/continuum/sdu_safety.hpp"
#include "tendril/continuum/sdu_simulation.hpp"

namespace tendril::continuum {
namespace {

TEST(SduLaws, ProximitySpeedScalingT32) {
  ProximityParameters p;
  p.d_max_mm = 100.0;  // the nominal range
  EXPECT_DOUBLE_EQ(proximity_speed_limit(p, 0.0), 0.25);
  EXPECT_DOUBLE_EQ(proximity_speed_limit(p, 50.0), 25.125);
  EXPECT_DOUBLE_EQ(proximity_speed_limit(p, 100.0), 50.0);
  EXPECT_DOUBLE_EQ(proximity_speed_limit(p, 1e6), 50.0);
  const ProximityParameters def;  // tendril's d_max = 130 mm
  EXPECT_DOUBLE_EQ(proximity_speed_limit(def, 65.0), 25.125);
  EXPECT_DOUBLE_EQ(proximity_speed_limit(def, std::nan("")), 0.25);  // unknown distance: the safe speed
  EXPECT_DOUBLE_EQ(proximity_speed_limit(def, -3.0), 0.25);
  EXPECT_NEAR(effective_distance(80.0, M_PI / 3), 40.0, 1e-12);  // (3.5)
}

TEST(SduLaws, CapKeepsDirection) {
  const Eigen::Vector3d v = cap_speed({30, 40, 0}, 10.0);
  EXPECT_NEAR((v - Eigen::Vector3d(6, 8, 0)).norm(), 0.0, 1e-12);
  EXPECT_EQ(cap_speed({1, 0, 0}, 10.0), Eigen::Vector3d(1, 0, 0));
  EXPECT_EQ(cap_speed({std::nan(""), 0, 0}, 10.0), Eigen::Vector3d::Zero());
  EXPECT_EQ(cap_speed({1, 0, 0}, std::nan("")), Eigen::Vector3d::Zero());
}

TEST(SduLaws, NoSlipRollKeepsTheContactPointStill) {
  const Eigen::Vector3d r_c(0, 79, 0), z(0, 0, 1);
  const auto twist = no_slip_roll_twist(r_c, z, 0.2);
  const Eigen::Vector3d v = twist.head<3>(), w = twist.tail<3>();
  EXPECT_NEAR((v + w.cross(r_c)).norm(), 0.0, 1e-12);  // velocity of the contact point
  EXPECT_NEAR(w.z(), 0.2, 1e-12);
  EXPECT_NEAR(v.norm(), 0.2 * 79, 1e-9);  // the centre rolls along the surface
  EXPECT_EQ(no_slip_roll_twist(r_c, z, std::nan("")), (Eigen::Matrix<double, 6, 1>::Zero()));
}

TEST(SduLaws, GuidanceMovesAwayFromAHandAndYieldsToAPush) {
  GuidanceParameters g;
  // Hand 30 mm from the left sensor, nothing on the right: move right.
  EXPECT_GT(contactless_guidance(g, std::nan(""), 30.0), 0.0);
  EXPECT_DOUBLE_EQ(contactless_guidance(g, 100.0, 60.0), 0.5 * 40.0 > 20.0 ? 20.0 : 0.5 * 40.0);
  EXPECT_DOUBLE_EQ(contactless_guidance(g, 61.0, 60.0), 0.0);  // deadband
  // Push on the right window (ΔB_z,r = 0.5 mT): move left.
  EXPECT_LT(contact_guidance(g, 0.5, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(contact_guidance(g, 0.3, 0.1), -20.0 * 0.2);
  EXPECT_DOUBLE_EQ(contact_guidance(g, 0.02, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(contact_guidance(g, std::nan(""), 0.0), 0.0);
  EXPECT_DOUBLE_EQ(contact_guidance(g, 10.0, 0.0), -20.0);  // saturated
  EXPECT_STREQ(to_string(GuidanceMode::kContactBased), "contact_based");
}

TEST(SduLaws, GuidanceModesFromTheTopDisksSample) {
  GuidanceParameters g;
  const GuidancePair pair;
  HallBias bias;
  SduSample top;
  top.received = true;
  top.tof_status.fill(TofStatus::kNoTarget);
  top.hall_ok.fill(true);
  for (std::size_t j = 0; j < kHallPerSdu; ++j) top.hall_mT[j] = bias.b0_mT[j] = {0.1, -0.2, 9.0};
  // A hand 40 mm from the left window (slot 2): contactless guidance moves right, at most 20 mm/s.
  top.tof_status[pair.tof_left] = TofStatus::kValid;
  top.tof_mm[pair.tof_left] = 40.0;
  EXPECT_DOUBLE_EQ(guidance_command(GuidanceMode::kContactless, g, pair, top, bias), 20.0);
  EXPECT_DOUBLE_EQ(guidance_command(GuidanceMode::kOff, g, pair, top, bias), 0.0);
  // A push on the right window: contact-based guidance yields, to the left.
  top.hall_mT[pair.hall_right][2] += 0.4;
  EXPECT_DOUBLE_EQ(guidance_command(GuidanceMode::kContactBased, g, pair, top, bias), -8.0);
  top.hall_ok[pair.hall_left] = false;
  EXPECT_DOUBLE_EQ(guidance_command(GuidanceMode::kContactBased, g, pair, top, bias), 0.0);
  GuidancePair bad;
  bad.tof_right = 8;
  EXPECT_DOUBLE_EQ(guidance_command(GuidanceMode::kContactless, g, bad, top, bias), 0.0);
}

// Samples from 5 SIMULATED nodes in an empty scene, unbiased, then one thing at a time goes wrong.
class SduSupervisorTest : public ::testing::Test {
 protected:
  SduSupervisorTest() : supervisor_(std::make_unique<SduSupervisor>(model_, kSdusPerSegment, params_)) {
    for (std::size_t i = 0; i < kSdusPerSegment; ++i)
      nodes_.emplace_back(model_, TofModel{}, HallModel{}, 100 + i);
    poses_ = disk_poses(model_, {});
  }
  void sense(double dt = 0.01) {
    now_ns_ += static_cast<std::int64_t>(dt * 1e9);
    for (std::size_t i = 0; i < kSdusPerSegment; ++i) {
      if (silent_[i]) continue;
      samples_[i] = nodes_[i].sense(scene_, poses_[i], now_ns_ * 1e-9);
      samples_[i].stamp_ns = now_ns_;
    }
  }
  const SduSafetyDecision& step() { return supervisor_->step(now_ns_, poses_, samples_); }
  void unbias() {
    for (int k = 0; k < 60; ++k) {
      sense();
      step();
    }
    ASSERT_EQ(supervisor_->decision().state, SduSafetyState::kClear);
  }
  std::vector<std::string> drain() {
    std::vector<std::string> out;
    supervisor_->events().drain([&](const safety::SafetyEvent& e) { out.emplace_back(e.text); });
    return out;
  }
  SduSegmentModel model_;
  SduSupervisorParameters params_;
  std::unique_ptr<SduSupervisor> supervisor_;
  std::vector<SimulatedSduNode> nodes_;
  std::array<Eigen::Isometry3d, kSdusPerSegment> poses_;
  std::array<SduSample, kSdusPerSegment> samples_{};
  std::array<bool, kSdusPerSegment> silent_{};
  Scene scene_;
  std::int64_t now_ns_ = 1'000'000'000;
};

TEST_F(SduSupervisorTest, HoldsWhileUnbiasingThenRunsAtFullSpeedInTheOpen) {
  sense();
  EXPECT_EQ(step().state, SduSafetyState::kUnbiasing);
  EXPECT_EQ(supervisor_->decision().speed_limit_mm_s, 0.0);
  unbias();
  EXPECT_DOUBLE_EQ(supervisor_->decision().speed_limit_mm_s, 50.0);
  for (std::size_t i = 0; i < kSdusPerSegment; ++i)
    for (std::size_t j = 0; j < kHallPerSdu; ++j)
      EXPECT_NEAR(supervisor_->bias()[i].b0_mT[j][2], nodes_[i].rest_field()[j][2], 0.003);
  const auto log = drain();
  ASSERT_FALSE(log.empty());
  EXPECT_NE(log.front().find("unbiasing"), std::string::npos) << log.front();
  EXPECT_NE(log.back().find("clear"), std::string::npos) << log.back();
}

TEST_F(SduSupervisorTest, ASilentDiskHoldsTheRobotAndNothingIsLostWhenItReturns) {
  unbias();
  silent_[3] = true;
  for (int k = 0; k < 3; ++k) {
    sense();
    step();
  }
  EXPECT_EQ(supervisor_->decision().state, SduSafetyState::kClear);  // 20 ms: within the 30 ms bound
  sense();
  sense();
  const auto& d = step();
  EXPECT_EQ(d.state, SduSafetyState::kHold);
  EXPECT_EQ(d.cause, SduCause::kSduSilent);
  EXPECT_EQ(d.disk, 3);
  EXPECT_EQ(d.speed_limit_mm_s, 0.0);
  EXPECT_EQ(apply_sdu_safety(d, params_, {10, 0, 0}), Eigen::Vector3d::Zero());
  char buf[96];
  EXPECT_STREQ(describe(d, buf, sizeof buf), "SDU 3 silent for 50 ms: holding");
  const auto log = drain();
  EXPECT_EQ(log.back(), "SDU 3 silent for 50 ms: holding");
  silent_[3] = false;
  sense();
  EXPECT_EQ(step().state, SduSafetyState::kClear);  // the disk speaks again: the hold ends, logged
  EXPECT_NE(drain().back().find("clear"), std::string::npos);
}

TEST_F(SduSupervisorTest, ANeverHeardDiskHoldsFromTheStart) {
  silent_[0] = true;
  sense();
  const auto& d = step();
  EXPECT_EQ(d.state, SduSafetyState::kHold);
  EXPECT_EQ(d.cause, SduCause::kSduSilent);
  char buf[96];
  EXPECT_STREQ(describe(d, buf, sizeof buf), "SDU 0 has sent no sample yet: holding");
}

TEST_F(SduSupervisorTest, AnUnusableToFReadingSlowsToTheSafeSpeed) {
  unbias();
  for (auto bad : {std::nan(""), -1.0, 1e9}) {
    sense();
    samples_[2].tof_status[5] = TofStatus::kValid;
    samples_[2].tof_mm[5] = bad;
    const auto& d = step();
    EXPECT_EQ(d.state, SduSafetyState::kSlowed) << bad;
    EXPECT_EQ(d.cause, SduCause::kTofInvalid);
    EXPECT_EQ(d.disk, 2);
    EXPECT_EQ(d.slot, 5);
    EXPECT_DOUBLE_EQ(d.speed_limit_mm_s, 0.25);
    EXPECT_NEAR(apply_sdu_safety(d, params_, {50, 0, 0}).norm(), 0.25, 1e-12);
  }
  sense();
  samples_[2].tof_status[5] = TofStatus::kSensorError;
  EXPECT_EQ(step().cause, SduCause::kTofInvalid);
  const auto log = drain();
  EXPECT_NE(log.back().find("SDU 2 ToF 5 reading unusable"), std::string::npos) << log.back();
  sense();
  EXPECT_EQ(step().state, SduSafetyState::kClear);
}

TEST_F(SduSupervisorTest, AnUnusableHallReadingHolds) {
  unbias();
  for (auto bad : {std::nan(""), std::numeric_limits<double>::infinity(), 500.0}) {
    sense();
    samples_[4].hall_mT[1][0] = bad;
    const auto& d = step();
    EXPECT_EQ(d.state, SduSafetyState::kHold) << bad;
    EXPECT_EQ(d.cause, SduCause::kHallInvalid);
    EXPECT_EQ(d.disk, 4);
    EXPECT_EQ(d.slot, 1);
  }
  sense();
  samples_[4].hall_ok[7] = false;  // the node's error code
  EXPECT_EQ(step().slot, 7);
  EXPECT_NE(drain().back().find("SDU 4 Hall 7 reading unusable"), std::string::npos);
}

TEST_F(SduSupervisorTest, ADriftingBaselineHoldsUntilUnbiasedAgain) {
  unbias();
  nodes_[1].hall().drift_mT_per_s = -0.02;  // the field sinks: contacts there would be missed
  int cycles = 0;
  while (supervisor_->decision().state == SduSafetyState::kClear && cycles < 2000) {
    sense();
    step();
    ++cycles;
  }
  const auto& d = supervisor_->decision();
  EXPECT_EQ(d.state, SduSafetyState::kHold);
  EXPECT_EQ(d.cause, SduCause::kBaselineDrift);
  EXPECT_EQ(d.disk, 1);
  // Found within the filter's lag plus the 2 s dwell after crossing 0.06 mT (3 s of drift).
  EXPECT_LT(cycles * 0.01, 3.0 + 0.5 + 2.0 + 0.1);
  const auto drift_log = drain();
  EXPECT_NE(drift_log.back().find("baseline drifted"), std::string::npos);
  std::printf("drift hold after %.2f s of drift: \"%s\"\n", cycles * 0.01, drift_log.back().c_str());
  // It stays held however long; an operator's unbias (the drift stopped) brings the robot back.
  for (int k = 0; k < 100; ++k) {
    sense();
    step();
  }
  EXPECT_EQ(supervisor_->decision().cause, SduCause::kBaselineDrift);
  nodes_[1].hall().drift_mT_per_s = 0.0;
  // (the simulated drift is t·rate: freezing the rate puts the offset back, as a recalibrated magnet would)
  EXPECT_TRUE(supervisor_->request_unbias());
  unbias();
}

TEST_F(SduSupervisorTest, ContactStopsInTheCycleItIsSeenAndOnlyRetreatIsAllowed) {
  unbias();
  sense();
  samples_[4].hall_mT[2][2] = supervisor_->bias()[4].b0_mT[2][2] + 0.26;  // 1 N on the top disk, window 2
  const auto& d = step();
  EXPECT_EQ(d.state, SduSafetyState::kContact);
  EXPECT_EQ(d.disk, 4);
  EXPECT_EQ(d.slot, 2);
  EXPECT_NEAR(d.value, 1.0, 0.05);
  EXPECT_EQ(d.speed_limit_mm_s, 0.0);
  const Eigen::Vector3d n = d.contact.normal;
  EXPECT_EQ(apply_sdu_safety(d, params_, 10 * n), Eigen::Vector3d::Zero());  // into the contact
  const Eigen::Vector3d tangent = n.cross(Eigen::Vector3d::UnitZ());
  EXPECT_EQ(apply_sdu_safety(d, params_, 10 * tangent), Eigen::Vector3d::Zero());   // sliding
  EXPECT_NEAR((apply_sdu_safety(d, params_, -20 * n) + 5 * n).norm(), 0.0, 1e-12);  // away, at 5 mm/s
  EXPECT_FALSE(supervisor_->request_unbias());  // never re-zero under a load
  // The no-slip roll about the contact: the disk centre at most 5 mm/s (r_c = 79 mm).
  EXPECT_NEAR(apply_sdu_roll(d, params_, 1.0), 5.0 / 79.0, 1e-9);
  EXPECT_NEAR(apply_sdu_roll(d, params_, -0.01), -0.01, 1e-12);
  EXPECT_EQ(apply_sdu_roll(d, params_, std::nan("")), 0.0);
  char buf[96];
  EXPECT_STREQ(describe(d, buf, sizeof buf), "contact on SDU 4 Hall 2 (112.5 deg), 1.00 N: stopped");
  // A contact between windows 2 and 3 whose strongest window alternates is one event, not one per
  // sample; a contact that jumps to a window across the disk is logged.
  drain();
  for (int k = 0; k < 10; ++k) {
    sense();
    samples_[4].hall_mT[2 + k % 2][2] = supervisor_->bias()[4].b0_mT[2 + k % 2][2] + 0.26;
    samples_[4].hall_mT[3 - k % 2][2] = supervisor_->bias()[4].b0_mT[3 - k % 2][2] + 0.2;
    EXPECT_EQ(step().slot, 2 + k % 2);
  }
  EXPECT_TRUE(drain().empty());
  sense();
  samples_[4].hall_mT[6][2] = supervisor_->bias()[4].b0_mT[6][2] + 0.26;
  EXPECT_EQ(step().slot, 6);
  const auto moved = drain();
  ASSERT_EQ(moved.size(), 1U);
  EXPECT_NE(moved.front().find("Hall 6"), std::string::npos) << moved.front();
  // Hysteresis: 0.3 N keeps the contact, 0.1 N releases it.
  sense();
  samples_[4].hall_mT[2][2] = supervisor_->bias()[4].b0_mT[2][2] + 0.3 * 0.26;
  EXPECT_EQ(step().state, SduSafetyState::kContact);
  sense();
  EXPECT_EQ(step().state, SduSafetyState::kClear);
}

TEST_F(SduSupervisorTest, ProximityScalesTheCommandedSpeed) {
  unbias();
  // A wall 65 mm in front of every disk's slot 0.
  scene_.add(ScenePlane{Eigen::Vector3d(79 + 65, 0, 0), -Eigen::Vector3d::UnitX()});
  sense();
  const auto& d = step();
  EXPECT_EQ(d.state, SduSafetyState::kClear);
  EXPECT_NEAR(d.nearest_d_e_mm, 65.0, 2.0);
  EXPECT_NEAR(d.speed_limit_mm_s, 25.125, 0.8);
  EXPECT_NEAR(apply_sdu_safety(d, params_, {100, 0, 0}).norm(), d.speed_limit_mm_s, 1e-12);
  EXPECT_EQ(apply_sdu_roll(d, params_, 0.1), 0.0);  // no contact, nothing to roll about
}

// (3.5) with the map's planes: a wall leaning 60° from the lowest disk's slot 0 line of sight (and
// farther from every other sensor) is read along that line, d_e = d·cos 60° once the plane is mapped.
TEST_F(SduSupervisorTest, MappedPlanesGiveTheEffectiveDistanceItsAngle) {
  unbias();
  const Eigen::Vector3d n(std::cos(M_PI / 3), 0.0, -std::sin(M_PI / 3));  // towards the wall, from the robot
  const double offset = n.dot(Eigen::Vector3d(79.0, 0.0, 74.0)) + 40.0;   // 40 mm from disk 0's window
  scene_.add(ScenePlane{offset * n, -n});
  sense();
  const double without = step().nearest_d_e_mm;
  EXPECT_GT(without, 55.0);  // read along the tilted line of sight (the cone's nearest return)
  const Plane mapped{n, offset};
  supervisor_->set_planes(std::span(&mapped, 1));
  sense();
  const auto& d = step();
  EXPECT_NEAR(d.nearest_d_e_mm, 0.5 * without, 1.5);
  EXPECT_LT(d.nearest_d_e_mm, 40.0);
  EXPECT_NEAR(d.speed_limit_mm_s, proximity_speed_limit(params_.proximity, d.nearest_d_e_mm), 1e-12);
  std::printf("a wall 40 mm away, leaning 60 deg: d_e %.1f mm without the mapped plane, %.1f mm with it\n",
              without, d.nearest_d_e_mm);
  supervisor_->set_planes({});
  sense();
  EXPECT_NEAR(step().nearest_d_e_mm, without, 1.5);
}

TEST_F(SduSupervisorTest, StepNeverAllocates) {
  unbias();
  scene_.add(ScenePlane{Eigen::Vector3d(79 + 65, 0, 0), -Eigen::Vector3d::UnitX()});
  std::vector<std::array<SduSample, kSdusPerSegment>> inputs;
  for (int k = 0; k < 300; ++k) {
    sense();
    auto s = samples_;
    if (k % 50 == 10) s[1].tof_mm[0] = std::nan("");
    if (k % 50 == 20) s[2].hall_ok[3] = false;
    if (k % 50 == 30) s[3].hall_mT[1][2] += 1.0;
    if (k % 50 == 40) s[4].stamp_ns -= 100'000'000;
    inputs.push_back(s);
  }
  const Plane wall{-Eigen::Vector3d::UnitX(), -(79.0 + 65.0)};
  supervisor_->set_planes(std::span(&wall, 1));
  std::int64_t t = now_ns_ - 300LL * 10'000'000;
  const long before = tendril::testing::allocation_count.load();
  for (const auto& s : inputs) {
    t += 10'000'000;
    const auto& d = supervisor_->step(t, poses_, s);
    (void)apply_sdu_safety(d, params_, {10, 20, 0});
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  EXPECT_GT(supervisor_->events().pushed(), 10U);
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
}

TEST(SduSupervisorSetup, RefusesBadParametersWithTheirNames) {
  SduSegmentModel m;
  SduSupervisorParameters p;
  EXPECT_THROW(SduSupervisor(m, 0, p), std::invalid_argument);
  p.proximity.v_min_mm_s = 60.0;
  try {
    SduSupervisor s(m, 5, p);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("v_min"), std::string::npos);
  }
}

}  // namespace
}  // namespace tendril::continuum
