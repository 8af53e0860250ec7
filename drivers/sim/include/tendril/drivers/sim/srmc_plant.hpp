// SrmcPlant: SIMULATED mechanics of the steerable robotic microcatheter's actuation unit (seed 000
// §4.3). Four simulated drives give the joint vector q = (insertion mm, roll rad, proximal bend
// drive mm, distal bend drive mm). Each bend drive's active carriage pushes a floating carriage
// through a spring of stiffness k; the spring deflection (drive - carriage, mm) is what the linear
// potentiometers read, and the spring force loads the drive's lead screw.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <random>

#include "tendril/drivers/sim/simulation.hpp"

namespace tendril::sim {

struct SrmcPlantParameters {
  // Spring and floating carriage (the seed gives no values: assumptions, see README of drivers/sim).
  double spring_stiffness = 0.2;     // N/mm
  double carriage_mass = 0.02;       // kg
  double carriage_damping = 0.0;     // N s/mm; <= 0 picks critical damping from k and m
  double carriage_friction = 0.0;    // N, Coulomb friction on the passive rail (Igus: near zero)
  double tube_stiffness = 0.0;       // N/mm, elastic return force of the bent tube on the carriage
  double potentiometer_noise = 0.0;  // mm, Gaussian sigma on the deflection reading
  double max_physics_dt = 0.0005;    // s
  std::uint64_t noise_seed = 7;
};

struct SrmcPlantState {
  std::array<double, 4> q{};             // drive (encoder-side) joint positions
  std::array<double, 4> qd{};            // joint velocities
  std::array<double, 2> carriage{};      // floating carriage positions, mm (what bends the tubes)
  std::array<double, 2> deflection{};    // spring deflection q_s1, q_s2, mm (potentiometers)
  std::array<double, 2> spring_force{};  // N, k * deflection
};

class SrmcPlant final : public Plant {
 public:
  static constexpr std::size_t kInsertion = 0, kRoll = 1, kProximalBend = 2, kDistalBend = 3;

  // drive_index[j]: which drive of `sim` moves joint j. The plant does not register itself; call
  // sim.add_plant(plant). Throws SimulationSetupError on a bad index or parameter.
  SrmcPlant(Simulation& sim, std::array<std::size_t, 4> drive_index, SrmcPlantParameters params = {});

  void step(double dt) noexcept override;

  // External axial force on a floating carriage (N, + pushes toward larger q), e.g. a vessel wall
  // acting on the tip. Any thread.
  void set_external_force(std::size_t bend_channel, double newtons) noexcept;
  // Latest state; any thread.
  SrmcPlantState state() const noexcept { return state_.load(); }

 private:
  Simulation& sim_;
  std::array<std::size_t, 4> drive_index_;
  SrmcPlantParameters params_;
  std::array<double, 2> carriage_pos_{};
  std::array<double, 2> carriage_vel_{};  // mm/s
  std::array<std::atomic<double>, 2> external_force_{};
  bool initialised_ = false;
  std::mt19937_64 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};
  teleop::LatestValue<SrmcPlantState> state_;
};

}  // namespace tendril::sim
