// The SIMULATED parts of a steerable catheter on a virtual bus (catheter_simulation.cpp): the
// series-elastic plant in its vessel and the simulated ADC nodes.
#pragma once

#include <memory>

#include "steerable_catheter/catheter_robot.hpp"
#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"
#include "tendril/drivers/sim/simulated_analog_joystick.hpp"
#include "tendril/drivers/sim/srmc_plant.hpp"

namespace tendril::server {

struct CatheterSimulation {
  std::unique_ptr<can::Bus> sensor_endpoint, joystick_endpoint;
  std::unique_ptr<sim::SimulatedAnalogInputNode> sensor_node;
  std::unique_ptr<sim::SimulatedAnalogJoystick> joystick_node;
  std::unique_ptr<sim::CatheterVesselContact> contact;
  std::unique_ptr<sim::SrmcPlant> plant;
};

}  // namespace tendril::server
