// Simulation host and SrmcPlant, stepped in simulated time (one real-time smoke test that does not
// depend on how fast the machine is).
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>
#include <thread>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"

namespace tendril::sim {
namespace {

namespace co = canopen;

struct SrmcRig {
  can::VirtualBus bus{"srmc"};
  std::unique_ptr<can::VirtualBusEndpoint> master = bus.attach("master");
  Simulation sim{bus};
  SrmcRig() {
    sim.add_drive(1, DriveParameters::srmc_insertion("insertion"));
    sim.add_drive(2, DriveParameters::srmc_roll("roll"));
    sim.add_drive(3, DriveParameters::srmc_bend("proximal_bend"));
    sim.add_drive(4, DriveParameters::srmc_bend("distal_bend"));
  }
  std::vector<can::Frame> drain() {
    std::vector<can::Frame> out;
    while (auto f = master->receive(std::chrono::nanoseconds::zero())) out.push_back(*f);
    return out;
  }
  void send(const can::Frame& f) { ASSERT_EQ(master->send(f), can::SendResult::ok); }
  // Enables drive `node` in CSP by RPDO1 and moves it to `target_units` over `seconds` (cosine).
  void move(std::uint8_t node, double target_units, double seconds) {
    auto& d = sim.drive(node - 1);
    const double cpu = d.parameters().counts_per_unit();
    const double start = d.position_counts();
    const int cycles = static_cast<int>(seconds * 1000);
    for (int i = 0; i <= cycles + 300; ++i) {
      const double s = i >= cycles ? 1.0 : 0.5 - 0.5 * std::cos(std::numbers::pi * i / cycles);
      const std::uint16_t cw = i == 0 ? 0x0006 : i == 1 ? 0x0007 : 0x000F;
      can::Frame f;
      f.id = co::cob::rpdo1 + node;
      f.len = 6;
      co::put_u16(&f.data[0], cw);
      co::put_u32(&f.data[2],
                  static_cast<std::uint32_t>(std::lround(start + s * (target_units * cpu - start))));
      send(f);
      send(can::Frame::make(co::cob::sync, {}));
      sim.step(0.001);
    }
  }
};

TEST(Simulation, EveryDriveBootsOnTheSharedBus) {
  SrmcRig rig;
  EXPECT_THROW(rig.sim.add_drive(3, DriveParameters::srmc_bend("again")), SimulationSetupError);
  rig.sim.step(0.001);
  std::set<std::uint32_t> booted;
  for (const auto& f : rig.drain()) {
    if (f.id > co::cob::heartbeat && f.len == 1 && f.data[0] == 0) booted.insert(f.id - co::cob::heartbeat);
  }
  EXPECT_EQ(booted, (std::set<std::uint32_t>{1, 2, 3, 4}));
  // NMT start to all nodes, one SYNC: four TPDO1 answers.
  rig.send(can::Frame::make(co::cob::nmt, {0x01, 0x00}));
  rig.send(can::Frame::make(co::cob::sync, {}));
  rig.sim.step(0.001);
  int tpdo1 = 0;
  for (const auto& f : rig.drain()) tpdo1 += (f.id > co::cob::tpdo1 && f.id <= co::cob::tpdo1 + 4) ? 1 : 0;
  EXPECT_EQ(tpdo1, 4);
}

TEST(Simulation, RequestsFromOtherThreadsActAtTheNextCycle) {
  SrmcRig rig;
  rig.sim.step(0.001);
  rig.sim.request_fault(1, co::emcy_code::over_current);
  rig.sim.step(0.001);
  EXPECT_EQ(rig.sim.truth(1).state, co::Cia402State::fault);
  rig.sim.request_power_cycle(1);
  rig.sim.step(0.001);
  EXPECT_EQ(rig.sim.truth(1).state, co::Cia402State::switch_on_disabled);
}

TEST(SrmcPlant, MapsDrivePositionsToTheJointVector) {
  SrmcRig rig;
  SrmcPlant plant(rig.sim, {0, 1, 2, 3});
  rig.sim.add_plant(plant);
  rig.sim.step(0.001);
  rig.send(can::Frame::make(co::cob::nmt, {0x01, 0x00}));
  rig.sim.step(0.001);
  rig.move(1, 12.0, 0.5);
  rig.move(2, 0.7, 0.5);
  rig.move(3, 1.5, 0.5);
  rig.move(4, -0.8, 0.5);
  rig.sim.step(0.3);
  const auto s = plant.state();
  EXPECT_NEAR(s.q[SrmcPlant::kInsertion], 12.0, 0.01);
  EXPECT_NEAR(s.q[SrmcPlant::kRoll], 0.7, 0.001);
  EXPECT_NEAR(s.q[SrmcPlant::kProximalBend], 1.5, 0.01);
  EXPECT_NEAR(s.q[SrmcPlant::kDistalBend], -0.8, 0.01);
  // No external load: the floating carriages follow, springs relaxed.
  EXPECT_NEAR(s.deflection[0], 0.0, 0.01);
  EXPECT_NEAR(s.deflection[1], 0.0, 0.01);
  EXPECT_NEAR(s.carriage[0], 1.5, 0.01);
}

TEST(SrmcPlant, ExternalForceDeflectsTheSpringByForceOverStiffness) {
  SrmcRig rig;
  SrmcPlantParameters p;
  p.spring_stiffness = 0.2;  // N/mm
  SrmcPlant plant(rig.sim, {0, 1, 2, 3}, p);
  rig.sim.add_plant(plant);
  rig.sim.step(0.001);
  rig.send(can::Frame::make(co::cob::nmt, {0x01, 0x00}));
  rig.move(3, 2.0, 0.2);              // enabled and holding 2 mm
  plant.set_external_force(0, -0.1);  // the tip meets a wall: 0.1 N pushing back
  for (int i = 0; i < 1000; ++i) {
    can::Frame f;
    f.id = co::cob::rpdo1 + 3;
    f.len = 6;
    co::put_u16(&f.data[0], 0x000F);
    co::put_u32(&f.data[2], static_cast<std::uint32_t>(
                                std::lround(2.0 * rig.sim.drive(2).parameters().counts_per_unit())));
    rig.send(f);
    rig.send(can::Frame::make(co::cob::sync, {}));
    rig.sim.step(0.001);
  }
  const auto s = plant.state();
  EXPECT_NEAR(s.q[SrmcPlant::kProximalBend], 2.0, 0.01) << "the servo holds the drive against the spring";
  EXPECT_NEAR(s.deflection[0], 0.5, 0.02) << "0.1 N / 0.2 N/mm";
  EXPECT_NEAR(s.carriage[0], 1.5, 0.02);
  EXPECT_NEAR(s.deflection[1], 0.0, 0.001);
  EXPECT_GT(std::abs(rig.sim.truth(2).motor_torque), 0.0) << "the spring loads the lead screw";
}

TEST(Simulation, RealTimeThreadRunsTheDrivesAndStops) {
  SrmcRig rig;
  rig.sim.start_realtime(std::chrono::milliseconds(1));
  EXPECT_THROW(rig.sim.start_realtime(std::chrono::milliseconds(1)), SimulationSetupError);
  EXPECT_THROW(rig.sim.add_drive(9, DriveParameters::srmc_bend("late")), SimulationSetupError);
  // Wait (bounded) for the boot-up messages; no assertion on speed.
  int booted = 0;
  for (int i = 0; i < 5000 && booted < 4; ++i) {
    if (auto f = rig.master->receive(std::chrono::milliseconds(1)))
      booted += f->id > co::cob::heartbeat ? 1 : 0;
  }
  rig.sim.stop();
  EXPECT_FALSE(rig.sim.running());
  EXPECT_EQ(booted, 4);
  const auto stats = rig.sim.realtime_statistics();
  EXPECT_GT(stats.cycles, 0u);
  EXPECT_GE(stats.max_lateness_ns, stats.last_lateness_ns);
}

}  // namespace
}  // namespace tendril::sim
