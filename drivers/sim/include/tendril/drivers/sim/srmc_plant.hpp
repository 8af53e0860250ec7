// SrmcPlant: SIMULATED mechanics of the steerable robotic microcatheter's actuation unit (Abah 2022,
// §4.4.1). Four simulated drives give the joint vector q = (insertion mm, roll rad, proximal bend
// drive mm, distal bend drive mm). Each bend drive's active carriage pushes a floating carriage
// through a spring of stiffness k; the spring deflection (drive - carriage, mm) is what the linear
// potentiometers read, and the spring force loads the drive's lead screw.
//
// Optional parts: the distal coupling of eq. 4.15 (the distal tube sees q4_eff = carriage_2 + c·θ_L1,
// with θ_L1 from the shape model), a vessel (CatheterVesselContact) whose wall forces act on the
// carriages and the insertion drive, and a SimulatedAnalogInputNode that carries the potentiometer
// voltages (2.5 V + deflection·volts_per_mm on channels 0 and 1) onto the CAN bus.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <optional>
#include <random>

#include <Eigen/Core>

#include "tendril/drivers/sim/simulation.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"

namespace tendril::sim {

struct SrmcPlantParameters {
  // Spring and floating carriage (the dissertation gives no values: assumptions, see README of drivers/sim).
  double spring_stiffness = 0.2;     // N/mm
  double carriage_mass = 0.02;       // kg
  double carriage_damping = 0.0;     // N s/mm; <= 0 picks critical damping from k and m
  double carriage_friction = 0.0;    // N, Coulomb friction on the passive rail (Igus: near zero)
  double tube_stiffness = 0.0;       // N/mm, elastic return force of the bent tube on the carriage
  double potentiometer_noise = 0.0;  // mm, Gaussian sigma on the deflection reading
  double max_physics_dt = 0.0005;    // s
  std::uint64_t noise_seed = 7;
  // Assembled catheter shape (bend per mm of carriage travel); needed for coupling, vessel contact
  // and the reported bend angles. Without it those stay zero.
  std::optional<teleop::ModalCatheterParameters> shape;
  double coupling_mm_per_rad = 0.0;         // c = r1·cos δ2 (eq. 4.15); 0 = no coupling
  double potentiometer_volts_per_mm = 0.5;  // when a potentiometer node is attached
};

struct SrmcPlantState {
  std::array<double, 4> q{};             // drive (encoder-side) joint positions
  std::array<double, 4> qd{};            // joint velocities
  std::array<double, 2> carriage{};      // floating carriage positions, mm (what bends the tubes)
  std::array<double, 2> deflection{};    // spring deflection q_s1, q_s2, mm (potentiometers)
  std::array<double, 2> spring_force{};  // N, k * deflection
  double distal_actuation = 0.0;         // q4_eff = carriage_2 + c·θ_L1 (mm)
  std::array<double, 2> bend{};          // assembled tip bend of each segment (rad)
  double tip_bend = 0.0;                 // tip tangent against the insertion axis (rad)
  double contact_force = 0.0;            // largest local wall force now (N, one backbone point)
  double total_contact_force = 0.0;      // sum over the points in contact (N)
  double max_contact_force = 0.0;        // largest local wall force since start (N)
  int points_in_contact = 0;
};

class CatheterVesselContact;
class SimulatedAnalogInputNode;

class SrmcPlant final : public Plant {
 public:
  static constexpr std::size_t kInsertion = 0, kRoll = 1, kProximalBend = 2, kDistalBend = 3;

  // drive_index[j]: which drive of `sim` moves joint j. The plant does not register itself; call
  // sim.add_plant(plant). Throws SimulationSetupError on a bad index or parameter.
  SrmcPlant(Simulation& sim, std::array<std::size_t, 4> drive_index, SrmcPlantParameters params = {});
  // The drives of joints insertion, roll, proximal, distal directly (stepped by their owner before
  // the plant). Throws SimulationSetupError on a null drive or a bad parameter.
  SrmcPlant(std::array<SimulatedCia402Drive*, 4> drives, SrmcPlantParameters params = {});

  // Set-up, before stepping: not owned, must outlive the plant. The vessel needs params.shape.
  void set_vessel(CatheterVesselContact* vessel);
  void set_potentiometer_node(SimulatedAnalogInputNode* node) noexcept { potentiometers_ = node; }

  void step(double dt) noexcept override;

  // External axial force on a floating carriage (N, + pushes toward larger q), e.g. a vessel wall
  // acting on the tip. Any thread.
  void set_external_force(std::size_t bend_channel, double newtons) noexcept;
  // Latest state; any thread.
  SrmcPlantState state() const noexcept { return state_.load(); }

 private:
  void validate();

  std::array<SimulatedCia402Drive*, 4> drives_{};
  SrmcPlantParameters params_;
  std::optional<teleop::ModalCatheterKinematics> shape_;
  CatheterVesselContact* vessel_ = nullptr;
  SimulatedAnalogInputNode* potentiometers_ = nullptr;
  std::array<double, 2> wall_force_{};  // on the carriages, from the last contact evaluation
  double max_contact_force_ = 0.0;
  std::array<double, 2> carriage_pos_{};
  std::array<double, 2> carriage_vel_{};  // mm/s
  std::array<std::atomic<double>, 2> external_force_{};
  bool initialised_ = false;
  std::mt19937_64 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};
  hardware::LatestValue<SrmcPlantState> state_;
};

}  // namespace tendril::sim
