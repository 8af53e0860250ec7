#include "siphon_vessels.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace tendril::test {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

// An arc of `degrees` at `radius` mm, its plane rolled by `roll_deg` about the tangent.
SiphonPiece bend(double degrees, double radius, double roll_deg) {
  return {radius * degrees * kDeg, radius, roll_deg * kDeg};
}
SiphonPiece straight(double length) { return {length, 0.0, 0.0}; }

}  // namespace

const std::vector<SiphonShape>& siphon_shapes() {
  // Shapes after the siphon types of the angiographic literature (U/V/C/S-shaped cavernous ICA): the
  // petrous turn, then the posterior and anterior genu of the siphon in quick succession.
  static const std::vector<SiphonShape> shapes{
      // "C" siphon, 96.3 mm: petrous turn 90° (r 7), then a tight 160° genu (r 4.5) folding the
      // vessel back, a 100° anterior bend out of plane (r 5) and the supraclinoid run.
      {"c_siphon",
       {straight(30.0), bend(90.0, 7.0, 0.0), straight(8.0), bend(160.0, 4.5, 170.0), straight(6.0),
        bend(100.0, 5.0, 80.0), straight(20.0)}},
      // "S" double siphon, 92.0 mm: two opposite 150° turns (r 4 and 5) back to back with 4 mm
      // between them, then a 90° turn (r 6) into a third plane.
      {"s_siphon",
       {straight(30.0), bend(150.0, 4.0, 0.0), straight(4.0), bend(150.0, 5.0, 180.0), straight(5.0),
        bend(90.0, 6.0, -70.0), straight(20.0)}},
      // Out-of-plane double loop, 123.6 mm: 120° (r 6), 170° (r 5) and 140° (r 4.5) turns whose
      // planes roll by 120° and 60°, then a 100° turn (r 7).
      {"double_loop",
       {straight(35.0), bend(120.0, 6.0, 0.0), straight(5.0), bend(170.0, 5.0, 120.0), straight(5.0),
        bend(140.0, 4.5, 60.0), straight(8.0), bend(100.0, 7.0, -90.0), straight(20.0)}},
  };
  return shapes;
}

teleop::CenterlinePolyline make_siphon(const SiphonShape& shape, double point_spacing) {
  teleop::CenterlinePolyline out;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();  // columns: normal, binormal, tangent
  out.points.push_back(position);
  for (const auto& piece : shape.pieces) {
    const double curvature = piece.radius > 0.0 ? 1.0 / piece.radius : 0.0;
    if (curvature > 0.0)
      frame = frame * Eigen::AngleAxisd(piece.plane_roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    const auto steps = std::max(1, static_cast<int>(std::ceil(piece.length / point_spacing)));
    const double h = piece.length / steps;
    for (int k = 0; k < steps; ++k) {
      // Arc step whose chord is exactly h (as in make_synthetic_ica), so the polyline has the length.
      const double angle = curvature > 0.0 ? 2.0 * std::asin(std::min(1.0, 0.5 * curvature * h)) : 0.0;
      const Eigen::Vector3d local = curvature > 0.0 ? Eigen::Vector3d((1.0 - std::cos(angle)) / curvature,
                                                                      0.0, std::sin(angle) / curvature)
                                                    : Eigen::Vector3d(0.0, 0.0, h);
      position += frame * local;
      frame = frame * Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
      out.points.push_back(position);
    }
  }
  out.radii.assign(out.points.size(), 2.5);
  return out;
}

}  // namespace tendril::test
