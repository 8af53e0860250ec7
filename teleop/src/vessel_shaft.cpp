#include "tendril/teleop/vessel_shaft.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace tendril::teleop {

VesselShaft::VesselShaft(const CenterlinePolyline& vessel, double steerable_length, double ds)
    : vessel_(VesselCenterline::from_polyline(vessel, ds)), steerable_length_(steerable_length) {
  if (!(steerable_length > 0.0) || !std::isfinite(steerable_length))
    throw std::invalid_argument("VesselShaft: the steerable length must be > 0");
  const auto& t = vessel_.tangents();
  transport_.resize(t.size());
  // The entry's frame: the rotation taking +z to the first tangent (the identity for a vessel placed
  // at the entry with placement_at_entry()).
  transport_[0] = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), t[0]).toRotationMatrix();
  for (std::size_t i = 1; i < t.size(); ++i)
    transport_[i] = Eigen::Quaterniond::FromTwoVectors(t[i - 1], t[i]).toRotationMatrix() * transport_[i - 1];
}

void VesselShaft::pose_at(double s, Eigen::Matrix3d& rotation, Eigen::Vector3d& position) const noexcept {
  const auto& P = vessel_.points();
  const auto& T = vessel_.tangents();
  const std::size_t last = P.size() - 1;
  if (!std::isfinite(s)) s = 0.0;
  if (s <= 0.0) {
    rotation = transport_[0];
    position = P[0] + s * T[0];
    return;
  }
  const double ds = vessel_.spacing();
  const double length = vessel_.length();
  if (s >= length) {
    rotation = transport_[last];
    position = P[last] + (s - length) * T[last];
    return;
  }
  const auto i = std::min(static_cast<std::size_t>(s / ds), last - 1);
  const double u = std::clamp(s / ds - static_cast<double>(i), 0.0, 1.0);
  const Eigen::Vector3d tangent = ((1.0 - u) * T[i] + u * T[i + 1]).normalized();
  rotation = Eigen::Quaterniond::FromTwoVectors(T[i], tangent).toRotationMatrix() * transport_[i];
  position = (1.0 - u) * P[i] + u * P[i + 1];
}

void VesselShaft::section_base(double q1, Eigen::Matrix3d& rotation,
                               Eigen::Vector3d& position) const noexcept {
  pose_at(q1 - steerable_length_, rotation, position);
}

Eigen::Vector3d VesselShaft::shaft_point(double q1, double back) const noexcept {
  Eigen::Matrix3d r;
  Eigen::Vector3d p;
  pose_at(q1 - steerable_length_ - back, r, p);
  return p;
}

void VesselShaft::place(double q1, std::span<Eigen::Vector3d> points) const noexcept {
  Eigen::Matrix3d r;
  Eigen::Vector3d p;
  section_base(q1, r, p);
  for (auto& x : points) x = p + r * x;
}

}  // namespace tendril::teleop
