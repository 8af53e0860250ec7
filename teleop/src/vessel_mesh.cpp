#include "tendril/teleop/vessel_mesh.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <queue>
#include <string>
#include <unordered_map>
#include <utility>

namespace tendril::teleop {
namespace {

constexpr double kPi() { return 3.14159265358979323846; }

// ---- STL parsing ----------------------------------------------------------------------------------

std::uint32_t read_u32_le(const char* p) {
  const auto* b = reinterpret_cast<const unsigned char*>(p);
  return static_cast<std::uint32_t>(b[0]) | (static_cast<std::uint32_t>(b[1]) << 8) |
         (static_cast<std::uint32_t>(b[2]) << 16) | (static_cast<std::uint32_t>(b[3]) << 24);
}

float read_f32_le(const char* p) {
  const std::uint32_t bits = read_u32_le(p);
  float value;
  std::memcpy(&value, &bits, sizeof value);
  return value;
}

// Merges exactly equal vertices so the triangles share indices (the edge graph needs connectivity).
class VertexMerger {
 public:
  explicit VertexMerger(TriangleMesh& mesh) : mesh_(mesh) {}
  std::uint32_t index_of(const Eigen::Vector3d& v) {
    Key key{v.x(), v.y(), v.z()};
    // −0.0 and +0.0 are the same point.
    for (double& c : key.c)
      if (c == 0.0) c = 0.0;
    const auto [it, inserted] = index_.try_emplace(key, static_cast<std::uint32_t>(mesh_.vertices.size()));
    if (inserted) mesh_.vertices.push_back(v);
    return it->second;
  }
  void add_triangle(const std::array<Eigen::Vector3d, 3>& corners) {
    std::array<std::uint32_t, 3> t{index_of(corners[0]), index_of(corners[1]), index_of(corners[2])};
    if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) mesh_.triangles.push_back(t);
  }

 private:
  struct Key {
    double c[3];
    bool operator==(const Key& o) const { return c[0] == o.c[0] && c[1] == o.c[1] && c[2] == o.c[2]; }
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const noexcept {
      std::size_t h = 0;
      for (double c : k.c) h = h * 1000003u ^ std::hash<double>{}(c);
      return h;
    }
  };
  TriangleMesh& mesh_;
  std::unordered_map<Key, std::uint32_t, KeyHash> index_;
};

void check_corner(const Eigen::Vector3d& v, std::size_t triangle) {
  if (!v.allFinite()) {
    throw VesselInputError("STL: triangle " + std::to_string(triangle + 1) +
                           " has a coordinate that is not finite");
  }
}

TriangleMesh parse_binary(std::string_view bytes, std::uint32_t count) {
  TriangleMesh mesh;
  VertexMerger merger(mesh);
  for (std::uint32_t t = 0; t < count; ++t) {
    const char* record = bytes.data() + 84 + 50 * static_cast<std::size_t>(t);
    std::array<Eigen::Vector3d, 3> corners;
    for (int c = 0; c < 3; ++c) {
      const char* p = record + 12 + std::ptrdiff_t{12} * c;  // skip the facet normal (unused)
      corners[c] = {read_f32_le(p), read_f32_le(p + 4), read_f32_le(p + 8)};
      check_corner(corners[c], t);
    }
    merger.add_triangle(corners);
  }
  return mesh;
}

class AsciiTokens {
 public:
  explicit AsciiTokens(std::string_view text) : text_(text) {}
  // Next whitespace-separated token, empty at the end.
  std::string_view next() {
    while (pos_ < text_.size() && is_space(text_[pos_])) ++pos_;
    const std::size_t start = pos_;
    while (pos_ < text_.size() && !is_space(text_[pos_])) ++pos_;
    last_ = start;
    return text_.substr(start, pos_ - start);
  }
  std::size_t line() const {
    return 1 + static_cast<std::size_t>(
                   std::count(text_.begin(), text_.begin() + static_cast<std::ptrdiff_t>(last_), '\n'));
  }
  // Rest of the current line (the solid's name).
  void skip_line() {
    while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
  }
  [[noreturn]] void fail(const std::string& what) const {
    throw VesselInputError("ASCII STL line " + std::to_string(line()) + ": " + what);
  }
  double number() {
    std::string_view token = next();
    if (token.empty()) fail("expected a number, got the end of the file");
    if (token.front() == '+') token.remove_prefix(1);
    double value = 0.0;
    const auto [end, error] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (error != std::errc() || end != token.data() + token.size()) {
      fail("expected a number, got '" + std::string(token.substr(0, 40)) + "'");
    }
    return value;
  }
  void expect(std::string_view word) {
    const std::string_view token = next();
    if (token != word)
      fail("expected '" + std::string(word) + "', got '" + std::string(token.substr(0, 40)) + "'");
  }

 private:
  static bool is_space(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
  }
  std::string_view text_;
  std::size_t pos_ = 0, last_ = 0;
};

TriangleMesh parse_ascii(std::string_view text, const StlLimits& limits) {
  TriangleMesh mesh;
  VertexMerger merger(mesh);
  AsciiTokens tokens(text);
  std::size_t facets = 0;
  bool in_solid = false;
  while (true) {
    const std::string_view token = tokens.next();
    if (token.empty()) break;
    if (token == "solid") {
      tokens.skip_line();  // the name may contain anything
      in_solid = true;
    } else if (token == "endsolid") {
      tokens.skip_line();
      in_solid = false;
    } else if (token == "facet" && in_solid) {
      if (++facets > limits.max_triangles) {
        tokens.fail("more than " + std::to_string(limits.max_triangles) + " triangles");
      }
      tokens.expect("normal");
      for (int i = 0; i < 3; ++i)
        (void)tokens.number();  // normals are recomputable; some exporters write nan
      tokens.expect("outer");
      tokens.expect("loop");
      std::array<Eigen::Vector3d, 3> corners;
      for (auto& corner : corners) {
        tokens.expect("vertex");
        for (int i = 0; i < 3; ++i) corner[i] = tokens.number();
        if (!corner.allFinite()) tokens.fail("vertex coordinate is not finite");
      }
      tokens.expect("endloop");
      tokens.expect("endfacet");
      merger.add_triangle(corners);
    } else {
      tokens.fail("unexpected '" + std::string(token.substr(0, 40)) +
                  "' (expected solid, facet or endsolid)");
    }
  }
  if (facets == 0) throw VesselInputError("ASCII STL: no facets (empty solid)");
  return mesh;
}

bool starts_with_solid(std::string_view bytes) {
  std::size_t i = 0;
  while (i < bytes.size() && (bytes[i] == ' ' || bytes[i] == '\t' || bytes[i] == '\r' || bytes[i] == '\n'))
    ++i;
  return bytes.substr(i, 5) == "solid";
}

// ---- centerline extraction ------------------------------------------------------------------------

struct Graph {
  std::vector<std::uint32_t> offsets, neighbours;
  std::vector<double> lengths;
};

Graph edge_graph(const TriangleMesh& mesh) {
  const std::size_t n = mesh.vertices.size();
  Graph g;
  g.offsets.assign(n + 1, 0);
  for (const auto& t : mesh.triangles)
    for (int c = 0; c < 3; ++c) g.offsets[t[c] + 1] += 2;
  for (std::size_t i = 0; i < n; ++i) g.offsets[i + 1] += g.offsets[i];
  g.neighbours.resize(g.offsets[n]);
  g.lengths.resize(g.offsets[n]);
  std::vector<std::uint32_t> fill(g.offsets.begin(), g.offsets.end() - 1);
  for (const auto& t : mesh.triangles) {
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t a = t[c], b = t[(c + 1) % 3];
      const double length = (mesh.vertices[a] - mesh.vertices[b]).norm();
      g.neighbours[fill[a]] = b;
      g.lengths[fill[a]++] = length;
      g.neighbours[fill[b]] = a;
      g.lengths[fill[b]++] = length;
    }
  }
  return g;
}

// Surface distance (along triangle edges) from source; unreachable vertices get +∞.
std::vector<double> dijkstra(const Graph& g, std::uint32_t source) {
  const std::size_t n = g.offsets.size() - 1;
  std::vector<double> distance(n, std::numeric_limits<double>::infinity());
  using Item = std::pair<double, std::uint32_t>;
  std::priority_queue<Item, std::vector<Item>, std::greater<>> queue;
  distance[source] = 0.0;
  queue.emplace(0.0, source);
  while (!queue.empty()) {
    const auto [d, v] = queue.top();
    queue.pop();
    if (d > distance[v]) continue;
    for (std::uint32_t e = g.offsets[v]; e < g.offsets[v + 1]; ++e) {
      const double candidate = d + g.lengths[e];
      if (candidate < distance[g.neighbours[e]]) {
        distance[g.neighbours[e]] = candidate;
        queue.emplace(candidate, g.neighbours[e]);
      }
    }
  }
  return distance;
}

std::uint32_t farthest(const std::vector<double>& distance) {
  std::uint32_t best = 0;
  for (std::uint32_t i = 0; i < distance.size(); ++i)
    if (std::isfinite(distance[i]) && (!std::isfinite(distance[best]) || distance[i] > distance[best]))
      best = i;
  return best;
}

// Uniform grid over points for radius queries.
class PointGrid {
 public:
  PointGrid(const std::vector<Eigen::Vector3d>& points, double cell) : points_(points), cell_(cell) {
    order_.resize(points.size());
    for (std::uint32_t i = 0; i < points.size(); ++i) order_[i] = i;
    std::sort(order_.begin(), order_.end(),
              [&](std::uint32_t a, std::uint32_t b) { return key(points[a]) < key(points[b]); });
    for (std::uint32_t i = 0; i < order_.size();) {
      const auto k = key(points[order_[i]]);
      std::uint32_t j = i;
      while (j < order_.size() && key(points[order_[j]]) == k) ++j;
      cells_.emplace(k, std::make_pair(i, j));
      i = j;
    }
  }
  // Calls visit(index) for every point within radius (≤ cell) of centre.
  template <class Visit>
  void within(const Eigen::Vector3d& centre, double radius, Visit&& visit) const {
    const auto c = cell_of(centre);
    for (std::int64_t dx = -1; dx <= 1; ++dx)
      for (std::int64_t dy = -1; dy <= 1; ++dy)
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          const auto it = cells_.find(pack(c[0] + dx, c[1] + dy, c[2] + dz));
          if (it == cells_.end()) continue;
          for (std::uint32_t i = it->second.first; i < it->second.second; ++i)
            if ((points_[order_[i]] - centre).squaredNorm() <= radius * radius) visit(order_[i]);
        }
  }

 private:
  std::array<std::int64_t, 3> cell_of(const Eigen::Vector3d& p) const {
    return {static_cast<std::int64_t>(std::floor(p.x() / cell_)),
            static_cast<std::int64_t>(std::floor(p.y() / cell_)),
            static_cast<std::int64_t>(std::floor(p.z() / cell_))};
  }
  static std::uint64_t pack(std::int64_t x, std::int64_t y, std::int64_t z) {
    const auto part = [](std::int64_t v) { return static_cast<std::uint64_t>(v + (1 << 20)) & 0x1FFFFFu; };
    return part(x) << 42 | part(y) << 21 | part(z);
  }
  std::uint64_t key(const Eigen::Vector3d& p) const {
    const auto c = cell_of(p);
    return pack(c[0], c[1], c[2]);
  }
  const std::vector<Eigen::Vector3d>& points_;
  double cell_;
  std::vector<std::uint32_t> order_;
  std::unordered_map<std::uint64_t, std::pair<std::uint32_t, std::uint32_t>> cells_;
};

struct Cluster {
  Eigen::Vector3d centre;
  double radius;
};

// Least-squares (Kåsa) circle through 2D points; false if ill-conditioned.
bool fit_circle(const std::vector<Eigen::Vector2d>& uv, Eigen::Vector2d& centre, double& radius) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (const auto& p : uv) {
    const Eigen::Vector3d row(p.x(), p.y(), 1.0);
    const double rhs = -(p.squaredNorm());
    A += row * row.transpose();
    b += row * rhs;
  }
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(A);
  if (lu.rank() < 3) return false;
  const Eigen::Vector3d x = lu.solve(b);
  centre = -0.5 * x.head<2>();
  const double r2 = centre.squaredNorm() - x[2];
  if (!(r2 > 0.0) || !centre.allFinite()) return false;
  radius = std::sqrt(r2);
  return true;
}

// Step 3 for one cluster: slab across direction at centre, best-fit plane, circle in the plane.
bool refine(const PointGrid& grid, const std::vector<Eigen::Vector3d>& points, double half_width,
            double search, Eigen::Vector3d& centre, Eigen::Vector3d& direction, double& radius) {
  std::vector<std::uint32_t> slab;
  grid.within(centre, search, [&](std::uint32_t i) {
    if (std::abs((points[i] - centre).dot(direction)) <= half_width) slab.push_back(i);
  });
  if (slab.size() < 8) return false;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (auto i : slab) mean += points[i];
  mean /= static_cast<double>(slab.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (auto i : slab) covariance += (points[i] - mean) * (points[i] - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance);
  Eigen::Vector3d normal = eigen.eigenvectors().col(0);  // smallest variance: across the slab
  // A slab thinner than the lumen has its least spread along the vessel; if the fit tilted the normal
  // far from the current direction (too few points on one side), keep the direction.
  if (std::abs(normal.dot(direction)) < 0.7) normal = direction;
  if (normal.dot(direction) < 0.0) normal = -normal;
  const Eigen::Vector3d u = normal.unitOrthogonal(), v = normal.cross(u);
  std::vector<Eigen::Vector2d> uv;
  uv.reserve(slab.size());
  for (auto i : slab) uv.emplace_back((points[i] - mean).dot(u), (points[i] - mean).dot(v));
  Eigen::Vector2d c2;
  double r = 0.0;
  Eigen::Vector3d fitted = mean;
  if (fit_circle(uv, c2, r) && c2.norm() < search) {
    fitted = mean + c2.x() * u + c2.y() * v;
  } else {
    r = 0.0;
    for (const auto& p : uv) r += p.norm();
    r /= static_cast<double>(uv.size());
  }
  centre = fitted;
  direction = normal;
  radius = r;
  return true;
}

// Reinsch cubic smoothing spline (Green & Silverman §2.3) of several value columns over knots x:
// minimises Σ(y − f)² + λ∫f''²; returns fitted values and second derivatives at the knots.
void smoothing_spline(const std::vector<double>& x, const Eigen::MatrixXd& y, double lambda,
                      Eigen::MatrixXd& f, Eigen::MatrixXd& second) {
  const auto n = static_cast<Eigen::Index>(x.size());
  const Eigen::Index m = n - 2;
  std::vector<double> h(x.size() - 1);
  for (std::size_t i = 0; i + 1 < x.size(); ++i) h[i] = x[i + 1] - x[i];
  Eigen::SparseMatrix<double> Q(n, m), R(m, m);
  std::vector<Eigen::Triplet<double>> q, r;
  for (Eigen::Index j = 1; j <= m; ++j) {
    const double a = h[static_cast<std::size_t>(j - 1)], b = h[static_cast<std::size_t>(j)];
    q.emplace_back(j - 1, j - 1, 1.0 / a);
    q.emplace_back(j, j - 1, -1.0 / a - 1.0 / b);
    q.emplace_back(j + 1, j - 1, 1.0 / b);
    r.emplace_back(j - 1, j - 1, (a + b) / 3.0);
    if (j < m) {
      r.emplace_back(j - 1, j, b / 6.0);
      r.emplace_back(j, j - 1, b / 6.0);
    }
  }
  Q.setFromTriplets(q.begin(), q.end());
  R.setFromTriplets(r.begin(), r.end());
  const Eigen::SparseMatrix<double> Qt = Q.transpose();
  const Eigen::SparseMatrix<double> system = R + lambda * (Qt * Q);
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(system);
  if (solver.info() != Eigen::Success)
    throw VesselInputError("STL centerline: smoothing spline failed (degenerate clusters)");
  const Eigen::MatrixXd gamma = solver.solve(Qt * y);
  f = y - lambda * (Q * gamma);
  second = Eigen::MatrixXd::Zero(n, y.cols());
  second.middleRows(1, m) = gamma;
}

}  // namespace

TriangleMesh parse_stl(std::string_view bytes, const StlLimits& limits) {
  if (bytes.empty()) throw VesselInputError("STL: the file is empty");
  if (bytes.size() >= 84) {
    const std::uint32_t count = read_u32_le(bytes.data() + 80);
    if (bytes.size() == 84 + 50 * static_cast<std::uint64_t>(count)) {
      if (count == 0) throw VesselInputError("binary STL: no triangles");
      if (count > limits.max_triangles) {
        throw VesselInputError("binary STL: " + std::to_string(count) +
                               " triangles, more than the limit of " + std::to_string(limits.max_triangles));
      }
      TriangleMesh mesh = parse_binary(bytes, count);
      if (mesh.triangles.empty()) throw VesselInputError("binary STL: every triangle is degenerate");
      return mesh;
    }
  }
  if (starts_with_solid(bytes) && bytes.find("facet") != std::string_view::npos) {
    TriangleMesh mesh = parse_ascii(bytes, limits);
    if (mesh.triangles.empty()) throw VesselInputError("ASCII STL: every triangle is degenerate");
    return mesh;
  }
  if (bytes.size() >= 84) {
    const std::uint32_t count = read_u32_le(bytes.data() + 80);
    throw VesselInputError("not an STL file: as binary STL, " + std::to_string(count) + " triangles need " +
                           std::to_string(84 + 50 * static_cast<std::uint64_t>(count)) +
                           " bytes but there are " + std::to_string(bytes.size()) +
                           ", and it is not ASCII STL ('solid' … 'facet')");
  }
  throw VesselInputError("not an STL file: too short for binary STL (" + std::to_string(bytes.size()) +
                         " bytes) and not ASCII STL ('solid' … 'facet')");
}

CenterlinePolyline extract_centerline(const TriangleMesh& mesh, const StlCenterlineOptions& options) {
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (!positive(options.cluster_spacing) || !positive(options.smoothing_length) ||
      !positive(options.output_spacing)) {
    throw VesselInputError(
        "STL centerline: cluster_spacing, smoothing_length and output_spacing must be > 0 mm");
  }
  if (mesh.vertices.size() < 3 || mesh.triangles.empty()) throw VesselInputError("STL: no usable triangles");
  for (const auto& v : mesh.vertices)
    if (!v.allFinite()) throw VesselInputError("STL: a vertex is not finite");
  for (const auto& t : mesh.triangles)
    for (auto i : t)
      if (i >= mesh.vertices.size()) throw VesselInputError("STL: triangle index out of range");

  // Step 1: principal direction and extent.
  Eigen::Vector3d lo = mesh.vertices[0], hi = mesh.vertices[0];
  for (const auto& v : mesh.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  const double extent = (hi - lo).norm();
  if (extent < VesselCenterline::kMinimumPlausibleLengthMm) {
    throw VesselInputError(
        "STL: the mesh spans only " + std::to_string(extent) +
        " units; coordinates look like metres, but millimetres are expected (scale by 1000)");
  }
  // No catheterised vessel path spans 2 m (groin to brain is about 1 m); larger extents would also
  // make extraction slow for nothing.
  constexpr double kMaximumPlausibleExtentMm = 2'000.0;
  if (extent > kMaximumPlausibleExtentMm) {
    throw VesselInputError("STL: the mesh spans " + std::to_string(extent) +
                           " mm, more than 2 m; millimetres are expected (was it in micrometres?)");
  }

  // Ends: two sweeps of surface distance within the largest connected part.
  const Graph graph = edge_graph(mesh);
  std::vector<double> from_any = dijkstra(graph, mesh.triangles[0][0]);
  {
    // Start from the largest component: label components by repeated sweeps (unreached = +∞).
    std::vector<std::int32_t> label(mesh.vertices.size(), -1);
    std::vector<std::size_t> sizes;
    for (std::uint32_t s = 0; s < mesh.vertices.size(); ++s) {
      if (label[s] >= 0 || graph.offsets[s] == graph.offsets[s + 1]) continue;
      const auto id = static_cast<std::int32_t>(sizes.size());
      sizes.push_back(0);
      std::vector<std::uint32_t> stack{s};
      label[s] = id;
      while (!stack.empty()) {
        const auto v = stack.back();
        stack.pop_back();
        ++sizes.back();
        for (auto e = graph.offsets[v]; e < graph.offsets[v + 1]; ++e)
          if (label[graph.neighbours[e]] < 0) {
            label[graph.neighbours[e]] = id;
            stack.push_back(graph.neighbours[e]);
          }
      }
    }
    const auto largest =
        static_cast<std::int32_t>(std::max_element(sizes.begin(), sizes.end()) - sizes.begin());
    for (std::uint32_t s = 0; s < mesh.vertices.size(); ++s)
      if (label[s] == largest) {
        from_any = dijkstra(graph, s);
        break;
      }
  }
  const std::uint32_t end_a = farthest(from_any);
  const std::vector<double> distance = dijkstra(graph, end_a);
  const double span = distance[farthest(distance)];

  // Step 2: equidistant clusters by surface distance from the end; rough centres and radii.
  const double h = options.cluster_spacing;
  constexpr double kMaxSamples = 1e6;  // bounds memory whatever the options
  if (span / h > kMaxSamples || 4.0 * std::max(span, extent) / options.output_spacing > kMaxSamples) {
    throw VesselInputError(
        "STL centerline: cluster_spacing or output_spacing is too small for a mesh this large");
  }
  const auto bands = static_cast<std::size_t>(span / h) + 1;
  std::vector<Eigen::Vector3d> sums(bands, Eigen::Vector3d::Zero());
  std::vector<std::size_t> counts(bands, 0);
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!std::isfinite(distance[i])) continue;
    const auto b = std::min(bands - 1, static_cast<std::size_t>(distance[i] / h));
    sums[b] += mesh.vertices[i];
    ++counts[b];
  }
  std::vector<Eigen::Vector3d> rough;
  for (std::size_t b = 0; b < bands; ++b)
    if (counts[b] > 0) rough.push_back(sums[b] / static_cast<double>(counts[b]));
  if (rough.size() < 3) {
    throw VesselInputError("STL: the mesh is too short for centerline extraction (fewer than 3 clusters at " +
                           std::to_string(h) + " mm spacing)");
  }
  std::vector<double> spread(bands, 0.0);
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!std::isfinite(distance[i])) continue;
    const auto b = std::min(bands - 1, static_cast<std::size_t>(distance[i] / h));
    spread[b] = std::max(spread[b], (mesh.vertices[i] - sums[b] / static_cast<double>(counts[b])).norm());
  }
  std::vector<double> spreads;
  for (std::size_t b = 0; b < bands; ++b)
    if (counts[b] > 0) spreads.push_back(spread[b]);
  std::nth_element(spreads.begin(), spreads.begin() + static_cast<std::ptrdiff_t>(spreads.size() / 2),
                   spreads.end());
  const double typical_radius = std::max(spreads[spreads.size() / 2], h);

  // Surface samples so coarse triangles (long edges) still put points into thin slabs.
  std::vector<Eigen::Vector3d> cloud = mesh.vertices;
  const double sample_spacing = 0.5 * h;
  constexpr std::size_t kMaxCloud = 4'000'000;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    const double longest = std::max({(a - b).norm(), (b - c).norm(), (c - a).norm()});
    const auto m = static_cast<int>(std::min(64.0, std::ceil(longest / sample_spacing)));
    for (int i = 0; i <= m && cloud.size() < kMaxCloud; ++i)
      for (int j = 0; i + j <= m; ++j) {
        if ((i == 0 && j == 0) || (i == m && j == 0) || (i == 0 && j == m)) continue;  // the corners
        cloud.push_back(a + (b - a) * (static_cast<double>(i) / m) + (c - a) * (static_cast<double>(j) / m));
      }
  }

  // Step 3: refine each cluster with its local best-fit plane and circle.
  const double search_limit = 2.0 * typical_radius + h;
  const PointGrid grid(cloud, search_limit);
  std::vector<Cluster> clusters;
  std::vector<Eigen::Vector3d> centres = rough;
  std::vector<double> radii(rough.size(), typical_radius);
  std::vector<bool> good(rough.size(), true);
  for (int pass = 0; pass < 2; ++pass) {
    const std::vector<Eigen::Vector3d> previous = centres;
    for (std::size_t k = 0; k < centres.size(); ++k) {
      const std::size_t before = k == 0 ? 0 : k - 1, after = std::min(k + 1, centres.size() - 1);
      Eigen::Vector3d direction = previous[after] - previous[before];
      if (direction.norm() < 1e-12) {
        good[k] = false;
        continue;
      }
      direction.normalize();
      const double search = std::min(search_limit, 1.5 * std::max(radii[k], 0.25 * typical_radius) + h);
      double radius = radii[k];
      good[k] = refine(grid, cloud, 0.5 * h, search, centres[k], direction, radius);
      if (good[k]) radii[k] = radius;
    }
  }
  // Near each end a band of surface distance is an arc of the wall, not a ring, until it is half a
  // circumference away; its rough centre and direction are poor. Those clusters are dropped and
  // replaced by marching outwards from the first full-ring cluster: step h along the local direction,
  // refine, repeat while the slab still holds wall points.
  const auto arc_bands = static_cast<std::size_t>(std::ceil(kPi() * typical_radius / h)) + 1;
  const std::size_t trim = std::min(arc_bands, centres.size() / 4);
  std::vector<Cluster> interior;
  for (std::size_t k = trim; k + trim < centres.size(); ++k) {
    if (!good[k] || !centres[k].allFinite()) continue;
    if (!interior.empty() && (centres[k] - interior.back().centre).norm() < 0.25 * h) continue;
    interior.push_back({centres[k], radii[k]});
  }
  auto march = [&](std::vector<Cluster>& line, bool backwards) {
    if (line.size() < 2) return std::vector<Cluster>{};
    const Cluster& end = backwards ? line.front() : line.back();
    const Cluster& inner = backwards ? line[1] : line[line.size() - 2];
    Eigen::Vector3d centre = end.centre, direction = (end.centre - inner.centre).normalized();
    double radius = end.radius;
    std::vector<Cluster> added;
    const std::size_t max_steps = 2 * arc_bands + 10;
    for (std::size_t step = 0; step < max_steps; ++step) {
      Eigen::Vector3d next = centre + h * direction, next_direction = direction;
      double next_radius = radius;
      const double search = std::min(search_limit, 1.5 * radius + h);
      if (!refine(grid, cloud, 0.5 * h, search, next, next_direction, next_radius)) break;
      if ((next - centre).dot(direction) < 0.25 * h || next_radius > 2.0 * radius + h) break;
      centre = next;
      direction = next_direction;
      radius = next_radius;
      added.push_back({centre, radius});
    }
    return added;
  };
  const std::vector<Cluster> head = march(interior, true), tail = march(interior, false);
  clusters.assign(head.rbegin(), head.rend());
  clusters.insert(clusters.end(), interior.begin(), interior.end());
  clusters.insert(clusters.end(), tail.begin(), tail.end());
  if (clusters.size() < 3) {
    throw VesselInputError("STL: the mesh does not look like a vessel (fewer than 3 usable cross-sections)");
  }

  // Step 4: smoothing spline over chord length, evaluated densely.
  const auto n = static_cast<Eigen::Index>(clusters.size());
  std::vector<double> knots(clusters.size(), 0.0);
  Eigen::MatrixXd values(n, 4);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto& c = clusters[static_cast<std::size_t>(i)];
    if (i > 0) {
      knots[static_cast<std::size_t>(i)] =
          knots[static_cast<std::size_t>(i - 1)] +
          (c.centre - clusters[static_cast<std::size_t>(i - 1)].centre).norm();
    }
    values.row(i) << c.centre.x(), c.centre.y(), c.centre.z(), c.radius;
  }
  Eigen::MatrixXd fitted, second;
  const double lambda = std::pow(options.smoothing_length, 4) / h;
  smoothing_spline(knots, values, lambda, fitted, second);

  CenterlinePolyline out;
  const double total = knots.back();
  if (total / options.output_spacing > 4.0 * kMaxSamples) {
    throw VesselInputError("STL centerline: output_spacing is too small for a centerline this long");
  }
  std::vector<double> stations;
  for (std::size_t k = 0; options.output_spacing * static_cast<double>(k) < total - 1e-9; ++k) {
    stations.push_back(options.output_spacing * static_cast<double>(k));
  }
  stations.push_back(total);
  out.points.reserve(stations.size());
  out.radii.reserve(stations.size());
  std::size_t i = 0;
  for (const double x : stations) {
    while (i + 2 < knots.size() && x > knots[i + 1]) ++i;
    const double hi_ = knots[i + 1] - knots[i];
    const double a = x - knots[i], b = knots[i + 1] - x;
    const auto r0 = static_cast<Eigen::Index>(i), r1 = r0 + 1;
    const Eigen::RowVector4d value =
        (a * fitted.row(r1) + b * fitted.row(r0)) / hi_ -
        a * b / 6.0 * ((1.0 + a / hi_) * second.row(r1) + (1.0 + b / hi_) * second.row(r0));
    out.points.emplace_back(value[0], value[1], value[2]);
    out.radii.push_back(std::max(0.0, value[3]));
    if (!value.allFinite())
      throw VesselInputError("STL: no centerline could be extracted (degenerate geometry)");
  }
  return out;
}

TriangleMesh make_tube_mesh(const CenterlinePolyline& centerline, double ring_spacing, int sides) {
  if (sides < 3) throw VesselInputError("make_tube_mesh: need at least 3 sides");
  const auto vessel = VesselCenterline::from_polyline(centerline, ring_spacing);
  TriangleMesh mesh;
  Eigen::Vector3d normal = vessel.tangents()[0].unitOrthogonal();
  for (std::size_t i = 0; i < vessel.size(); ++i) {
    const Eigen::Vector3d& t = vessel.tangents()[i];
    normal = (normal - normal.dot(t) * t).normalized();
    const Eigen::Vector3d binormal = t.cross(normal);
    const double radius = vessel.has_radius() ? vessel.radii()[i] : 1.5;
    for (int k = 0; k < sides; ++k) {
      const double a = 2.0 * kPi() * k / sides;
      mesh.vertices.push_back(vessel.points()[i] + radius * (std::cos(a) * normal + std::sin(a) * binormal));
    }
  }
  const auto n = static_cast<std::uint32_t>(sides);
  for (std::uint32_t i = 0; i + 1 < vessel.size(); ++i)
    for (std::uint32_t k = 0; k < n; ++k) {
      const std::uint32_t a = i * n + k, b = (i + 1) * n + k, c = (i + 1) * n + (k + 1) % n,
                          d = i * n + (k + 1) % n;
      mesh.triangles.push_back({a, b, c});
      mesh.triangles.push_back({a, c, d});
    }
  return mesh;
}

std::string write_binary_stl(const TriangleMesh& mesh) {
  std::string out(80, ' ');
  out.reserve(84 + 50 * mesh.triangles.size());
  auto put_u32 = [&out](std::uint32_t v) {
    for (int b = 0; b < 4; ++b) out.push_back(static_cast<char>((v >> (8 * b)) & 0xFFu));
  };
  auto put_f32 = [&](double v) {
    const auto f = static_cast<float>(v);
    std::uint32_t bits;
    std::memcpy(&bits, &f, sizeof bits);
    put_u32(bits);
  };
  put_u32(static_cast<std::uint32_t>(mesh.triangles.size()));
  for (const auto& t : mesh.triangles) {
    for (int i = 0; i < 3; ++i) put_f32(0.0);
    for (const auto index : t)
      for (int i = 0; i < 3; ++i) put_f32(mesh.vertices[index][i]);
    out.append(2, '\0');
  }
  return out;
}

std::vector<CenterlinePolyline> read_stl_centerline(std::string_view stl_bytes,
                                                    const StlCenterlineOptions& options) {
  return {extract_centerline(parse_stl(stl_bytes, options.limits), options)};
}

}  // namespace tendril::teleop
