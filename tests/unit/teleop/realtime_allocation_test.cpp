// The per-tick teleop functions must not touch the heap.
#include <gtest/gtest.h>

#include <array>
#include <memory>

#include "allocation_counter.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/pid.hpp"
#include "tendril/teleop/quintic_interpolator.hpp"

namespace tendril::teleop {
namespace {

TEST(TeleopRealtime, TickPathDoesNotAllocate) {
  QuinticInterpolator interp(4);
  Pid pid({.kp = 2.0, .ki = 1.0, .kd = 0.01, .output_limit = 5.0, .derivative_filter_time = 0.002});
  const ConstantCurvatureCatheter cat(CatheterParameters{});
  std::array<double, 4> q{}, qd{}, qdd{}, goal{10.0, 0.5, 0.3, -0.4};
  std::array<Eigen::Vector3d, 64> backbone;
  double sink = 0.0;

  const long before = tendril::testing::allocation_count.load();
  interp.reset(q);
  EXPECT_EQ(interp.retarget(0.0, goal, 2.0, 5.0), RetargetStatus::kOk);
  for (int i = 0; i < 1000; ++i) {
    const double t = i * 1e-3;
    if (i == 500) interp.retarget(t, std::array<double, 4>{1.0, -0.5, 0.0, 0.2}, 2.0, 5.0);
    interp.sample(t, q, qd, qdd);
    sink += pid.update(q[0], 0.9 * q[0], 1e-3);
    const ConstantCurvatureCatheter::JointVector jq(q[0], q[1], q[2], q[3]);
    sink += cat.tip_pose(jq).position.x();
    sink += cat.tip_position_jacobian(jq)(0, 2);
    sink += static_cast<double>(cat.backbone(jq, 20, backbone));
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  // The counter really sees allocations, so the check above can fail.
  tendril::testing::allocate_probe();
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
  EXPECT_TRUE(std::isfinite(sink));
}

}  // namespace
}  // namespace tendril::teleop
