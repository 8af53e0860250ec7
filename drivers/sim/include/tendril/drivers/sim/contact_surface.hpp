// ContactSurface: a SIMULATED compliant surface for a tool point — the tissue an ultrasound probe
// presses on (Heunis et al. 2021: "tissue as a spring with an uneven surface"). A plane, or a box whose top
// face is the surface, in a surface frame whose z axis points out of the material; an optional height map
// (SurfaceHeightMap) makes the surface uneven (issue 17 uses it for the limb). The surface can be moved
// at run time (limb motion) from any thread.
//
// Contact law (Kelvin–Voigt, a spring and a damper in parallel, pushing only):
//   F = max(0, k·δ + c·δ̇)·n̂,
// with δ the penetration along the outward normal n̂ and δ̇ its rate (from the tool's velocity relative
// to the surface's). Over a height map the penetration is the vertical depth below h(x, y) times n̂_z
// (exact for a flat surface, first order in the slope), and n̂ is the normal of the height map from
// central differences (0.5 mm). Inside a box the nearest face decides (the sides and the bottom are
// flat). Friction is not modelled: an ultrasound probe slides on gel.
//
// Defaults (the article gives none): k = 0.5 N/mm, the middle of the 0.1–2 N/mm range our check
// simulations span for porcine tissue; c = 0.005 N·s/mm, a 10 ms relaxation time, so the damper adds
// < 0.01 N at the controller's 1.33 mm/s approach and damps a fast impact.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>

#include "tendril/drivers/hardware/latest_value.hpp"

namespace tendril::sim {

// The hook for uneven surfaces. Called from the simulation threads: it must not allocate, lock or
// throw, and it must outlive every ContactSurface that uses it.
class SurfaceHeightMap {
 public:
  virtual ~SurfaceHeightMap() = default;
  // Height (mm) of the surface above the surface frame's z = 0 at (x, y) (mm, surface frame).
  virtual double height(double x, double y) const noexcept = 0;
};

enum class ContactShape : std::uint8_t { plane, box };

struct ContactSurfaceParameters {
  ContactShape shape = ContactShape::plane;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // surface frame in the arm's base frame
  double half_length = 150.0;                              // box: half extent along x (mm)
  double half_width = 100.0;                               // box: half extent along y (mm)
  double depth = 80.0;                                     // box: extent below the top face (mm)
  double stiffness = 0.5;                                  // k (N/mm)
  double damping = 0.005;                                  // c (N·s/mm)
  const SurfaceHeightMap* height_map = nullptr;            // not owned; nullptr: flat
};

struct ContactSample {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   // N on the tool point, base frame
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // outward unit normal at the contact, base frame
  double penetration = 0.0;                          // δ (mm)
  bool in_contact = false;
};

class ContactSurface {
 public:
  // Throws SimulationSetupError naming the parameter when one is out of range.
  explicit ContactSurface(const ContactSurfaceParameters& parameters);

  const ContactSurfaceParameters& parameters() const noexcept { return parameters_; }

  // The contact of a tool point at `point` moving at `velocity` (base frame; mm, mm/s). noexcept,
  // allocation-free; a non-finite input gives no contact.
  ContactSample contact(const Eigen::Vector3d& point, const Eigen::Vector3d& velocity) const noexcept;

  // Moves the surface (limb motion): its frame in the base frame and its linear velocity (mm/s). Any
  // thread; non-finite or non-rigid poses are ignored.
  void move_to(const Eigen::Isometry3d& pose,
               const Eigen::Vector3d& velocity = Eigen::Vector3d::Zero()) noexcept;
  Eigen::Isometry3d pose() const noexcept;

 private:
  struct Motion {  // trivially copyable, for LatestValue
    std::array<double, 16> pose{};
    std::array<double, 3> velocity{};
  };
  double surface_height(double x, double y) const noexcept;

  ContactSurfaceParameters parameters_;
  hardware::LatestValue<Motion> motion_;
};

}  // namespace tendril::sim
