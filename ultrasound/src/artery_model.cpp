// Artery model from ultrasound slices and catheter contacts (Heunis et al. 2021, §3.3); see the header.
#include "tendril/ultrasound/artery_model.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace tendril::ultrasound {

ReconstructedSlice map_slice(const SliceSegmentation& segmentation, const Eigen::Isometry3d& image_pose) {
  if (!segmentation.valid || segmentation.contour.empty()) {
    throw std::invalid_argument("map_slice: the slice was not segmented (no contour)");
  }
  ReconstructedSlice slice;
  slice.contour.reserve(segmentation.contour.size());
  for (const auto& yz : segmentation.contour)
    slice.contour.push_back(image_pose * Eigen::Vector3d(0.0, yz.x(), yz.y()));
  slice.centroid = image_pose * Eigen::Vector3d(0.0, segmentation.centre.x(), segmentation.centre.y());
  return slice;
}

teleop::TriangleMesh loft_artery_mesh(const std::vector<ReconstructedSlice>& slices) {
  if (slices.size() < 2) {
    throw std::invalid_argument("loft_artery_mesh: needs at least 2 slices, got " +
                                std::to_string(slices.size()));
  }
  const std::size_t n = slices.front().contour.size();
  if (n < 3) throw std::invalid_argument("loft_artery_mesh: contours need at least 3 points");
  teleop::TriangleMesh mesh;
  for (std::size_t s = 0; s < slices.size(); ++s) {
    if (slices[s].contour.size() != n) {
      throw std::invalid_argument("loft_artery_mesh: slice " + std::to_string(s) + " has " +
                                  std::to_string(slices[s].contour.size()) +
                                  " contour points, the first has " + std::to_string(n));
    }
    for (const auto& p : slices[s].contour) mesh.vertices.push_back(p);
  }
  for (std::size_t s = 0; s + 1 < slices.size(); ++s) {
    for (std::size_t q = 0; q < n; ++q) {
      const auto a = static_cast<std::uint32_t>(s * n + q),
                 b = static_cast<std::uint32_t>(s * n + (q + 1) % n);
      const auto c = static_cast<std::uint32_t>((s + 1) * n + q),
                 d = static_cast<std::uint32_t>((s + 1) * n + (q + 1) % n);
      mesh.triangles.push_back({a, b, d});
      mesh.triangles.push_back({a, d, c});
    }
  }
  return mesh;
}

Eigen::Vector3d closest_point_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                          const Eigen::Vector3d& b, const Eigen::Vector3d& c) noexcept {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + d1 / (d1 - d3) * ab;
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0)
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denominator = 1.0 / (va + vb + vc);
  return a + ab * (vb * denominator) + ac * (vc * denominator);
}

double distance_to_mesh(const teleop::TriangleMesh& mesh, const Eigen::Vector3d& p) noexcept {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d q =
        closest_point_on_triangle(p, mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]);
    best = std::min(best, (q - p).squaredNorm());
  }
  return std::sqrt(best);
}

void find_contacts(const teleop::TriangleMesh& wall, const std::vector<Eigen::Vector3d>& sensors,
                   const CatheterContactParameters& parameters, std::vector<CatheterContact>& contacts,
                   std::vector<double>& distances) {
  contacts.clear();
  distances.resize(sensors.size());
  const double threshold = parameters.threshold();
  for (std::size_t i = 0; i < sensors.size(); ++i) {
    distances[i] = distance_to_mesh(wall, sensors[i]);
    if (distances[i] < threshold) contacts.push_back({static_cast<int>(i), sensors[i], distances[i]});
  }
}

}  // namespace tendril::ultrasound
