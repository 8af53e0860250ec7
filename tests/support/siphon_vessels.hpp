// Tortuous carotid-siphon-like centerlines for the design optimiser's tests and benchmark. The repo
// has no patient files; these stand in for real ICAs whose cavernous segment folds back on itself in
// tight double bends (bend radii 4–7 mm, 90°–170° turns, in different planes), unlike the gentler,
// randomly generated make_synthetic_ica(). Each is a chain of straight runs and circular arcs, starting
// at the origin along +z, with a point every 0.1 mm; deterministic.
#pragma once

#include <string>
#include <vector>

#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::test {

struct SiphonPiece {
  double length;      // mm of arc length
  double radius;      // bend radius (mm); 0 = straight
  double plane_roll;  // rad: roll of the bending plane about the tangent, relative to the previous bend
};

struct SiphonShape {
  std::string name;
  std::vector<SiphonPiece> pieces;
};

// Three shapes (a "C" siphon with a tight genu, an "S" double siphon, an out-of-plane double loop),
// 92–124 mm long; the header of siphon_vessels.cpp lists their pieces.
const std::vector<SiphonShape>& siphon_shapes();

// The centerline of a shape (radius column 2.5 mm throughout).
teleop::CenterlinePolyline make_siphon(const SiphonShape& shape, double point_spacing = 0.1);

}  // namespace tendril::test
