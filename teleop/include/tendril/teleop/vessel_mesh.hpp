// Vessel surface meshes (STL, ASCII and binary) and centerline extraction from them (Abah 2022, §4.4.2,
// "centerline parameterisation", steps 1–4; step 5, resampling at ds, is VesselCenterline::from_polyline).
//
// The dissertation clusters vertices into equidistant slabs along one global PCA line. An ICA siphon turns
// by more than 90° (folds back on itself), so slabs along a single line cut the vessel twice. Here the
// same steps are applied locally (the dissertation leaves this open):
//   1. PCA of all vertices gives the principal direction; the mesh end is the farthest vertex along
//      the surface (two Dijkstra sweeps over the triangle edges), which for a tube is on a rim.
//   2. Vertices are clustered into equidistant bands of surface distance from that end (spacing
//      cluster_spacing); each band's centroid is a rough centre.
//   3. Each rough centre is refined: the vertices in a thin slab across the local direction (from the
//      neighbouring centres) and near the centre are fitted with a best-fit plane (PCA), projected onto
//      it, and the centre is the least-squares circle through the projected points (the plain mean of
//      step 3 in the dissertation is pulled towards the inner wall of a bend, where vertices crowd); twice.
//   4. A cubic smoothing spline (Reinsch) through the centres, parameterised by chord length, is
//      evaluated every output_spacing mm; radii are the fitted circle radii, smoothed alike.
// Units: millimetres. One branch per mesh; a branched mesh gives the centerline of its longest
// surface path and is not otherwise detected.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop {

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;                // unique (exactly equal coordinates merged)
  std::vector<std::array<std::uint32_t, 3>> triangles;  // indices into vertices
};

struct StlLimits {
  std::size_t max_triangles = 2'000'000;  // a 32 MiB binary upload holds about 670 000
};

// Parses binary STL (detected by size = 84 + 50·n with n the count at byte 80) or ASCII STL ("solid"
// then "facet … vertex x y z ×3 …"). Throws VesselInputError for empty, truncated or malformed input,
// more triangles than the limit, or a coordinate that is not finite. Triangles with repeated vertices
// (zero area after merging) are dropped; none left is an error.
TriangleMesh parse_stl(std::string_view bytes, const StlLimits& limits = {});

struct StlCenterlineOptions {
  StlLimits limits;
  double cluster_spacing = 1.0;   // mm between cluster centres along the vessel (step 2)
  double smoothing_length = 1.0;  // mm, scale of the smoothing spline: λ = length⁴ / cluster_spacing
  double output_spacing = 0.1;    // mm between points of the returned dense polyline
};

// Steps 1–4 above on a parsed mesh. Throws VesselInputError when the mesh is too small to be a vessel
// in millimetres (extent below 1 mm: metres given where millimetres are expected) or larger than 2 m,
// has fewer than 3 clusters, or the options are not positive and finite.
CenterlinePolyline extract_centerline(const TriangleMesh& mesh, const StlCenterlineOptions& options = {});

// parse_stl + extract_centerline. Returns one branch (with radii), starting at the mesh end found
// in step 1; orient it with orient_from() when the insertion end is known.
std::vector<CenterlinePolyline> read_stl_centerline(std::string_view stl_bytes,
                                                    const StlCenterlineOptions& options = {});

// Synthetic surface for tests, benchmarks and demos: an open tube around the polyline with a ring of
// `sides` vertices every ring_spacing mm (parallel-transported frame), radius from radii (or 1.5 mm
// when the polyline has none). Throws VesselInputError like VesselCenterline::from_polyline, or when
// sides < 3.
TriangleMesh make_tube_mesh(const CenterlinePolyline& centerline, double ring_spacing, int sides);

// Binary STL bytes of the mesh (float32 coordinates, zero normals).
std::string write_binary_stl(const TriangleMesh& mesh);

}  // namespace tendril::teleop
