// Active compliance (admittance) of the series-elastic bend drives, Abah 2022, §4.7.3, eqs. 4.24–4.26:
//   q_des = q_cur + [0, 0, dq_a1, dq_a2]ᵀ,  dq_ai = K_a·((1 − t_i)·v_min + t_i·v_max)·dt,
//   t_i = q_si / q_si,max  (q_si: spring deflection from the linear potentiometer).
// The dissertation prints no sign: the correction moves the bend drive the way that relaxes its
// spring, i.e. against the deflection (deflection = drive − carriage, so a wall that pushes the
// carriage up gives a negative deflection and the drive follows it up). |t_i| saturates at 1, and a
// deflection inside the deadband gives no motion (otherwise v_min would make the drive creep on
// sensor noise). Insertion and roll are left to the operator.
//
// Chosen values (the dissertation gives none), see teleop/steerable_catheter/README.md:
//   deadband 0.05 mm: the dissertation's trigger force ≈ 0.01 N over the 0.2 N/mm spring;
//   v_min 0.2 mm/s, v_max 2 mm/s (the bend drives' speed limit), K_a = 1;
//   q_s,max 1.0 mm (0.2 N on the tube); the safety bound that holds the robot is larger (1.5 mm).
#pragma once

#include <array>
#include <span>

namespace tendril::teleop {

struct ActiveComplianceParameters {
  double gain = 1.0;            // K_a (dimensionless)
  double min_speed = 0.2;       // v_min, mm/s
  double max_speed = 2.0;       // v_max, mm/s
  double max_deflection = 1.0;  // q_s,max, mm
  double deadband = 0.05;       // mm of deflection that reads as no contact
};

// Throws std::invalid_argument (a message naming the parameter) unless 0 < gain, 0 ≤ v_min ≤ v_max,
// 0 ≤ deadband < max_deflection, everything finite.
void validate(const ActiveComplianceParameters& parameters);

// dq_a (mm) for one bend drive over dt (s) from its spring deflection (mm). Zero for a non-finite
// deflection or dt ≤ 0 (the caller's sensor watchdog decides what a bad reading means).
double active_compliance_increment(const ActiveComplianceParameters& parameters, double deflection,
                                   double dt) noexcept;

// Eq. 4.24 for the four SRMC joints [insertion, roll, proximal drive, distal drive]: writes the bend
// entries of q_des from the measured bend positions plus their increments; insertion and roll of
// q_des are not touched.
void apply_active_compliance(const ActiveComplianceParameters& parameters, std::span<const double> q_measured,
                             const std::array<double, 2>& deflection, double dt,
                             std::span<double> q_des) noexcept;

}  // namespace tendril::teleop
