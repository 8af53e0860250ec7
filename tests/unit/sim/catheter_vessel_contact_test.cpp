// SIMULATED catheter-vessel contact and the SRMC plant's coupling and potentiometer output.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/analog_input_node.hpp"
#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"
#include "tendril/teleop/catheter_kinematics.hpp"
#include "tendril/teleop/vessel_shaft.hpp"

namespace tendril::sim {
namespace {

// The assembled SRMC shape of config/robots/srmc.json: 22/18.8 mm, δ2 = −0.76, bend a·k per mm.
teleop::ModalCatheterParameters shape() {
  teleop::CatheterParameters cc;
  cc.proximal_length = 22.0;
  cc.distal_length = 18.8;
  cc.plane_offset = -0.76;
  cc.proximal_curvature_gain = 0.063 * 1.4;
  cc.distal_curvature_gain = 0.17 * 1.4;
  return teleop::constant_curvature_modal_parameters(cc);
}

TEST(CatheterVesselContact, AStraightCatheterInAStraightTubeTouchesNothing) {
  CatheterVesselContact contact(arc_channel(200.0, 20.0, 0.5), shape(), {});
  const auto f = contact.evaluate(Eigen::Vector4d(30.0, 0.0, 0.0, 0.0));
  EXPECT_EQ(f.points_in_contact, 0);
  EXPECT_EQ(f.total_force, 0.0);
  for (double g : f.generalised) EXPECT_EQ(g, 0.0);
}

TEST(CatheterVesselContact, APerPointLumenNarrowsWhereTheVesselDoes) {
  // A straight tube along z, 2.0 mm wide up to z = 50 and narrowing linearly to 0.7 mm at z = 100. The
  // catheter (radius 0.6) bent in the x-z plane touches where the lumen is narrow and not where it is wide.
  std::vector<Eigen::Vector3d> line;
  std::vector<double> radii;
  for (int i = 0; i <= 100; ++i) {
    line.emplace_back(0.0, 0.0, static_cast<double>(i));
    radii.push_back(i <= 50 ? 2.0 : 2.0 - 1.3 * (i - 50) / 50.0);
  }
  CatheterVesselContactParameters wide;
  wide.lumen_radius = 2.0;
  CatheterVesselContactParameters narrowing = wide;
  narrowing.lumen_radii = radii;
  CatheterVesselContact constant(line, shape(), wide);
  CatheterVesselContact varying(line, shape(), narrowing);
  // q3 = 0.4 mm bends the tip about 1 mm off the axis (0.088 rad/mm · 0.4 mm · (11 + 18.8) mm): inside
  // a 2 mm lumen (1.4 mm free) everywhere, not where 0.4 mm is left.
  const Eigen::Vector4d bent_shallow(5.0, 0.0, 0.4, 0.0);  // base at z = 5, tip at z ≈ 46
  const Eigen::Vector4d bent_deep(50.0, 0.0, 0.4, 0.0);    // the same shape from z = 50 to ≈ 91
  ASSERT_EQ(constant.evaluate(bent_shallow).points_in_contact, 0);
  ASSERT_EQ(constant.evaluate(bent_deep).points_in_contact, 0) << "a constant lumen: no contact anywhere";
  EXPECT_EQ(varying.evaluate(bent_shallow).points_in_contact, 0) << "where the lumen is still 2 mm";
  const auto deep = varying.evaluate(bent_deep);
  EXPECT_GT(deep.points_in_contact, 0) << "where it has narrowed";
  EXPECT_GT(deep.total_force, 0.0);
  // Radii that do not match the centerline, or a lumen narrower than the catheter, are refused.
  auto bad = narrowing;
  bad.lumen_radii.pop_back();
  EXPECT_THROW(CatheterVesselContact(line, shape(), bad), std::invalid_argument);
  bad = narrowing;
  bad.lumen_radii[70] = 0.5;
  EXPECT_THROW(CatheterVesselContact(line, shape(), bad), std::invalid_argument);
}

TEST(CatheterVesselContact, ACurvedWallPushesTheProximalCarriageTowardTheCurve) {
  // The channel bends toward +x 5 mm past the tip; pushing the catheter in makes the wall bend it.
  CatheterVesselContact contact(arc_channel(45.0, 20.0, 2.0), shape(), {});
  const auto f = contact.evaluate(Eigen::Vector4d(20.0, 0.0, 0.0, 0.0));
  ASSERT_GT(f.points_in_contact, 0);
  EXPECT_GT(f.total_force, 0.0);
  EXPECT_LE(f.max_force, f.total_force);
  // Positive carriage travel bends the proximal segment toward +x: the wall asks for more of it, and
  // resists further insertion.
  EXPECT_GT(f.generalised[2], 0.0);
  EXPECT_LT(f.generalised[0], 0.0);
  // A little bend with the channel lowers the wall energy (the force is its slope).
  EXPECT_LT(contact.energy(Eigen::Vector4d(20.0, 0.0, 0.3, 0.0)),
            contact.energy(Eigen::Vector4d(20.0, 0.0, 0.0, 0.0)));
}

// The pruned nearest-segment search must be exact: compared with every segment, for points around
// a hairpin (the vessel folds back, so a remote part of the centerline is often the nearest).
TEST(CatheterVesselContact, PrunedDistanceEqualsTheDistanceToEverySegment) {
  const auto hairpin = arc_channel(30.0, 4.0, std::numbers::pi * 1.5, 0.5);
  CatheterVesselContact contact(hairpin, shape(), {});
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> x(-6.0, 14.0), y(-3.0, 3.0), z(-5.0, 40.0);
  for (int trial = 0; trial < 2000; ++trial) {
    const Eigen::Vector3d p(x(rng), y(rng), z(rng));
    double brute = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i + 1 < hairpin.size(); ++i) {
      const Eigen::Vector3d ab = hairpin[i + 1] - hairpin[i];
      const double u = std::clamp((p - hairpin[i]).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
      brute = std::min(brute, (hairpin[i] + u * ab - p).norm());
    }
    ASSERT_NEAR(contact.distance_to_centerline(p), brute, 1e-12) << p.transpose();
  }
}

// The generalised forces are the slope of the wall energy: −∂E/∂q by central differences of energy()
// on every joint, at poses pressed into the curved wall.
TEST(CatheterVesselContact, GeneralisedForcesAreMinusTheEnergyGradient) {
  CatheterVesselContact contact(arc_channel(45.0, 20.0, 2.0), shape(), {});
  for (const Eigen::Vector4d& q :
       {Eigen::Vector4d(20.0, 0.0, 0.0, 0.0), Eigen::Vector4d(24.0, 0.4, -1.0, 2.0),
        Eigen::Vector4d(27.0, -0.3, 3.0, -2.0)}) {
    const auto f = contact.evaluate(q);
    ASSERT_GT(f.points_in_contact, 0) << q.transpose();
    for (int j = 0; j < 4; ++j) {
      constexpr double h = 1e-5;
      Eigen::Vector4d plus = q, minus = q;
      plus[j] += h;
      minus[j] -= h;
      const double slope = -(contact.energy(plus) - contact.energy(minus)) / (2.0 * h);
      EXPECT_NEAR(f.generalised[static_cast<std::size_t>(j)], slope, 1e-6 + 1e-4 * std::abs(slope))
          << "joint " << j << " at " << q.transpose();
    }
  }
}

// Issue 31: the passive shaft along the vessel. An arc channel whose straight lead-in starts at the entry
// (0, 0, L1 + L2): before the entry the base is (0, 0, q1) on the axis, as without a shaft; with the base
// in the bend it sits on the arc, its axis the arc's tangent, and a catheter bent like the arc touches
// nothing where the straight one of before presses on the wall.
TEST(VesselShaft, TheSteerableBaseFollowsTheCenterlineAndItsTangent) {
  const double L = 40.8, lead = 10.0, radius = 60.0;
  auto channel = arc_channel(lead, radius, 1.2, 0.2);
  for (auto& p : channel) p.z() += L;
  teleop::CenterlinePolyline polyline{channel, {}};
  const teleop::VesselShaft shaft(polyline, L);
  Eigen::Matrix3d r;
  Eigen::Vector3d p;
  shaft.section_base(25.0, r, p);  // before the entry: the introducer
  EXPECT_NEAR((p - Eigen::Vector3d(0.0, 0.0, 25.0)).norm(), 0.0, 1e-6);
  EXPECT_NEAR((r - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-6);
  const double s = 40.0;  // 30 mm into the arc
  shaft.section_base(L + lead + s, r, p);
  const double a = s / radius;
  EXPECT_NEAR(
      (p - Eigen::Vector3d(radius * (1.0 - std::cos(a)), 0.0, L + lead + radius * std::sin(a))).norm(), 0.0,
      0.05);
  EXPECT_NEAR((r.col(2) - Eigen::Vector3d(std::sin(a), 0.0, std::cos(a))).norm(), 0.0, 0.01);
  EXPECT_NEAR(r.col(1).y(), 1.0, 1e-3);  // parallel transport in the bend's plane keeps ŷ

  // In the channel (with the introducer before it), straight bends: with the shaft the section starts
  // along the arc, without it the straight catheter leaves the arc and presses on the wall.
  std::vector<Eigen::Vector3d> tube;
  for (double z = -1.0; z < L; z += 0.5) tube.emplace_back(0.0, 0.0, z);
  tube.insert(tube.end(), channel.begin(), channel.end());
  CatheterVesselContactParameters cp;
  cp.lumen_radius = 2.5;
  CatheterVesselContact straight(tube, shape(), cp);
  CatheterVesselContact on_shaft(tube, shape(), cp);
  on_shaft.set_shaft(shaft);
  const Eigen::Vector4d q(L + lead + s, 0.0, 0.0, 0.0);
  EXPECT_GT(straight.evaluate(q).points_in_contact, 0);
  const auto f = on_shaft.evaluate(q);
  // A straight 40.8 mm section on a 60 mm arc: its tip is 40.8²/(2·60) ≈ 13.9 mm off — still touching,
  // but far less than the straight shaft's whole 80 mm lever.
  EXPECT_LT(f.max_force, straight.evaluate(q).max_force);

  // And the generalised forces are still −∂E/∂q, insertion and roll now along the shaft.
  for (const Eigen::Vector4d& qq :
       {Eigen::Vector4d(L + lead + s, 0.3, 1.0, -1.0), Eigen::Vector4d(L + 20.0, -0.2, 2.0, 1.0)}) {
    const auto g = on_shaft.evaluate(qq);
    ASSERT_GT(g.points_in_contact, 0) << qq.transpose();
    for (int j = 0; j < 4; ++j) {
      constexpr double h = 1e-5;
      Eigen::Vector4d plus = qq, minus = qq;
      plus[j] += h;
      minus[j] -= h;
      const double slope = -(on_shaft.energy(plus) - on_shaft.energy(minus)) / (2.0 * h);
      EXPECT_NEAR(g.generalised[static_cast<std::size_t>(j)], slope, 1e-5 + 1e-3 * std::abs(slope))
          << "joint " << j << " at " << qq.transpose();
    }
  }
}

TEST(CatheterVesselContact, RejectsAVesselItCannotModel) {
  EXPECT_THROW(CatheterVesselContact({Eigen::Vector3d::Zero()}, shape(), {}), std::invalid_argument);
  CatheterVesselContactParameters narrow;
  narrow.lumen_radius = 0.5;  // narrower than the 0.6 mm catheter
  EXPECT_THROW(CatheterVesselContact(arc_channel(10.0, 5.0, 1.0), shape(), narrow), std::invalid_argument);
  EXPECT_THROW(arc_channel(10.0, -1.0, 1.0), std::invalid_argument);
}

TEST(CatheterVesselContact, TipBendIsTheSumOfInPlaneSegmentBends) {
  auto planar = shape();
  planar.plane_offset = 0.0;
  const teleop::ModalCatheterKinematics k(planar);
  // 5 mm on each drive: 0.441 + 1.19 rad in one plane.
  EXPECT_NEAR(tip_bend(k, Eigen::Vector4d(10.0, 0.0, 5.0, 5.0)), 0.063 * 1.4 * 5 + 0.17 * 1.4 * 5, 1e-6);
}

struct PlantRig {
  can::VirtualBus bus{"srmc"};
  std::unique_ptr<can::VirtualBusEndpoint> master = bus.attach("master");
  std::unique_ptr<can::VirtualBusEndpoint> adc = bus.attach("adc");
  Simulation sim{bus};
  SimulatedAnalogInputNode node{*adc, [] {
                                  AnalogInputNodeParameters p;
                                  p.node_id = 0x31;
                                  p.noise_volts = 0.0;
                                  return p;
                                }()};
  PlantRig() {
    sim.add_drive(1, DriveParameters::srmc_insertion("insertion"));
    sim.add_drive(2, DriveParameters::srmc_roll("roll"));
    sim.add_drive(3, DriveParameters::srmc_bend("proximal_bend"));
    sim.add_drive(4, DriveParameters::srmc_bend("distal_bend"));
  }
};

TEST(SrmcPlantCoupling, ProximalBendShiftsTheDistalActuationByR1CosDelta2) {
  PlantRig rig;
  SrmcPlantParameters p;
  p.shape = shape();
  p.coupling_mm_per_rad = 0.6 * std::cos(-0.76);
  SrmcPlant plant(rig.sim, {0, 1, 2, 3}, p);
  plant.set_external_force(0, 0.4);  // pushes the proximal carriage up by 2 mm against the 0.2 N/mm spring
  for (int i = 0; i < 3000; ++i) plant.step(0.001);
  const auto s = plant.state();
  EXPECT_NEAR(s.carriage[0], 2.0, 0.05);
  EXPECT_NEAR(s.deflection[0], -2.0, 0.05);
  EXPECT_NEAR(s.bend[0], 0.063 * 1.4 * s.carriage[0], 1e-9);
  EXPECT_NEAR(s.distal_actuation, s.carriage[1] + p.coupling_mm_per_rad * s.bend[0], 1e-12);
  EXPECT_GT(s.bend[1], 0.0);  // the distal tube bends though its drive has not moved
}

TEST(SrmcPlantPotentiometers, DeflectionReachesTheBusAsVoltsAroundTheCentre) {
  PlantRig rig;
  SrmcPlantParameters p;
  p.potentiometer_volts_per_mm = 0.5;
  SrmcPlant plant(rig.sim, {0, 1, 2, 3}, p);
  plant.set_potentiometer_node(&rig.node);
  plant.set_external_force(1, -0.2);  // distal carriage pushed down 1 mm: deflection +1 mm
  canopen::AnalogInputReceiver rx({0x31, 5.0, 0.25, 100'000'000});
  std::int64_t now = 0;
  for (int i = 0; i < 3000; ++i) {
    plant.step(0.001);
    rig.node.step(0.001);
    now += 1'000'000;
    while (auto f = rig.master->receive(std::chrono::nanoseconds(0))) rx.handle(*f, now);
  }
  const auto r = rx.reading(now);
  ASSERT_TRUE(r.fresh);
  EXPECT_NEAR((r.volts[1] - 2.5) / 0.5, plant.state().deflection[1], 0.01);
  EXPECT_NEAR(plant.state().deflection[1], 1.0, 0.05);
  EXPECT_NEAR(r.volts[0], 2.5, 0.01);
}

}  // namespace
}  // namespace tendril::sim
