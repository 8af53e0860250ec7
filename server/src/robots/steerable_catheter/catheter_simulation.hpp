// The SIMULATED parts of a steerable catheter on a virtual bus (catheter_simulation.cpp): the
// series-elastic plant in its vessel and the simulated ADC nodes.
#pragma once

#include <atomic>
#include <memory>
#include <optional>

#include "steerable_catheter/catheter_robot.hpp"
#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"

namespace tendril::server {

// SIMULATED insertion of the true catheter (catheter.simulation.true_catheter): the arc length that
// reaches the vessel follows the insertion drive through a dead band (slack) and, pushing, sticks in
// the introducer until stick_mm of drive travel is stored in the buckled shaft, then slips forward by
// slip_fraction of it. Pulling back drags the catheter at once. Stepped after the plant at 1 kHz.
class TrueInsertion final : public sim::Plant {
 public:
  TrueInsertion(const sim::SrmcPlant& plant, const TrueCatheterSettings& truth)
      : plant_(plant), truth_(truth) {}
  void step(double dt) noexcept override;
  double inserted_mm() const noexcept { return inserted_.load(std::memory_order_relaxed); }  // any thread
  bool started() const noexcept { return started_.load(std::memory_order_acquire); }

 private:
  const sim::SrmcPlant& plant_;
  TrueCatheterSettings truth_;
  double s_ = 0.0;
  std::atomic<bool> started_{false};
  std::atomic<double> inserted_{0.0};
};

struct CatheterSimulation {
  std::unique_ptr<can::Bus> sensor_endpoint, joystick_endpoint;
  std::unique_ptr<sim::SimulatedAnalogInputNode> sensor_node;
  std::unique_ptr<sim::SimulatedAnalogJoystick> joystick_node;
  std::unique_ptr<sim::CatheterVesselContact> contact;
  std::unique_ptr<sim::SrmcPlant> plant;
  // With a true_catheter: its insertion and its shape (read-only after set-up).
  std::unique_ptr<TrueInsertion> insertion;
  std::optional<teleop::ModalCatheterKinematics> true_kinematics;
  // The plant's shape (the true catheter's with one), for simulated_backbone().
  std::optional<teleop::ModalCatheterKinematics> plant_kinematics;
};

}  // namespace tendril::server
