#include "tendril/drivers/sim/srmc_plant.hpp"

#include "tendril/drivers/sim/catheter_vessel_contact.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

namespace tendril::sim {

SrmcPlant::SrmcPlant(Simulation& sim, std::array<std::size_t, 4> drive_index, SrmcPlantParameters params)
    : params_(std::move(params)), rng_(params_.noise_seed) {
  for (std::size_t j = 0; j < 4; ++j) {
    if (drive_index[j] >= sim.drive_count()) {
      throw SimulationSetupError("SRMC plant: joint " + std::to_string(j) + " refers to drive " +
                                 std::to_string(drive_index[j]) + " but the simulation has " +
                                 std::to_string(sim.drive_count()) + " drives");
    }
    drives_[j] = &sim.drive(drive_index[j]);
  }
  validate();
}

SrmcPlant::SrmcPlant(std::array<SimulatedCia402Drive*, 4> drives, SrmcPlantParameters params)
    : drives_(drives), params_(std::move(params)), rng_(params_.noise_seed) {
  for (std::size_t j = 0; j < 4; ++j)
    if (!drives_[j]) throw SimulationSetupError("SRMC plant: joint " + std::to_string(j) + " has no drive");
  validate();
}

void SrmcPlant::validate() {
  if (!(params_.spring_stiffness > 0))
    throw SimulationSetupError("SRMC plant: spring_stiffness must be positive");
  if (!(params_.carriage_mass > 0)) throw SimulationSetupError("SRMC plant: carriage_mass must be positive");
  if (!(params_.max_physics_dt > 0))
    throw SimulationSetupError("SRMC plant: max_physics_dt must be positive");
  if (params_.carriage_friction < 0 || params_.tube_stiffness < 0 || params_.potentiometer_noise < 0)
    throw SimulationSetupError("SRMC plant: friction, tube stiffness and noise must not be negative");
  if (!std::isfinite(params_.coupling_mm_per_rad) || !(params_.potentiometer_volts_per_mm > 0))
    throw SimulationSetupError("SRMC plant: coupling must be finite and volts_per_mm positive");
  if (params_.carriage_damping <= 0) {
    // Critical damping in SI: c = 2 sqrt(k m), k in N/m -> back to N s/mm.
    params_.carriage_damping = 2.0 * std::sqrt(params_.spring_stiffness * 1e3 * params_.carriage_mass) * 1e-3;
  }
  if (params_.shape) {
    try {
      shape_.emplace(*params_.shape);
    } catch (const std::invalid_argument& e) {
      throw SimulationSetupError(std::string("SRMC plant: shape: ") + e.what());
    }
  }
  for (auto& f : external_force_) f.store(0.0);
  step(0.0);
}

void SrmcPlant::set_vessel(CatheterVesselContact* vessel) {
  if (vessel && !shape_)
    throw SimulationSetupError("SRMC plant: a vessel needs the catheter's shape (params.shape)");
  vessel_ = vessel;
}

void SrmcPlant::set_external_force(std::size_t bend_channel, double newtons) noexcept {
  if (bend_channel < 2 && std::isfinite(newtons)) external_force_[bend_channel].store(newtons);
}

void SrmcPlant::step(double dt) noexcept {
  SrmcPlantState out;
  for (std::size_t j = 0; j < 4; ++j) {
    const auto t = drives_[j]->truth();
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
    const double external = external_force_[c].load(std::memory_order_relaxed) + wall_force_[c];
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
    drives_[kProximalBend + c]->set_external_load(-out.spring_force[c]);
  }

  // What reaches the tubes: the proximal carriage, and the distal carriage shifted by the coupling.
  out.distal_actuation = out.carriage[1];
  if (shape_) {
    out.bend[0] =
        std::numbers::pi / 2.0 - shape_->tip_angle(teleop::CatheterSegment::kProximal, out.carriage[0]);
    out.distal_actuation += params_.coupling_mm_per_rad * out.bend[0];
    out.bend[1] =
        std::numbers::pi / 2.0 - shape_->tip_angle(teleop::CatheterSegment::kDistal, out.distal_actuation);
    out.tip_bend =
        sim::tip_bend(*shape_, Eigen::Vector4d(out.q[0], out.q[1], out.carriage[0], out.distal_actuation));
  }
  if (vessel_ && dt > 0) {
    // The wall forces of this pose act on the carriages over the next step (the wall is far slower
    // than a 1 ms step). The distal generalised force reaches carriage 2 directly (∂q4_eff/∂c2 = 1).
    const auto f =
        vessel_->evaluate(Eigen::Vector4d(out.q[0], out.q[1], out.carriage[0], out.distal_actuation));
    wall_force_ = {f.generalised[2], f.generalised[3]};
    drives_[kInsertion]->set_external_load(f.generalised[0]);
    // The contact force reported is the largest local wall load (one backbone point's spring),
    // the quantity that injures a vessel; the sum over points depends on how finely they are spaced.
    out.contact_force = f.max_force;
    out.total_contact_force = f.total_force;
    out.points_in_contact = f.points_in_contact;
    max_contact_force_ = std::max(max_contact_force_, f.max_force);
  }
  out.max_contact_force = max_contact_force_;
  if (potentiometers_) {
    const double centre = 0.5 * potentiometers_->parameters().supply_volts;
    potentiometers_->set_input_volts({centre + out.deflection[0] * params_.potentiometer_volts_per_mm,
                                      centre + out.deflection[1] * params_.potentiometer_volts_per_mm,
                                      centre});
  }
  state_.store(out);
}

}  // namespace tendril::sim
