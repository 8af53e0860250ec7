// The angulated scissor linkage (ASL) that serves as a spacer disk of the variable-diameter
// multi-backbone continuum robot (MBCR, Abah 2022, ch. 2), and the disk-interference limit on its
// outer radius (Abah 2022, §2.3–2.4, eqs. 2.1–2.18).
//
// Radii of one ASL, all measured from the disk centre (Table 2.1):
//   a  inner radius: the innermost vertices (the linkage's actuation radius, the robot's 5th joint)
//   r  configuration radius: the mid-range vertices, where the secondary backbones pass (design choice
//      of the dissertation, §2.3.4, since a and r are proportional for every n)
//   b  outer radius: the outermost vertices, which decide whether neighbouring disks collide
// Parameters: n rhombuses (n > 2), inner and outer arm lengths l₁, l₂, hinge diameter d.
//
// The model is immutable and every query is const, noexcept and allocation-free; the constructor
// throws std::invalid_argument naming the parameter when the linkage cannot exist. Queries outside
// the linkage's validity (2.3) return NaN rather than a wrong number. Lengths in mm, angles in rad.
#pragma once

namespace tendril::teleop {

struct ScissorLinkageParameters {
  int rhombus_count = 8;  // n; 8 keeps four backbones radially symmetric (Abah 2022, §2.3.4, Table 2.3)
  double inner_arm_length = 20.0;  // l₁ (mm), Table 2.3
  double outer_arm_length =
      20.0;  // l₂ (mm); l₂ = l₁ is the dissertation's design rule for a constant elbow angle
  // d (mm). The dissertation gives no value; 2 mm reproduces its "26 % change of the outer diameter" for
  // n = 8, l₁ = 20 mm (25.8 %, Abah 2022, §2.3.4), so it is our default.
  double hinge_diameter = 2.0;
};

class ScissorLinkage {
 public:
  // Throws std::invalid_argument when n ≤ 2, an arm length or d is not positive and finite, or d is so
  // large that the linkage has no admissible range (r_min ≥ r_max).
  explicit ScissorLinkage(const ScissorLinkageParameters& parameters);

  const ScissorLinkageParameters& parameters() const noexcept { return parameters_; }

  // (2.1) a = f_a(r) = r·cos(π/n) − √(l₁² − r²·sin²(π/n)) (elbow-in); NaN when r ≥ l₁/sin(π/n).
  double inner_radius(double r) const noexcept;
  // (2.2) b = f_b(r) = r·cos(π/n) + √(l₂² − r²·sin²(π/n)) (elbow-out); NaN when r ≥ l₂/sin(π/n).
  double outer_radius(double r) const noexcept;
  // (2.8) r(a) = a·cos(π/n) + √(l₁² − a²·sin²(π/n)), the inverse of (2.1).
  double configuration_radius(double a) const noexcept;
  // (2.11) da/dr (> 0 for every admissible r when n > 2) and db/dr.
  double inner_radius_rate(double r) const noexcept;
  double outer_radius_rate(double r) const noexcept;
  // dr/da = 1/(da/dr), the factor of the augmented Jacobian (2.21)–(2.22).
  double configuration_radius_rate(double a) const noexcept;
  // (2.4)–(2.6) elbow angle φ = α + β at r; π − 2π/n whenever l₁ = l₂ and r ≥ l₁.
  double elbow_angle(double r) const noexcept;

  // Extrema (2.9)–(2.14). The folded limit (inner hinges touch) gives r_min, the expanded limit
  // (inner hinges touch the outer ones, b − a = d) gives r_max.
  double configuration_radius_min() const noexcept { return r_min_; }
  double configuration_radius_max() const noexcept { return r_max_; }
  double inner_radius_min() const noexcept { return a_min_; }
  double inner_radius_max() const noexcept { return a_max_; }
  // b_min = f_b(r_max) for 2 < n < 6, else f_b(r_min) (Abah 2022, §2.3.4).
  double outer_radius_min() const noexcept { return b_min_; }
  // (2.12)–(2.13): b peaks at b_max = l₂/sin(π/n) where r = l₂/tan(π/n); when that r lies outside
  // [r_min, r_max] the largest admissible b is at the nearer end, which is what this returns.
  double outer_radius_max() const noexcept { return b_max_; }
  double configuration_radius_at_outer_max() const noexcept { return r_at_b_max_; }
  // The unconstrained peak of (2.13), l₂/sin(π/n), and the r where it occurs, l₂/tan(π/n).
  double outer_radius_peak() const noexcept;
  double configuration_radius_at_outer_peak() const noexcept;

  // The largest r in [r_min, r_max] whose whole expansion path from r_min keeps b(r) ≤ b_limit, i.e.
  // the first crossing of f_b(r) = b_limit on the way out from r_min (bisection, 60 halvings, no
  // allocation). Returns r_max when b never reaches b_limit, and NaN when even r_min exceeds it.
  double configuration_radius_for_outer_limit(double b_limit) const noexcept;

 private:
  ScissorLinkageParameters parameters_;
  double sin_sigma_ = 0.0, cos_sigma_ = 0.0;
  double r_min_ = 0.0, r_max_ = 0.0, a_min_ = 0.0, a_max_ = 0.0, b_min_ = 0.0, b_max_ = 0.0,
         r_at_b_max_ = 0.0;
};

// Disk interference of one continuum segment (Abah 2022, §2.4, Fig. 2.8): length L, n_d identical disks of
// height h_d. Θ = θ_L − π/2 is the bend of the end disk (0 when straight, Simaan's convention).
struct DiskInterferenceParameters {
  double segment_length = 200.0;  // L (mm), Table 2.3
  int disk_count = 8;             // n_d, Table 2.3
  double disk_height = 10.0;      // h_d (mm) = PF·L/n_d with PF = 0.4 (Table 2.3)
};

// (2.16) the largest outer radius b at which neighbouring disks do not touch, for a bend Θ. The
// formula is even in Θ, so either sign of bending gives the same limit; at Θ = 0 (straight) there is
// no limit and this returns +infinity. Returns NaN for a non-finite Θ.
double interference_outer_radius_limit(const DiskInterferenceParameters& disks, double bend) noexcept;
// (2.18) the same limit made dimensionless, b/L, from the packing fraction PF = n_d·h_d/L (2.17).
double interference_outer_radius_ratio(double packing_fraction, int disk_count, double bend) noexcept;
// Throws std::invalid_argument when L or h_d is not positive and finite, n_d < 2, or n_d·h_d > L.
void validate(const DiskInterferenceParameters& disks);

}  // namespace tendril::teleop
