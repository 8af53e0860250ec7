#include "tendril/drivers/sim/srmc_plant.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace tendril::sim {

SrmcPlant::SrmcPlant(Simulation& sim, std::array<std::size_t, 4> drive_index, SrmcPlantParameters params)
    : sim_(sim), drive_index_(drive_index), params_(params), rng_(params.noise_seed) {
  for (std::size_t j = 0; j < 4; ++j) {
    if (drive_index_[j] >= sim_.drive_count()) {
      throw SimulationSetupError("SRMC plant: joint " + std::to_string(j) + " refers to drive " +
                                 std::to_string(drive_index_[j]) + " but the simulation has " +
                                 std::to_string(sim_.drive_count()) + " drives");
    }
  }
  if (!(params_.spring_stiffness > 0))
    throw SimulationSetupError("SRMC plant: spring_stiffness must be positive");
  if (!(params_.carriage_mass > 0)) throw SimulationSetupError("SRMC plant: carriage_mass must be positive");
  if (!(params_.max_physics_dt > 0))
    throw SimulationSetupError("SRMC plant: max_physics_dt must be positive");
  if (params_.carriage_friction < 0 || params_.tube_stiffness < 0 || params_.potentiometer_noise < 0)
    throw SimulationSetupError("SRMC plant: friction, tube stiffness and noise must not be negative");
  if (params_.carriage_damping <= 0) {
    // Critical damping in SI: c = 2 sqrt(k m), k in N/m -> back to N s/mm.
    params_.carriage_damping = 2.0 * std::sqrt(params_.spring_stiffness * 1e3 * params_.carriage_mass) * 1e-3;
  }
  for (auto& f : external_force_) f.store(0.0);
  step(0.0);
}

void SrmcPlant::set_external_force(std::size_t bend_channel, double newtons) noexcept {
  if (bend_channel < 2 && std::isfinite(newtons)) external_force_[bend_channel].store(newtons);
}

void SrmcPlant::step(double dt) noexcept {
  SrmcPlantState out;
  for (std::size_t j = 0; j < 4; ++j) {
    const auto t = sim_.drive(drive_index_[j]).truth();
    out.q[j] = t.position;
    out.qd[j] = t.velocity;
  }
  if (!initialised_) {
    // Start at rest with relaxed springs.
    carriage_pos_ = {out.q[kProximalBend], out.q[kDistalBend]};
    initialised_ = true;
  }
  const int substeps = dt > 0 ? std::max(1, static_cast<int>(std::ceil(dt / params_.max_physics_dt))) : 0;
  const double h = substeps ? dt / substeps : 0.0;
  const double mm_per_s2_per_newton = 1e3 / params_.carriage_mass;  // a = F / m, in mm/s^2
  for (std::size_t c = 0; c < 2; ++c) {
    const double drive_pos = out.q[kProximalBend + c];
    const double external = external_force_[c].load(std::memory_order_relaxed);
    for (int i = 0; i < substeps; ++i) {
      const double spring = params_.spring_stiffness * (drive_pos - carriage_pos_[c]);
      double force = spring + external - params_.tube_stiffness * carriage_pos_[c] -
                     params_.carriage_damping * carriage_vel_[c];
      const double fc = params_.carriage_friction;
      if (carriage_vel_[c] == 0.0 && std::abs(force) <= fc) continue;  // static friction holds it
      force -= std::copysign(fc, carriage_vel_[c] != 0.0 ? carriage_vel_[c] : force);
      double v = carriage_vel_[c] + force * mm_per_s2_per_newton * h;
      if (carriage_vel_[c] != 0.0 && (v > 0) != (carriage_vel_[c] > 0) && fc > 0) v = 0.0;
      carriage_vel_[c] = v;
      carriage_pos_[c] += v * h;
    }
    const double deflection = drive_pos - carriage_pos_[c];
    out.carriage[c] = carriage_pos_[c];
    out.spring_force[c] = params_.spring_stiffness * deflection;
    out.deflection[c] =
        deflection + (params_.potentiometer_noise > 0 ? params_.potentiometer_noise * noise_(rng_) : 0.0);
    // The compressed spring pushes the active carriage back: load on the lead screw.
    sim_.drive(drive_index_[kProximalBend + c]).set_external_load(-out.spring_force[c]);
  }
  state_.store(out);
}

}  // namespace tendril::sim
