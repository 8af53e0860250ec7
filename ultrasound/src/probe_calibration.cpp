// Image-to-probe calibration with an N-wire phantom (Heunis et al. 2021, §2.3); see the header.
#include "tendril/ultrasound/probe_calibration.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "tendril/ultrasound/reconstruction_session.hpp"  // is_rigid

namespace tendril::ultrasound {
namespace {

constexpr double kPi = 3.14159265358979323846;

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", v);
  return buf;
}

double open_uniform(std::mt19937_64& engine) {
  return (static_cast<double>(engine() >> 11) + 0.5) * 0x1.0p-53;
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Matrix3d exp_rotation(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

}  // namespace

ImageCalibration ImageCalibration::nominal(const BModeGeometry& geometry) {
  ImageCalibration c;
  c.s_u = geometry.pixel_size;
  c.s_v = geometry.pixel_size;
  return c;
}

void ImageCalibration::validate() const {
  if (!is_rigid(image_in_probe))
    throw UltrasoundSetupError(
        "image calibration: H_I^U is not a rigid transform (finite, orthonormal, det +1)");
  for (const double s : {s_u, s_v}) {
    if (!std::isfinite(s) || s <= 0.0 || s > 10.0)
      throw UltrasoundSetupError("image calibration: a pixel scale must be in (0, 10] mm, got " + number(s));
  }
}

std::array<std::array<Eigen::Vector3d, 2>, 3> NWirePhantom::wires(const NWireLayer& layer) const {
  const double h = wire_half_length, z = layer.depth;
  return {{{Eigen::Vector3d(-h, layer.y_first, z), Eigen::Vector3d(h, layer.y_first, z)},
           {Eigen::Vector3d(layer.x_start, layer.y_first, z), Eigen::Vector3d(layer.x_end, layer.y_last, z)},
           {Eigen::Vector3d(-h, layer.y_last, z), Eigen::Vector3d(h, layer.y_last, z)}}};
}

void NWirePhantom::validate() const {
  if (layers.empty()) throw UltrasoundSetupError("N-wire phantom: it has no layers");
  if (!std::isfinite(wire_half_length) || wire_half_length <= 0.0)
    throw UltrasoundSetupError("N-wire phantom: the wires' half length must be positive, got " +
                               number(wire_half_length));
  for (std::size_t i = 0; i < layers.size(); ++i) {
    const NWireLayer& l = layers[i];
    for (const double v : {l.depth, l.y_first, l.y_last, l.x_start, l.x_end}) {
      if (!std::isfinite(v))
        throw UltrasoundSetupError("N-wire phantom: layer " + std::to_string(i) + " is not finite");
    }
    if (std::abs(l.y_last - l.y_first) < 4.0)
      throw UltrasoundSetupError("N-wire phantom: layer " + std::to_string(i) +
                                 "'s parallel wires are closer than 4 mm (their echoes would merge)");
    if (std::abs(l.x_end - l.x_start) < 4.0 || std::abs(l.x_start) > wire_half_length ||
        std::abs(l.x_end) > wire_half_length)
      throw UltrasoundSetupError("N-wire phantom: layer " + std::to_string(i) +
                                 "'s diagonal must span at least 4 mm along the wires and stay within them");
  }
}

std::vector<NWireCrossing> n_wire_crossings(const NWirePhantom& phantom,
                                            const Eigen::Isometry3d& phantom_T_image, double field_width_mm,
                                            double field_depth_mm) {
  std::vector<NWireCrossing> out;
  const Eigen::Vector3d origin = phantom_T_image.translation();
  const Eigen::Vector3d normal = phantom_T_image.linear().col(0);
  const Eigen::Isometry3d image_T_phantom = phantom_T_image.inverse();
  for (std::size_t l = 0; l < phantom.layers.size(); ++l) {
    const auto wires = phantom.wires(phantom.layers[l]);
    NWireCrossing crossing;
    crossing.layer = static_cast<int>(l);
    bool all = true;
    for (std::size_t w = 0; w < 3 && all; ++w) {
      const Eigen::Vector3d& a = wires[w][0];
      const Eigen::Vector3d& b = wires[w][1];
      const double da = normal.dot(a - origin), db = normal.dot(b - origin);
      if ((da > 0.0 && db > 0.0) || (da < 0.0 && db < 0.0) || da == db) {
        all = false;
        break;
      }
      const Eigen::Vector3d point = a + da / (da - db) * (b - a);
      const Eigen::Vector3d local = image_T_phantom * point;
      if (std::abs(local.y()) > 0.5 * field_width_mm || local.z() < 0.0 || local.z() > field_depth_mm) {
        all = false;
        break;
      }
      crossing.in_image[w] = {local.y(), local.z()};
      if (w == 1) crossing.middle_in_phantom = point;
    }
    if (all) out.push_back(crossing);
  }
  return out;
}

SimulatedNWireScanner::SimulatedNWireScanner(NWirePhantom phantom, const BModeGeometry& geometry,
                                             const ImageCalibration& truth,
                                             const SimulatedNWireParameters& parameters)
    : phantom_(std::move(phantom)), geometry_(geometry), truth_(truth), parameters_(parameters) {
  geometry_.validate();
  phantom_.validate();
  truth_.validate();
  const auto& p = parameters_;
  for (const double v : {p.water_echo, p.wire_echo, p.noise_sigma, p.wire_speckle}) {
    if (!std::isfinite(v) || v < 0.0)
      throw UltrasoundSetupError("simulated N-wire scanner: echoes and noise must be finite and >= 0, got " +
                                 number(v));
  }
  for (const double v : {p.lateral_psf_mm, p.axial_psf_mm}) {
    if (!std::isfinite(v) || v <= 0.0)
      throw UltrasoundSetupError("simulated N-wire scanner: the point-spread widths must be positive, got " +
                                 number(v));
  }
  if (p.wire_speckle > 1.0)
    throw UltrasoundSetupError("simulated N-wire scanner: wire_speckle is a fraction in [0, 1], got " +
                               number(p.wire_speckle));
}

std::vector<NWireCrossing> SimulatedNWireScanner::crossings(const Eigen::Isometry3d& phantom_T_probe) const {
  return n_wire_crossings(phantom_, phantom_T_probe * truth_.image_in_probe, truth_.s_u * geometry_.columns,
                          truth_.s_v * geometry_.rows);
}

BModeImage SimulatedNWireScanner::render(const Eigen::Isometry3d& phantom_T_probe, std::uint64_t seed) const {
  BModeImage image;
  image.geometry = geometry_;
  image.pixels.resize(geometry_.pixel_count());
  const std::vector<NWireCrossing> cut = crossings(phantom_T_probe);
  std::vector<Eigen::Vector2d> echoes;
  for (const auto& c : cut) echoes.insert(echoes.end(), c.in_image.begin(), c.in_image.end());
  const auto& p = parameters_;
  std::mt19937_64 engine(seed);
  const double rayleigh_sigma = std::sqrt(2.0 / kPi);
  const double reach_y = 4.0 * p.lateral_psf_mm, reach_z = 4.0 * p.axial_psf_mm;
  for (int row = 0; row < geometry_.rows; ++row) {
    for (int column = 0; column < geometry_.columns; ++column) {
      // Where this pixel truly is: the TRUE scales, not the geometry's nominal pixel size.
      const Eigen::Vector3d at = truth_.in_image(geometry_, {column, row});
      double wire = 0.0;
      for (const auto& e : echoes) {
        const double dy = at.y() - e.x(), dz = at.z() - e.y();
        if (std::abs(dy) > reach_y || std::abs(dz) > reach_z) continue;
        wire += p.wire_echo * std::exp(-0.5 * (dy * dy / (p.lateral_psf_mm * p.lateral_psf_mm) +
                                               dz * dz / (p.axial_psf_mm * p.axial_psf_mm)));
      }
      const double u1 = open_uniform(engine), u2 = open_uniform(engine), u3 = open_uniform(engine);
      const double speckle = rayleigh_sigma * std::sqrt(-2.0 * std::log(u1));
      const double noise = p.noise_sigma * std::sqrt(-2.0 * std::log(u2)) * std::cos(2.0 * kPi * u3);
      // A wire is a specular reflector: most of its echo is steady, a fraction speckles.
      const double value =
          p.water_echo * speckle + wire * (1.0 - p.wire_speckle + p.wire_speckle * speckle) + noise;
      image.pixels[static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry_.columns) +
                   static_cast<std::size_t>(column)] = static_cast<float>(std::clamp(value, 0.0, 1.0));
    }
  }
  return image;
}

std::vector<EchoSpot> detect_echo_spots(const BModeImage& image, const EchoSpotParameters& parameters) {
  const BModeGeometry& g = image.geometry;
  g.validate();
  if (image.pixels.size() != g.pixel_count())
    throw UltrasoundSetupError("echo spots: the image has " + std::to_string(image.pixels.size()) +
                               " pixels, its geometry says " + std::to_string(g.pixel_count()));
  if (!(parameters.blur_sigma_px > 0.0 && parameters.blur_sigma_px <= 10.0) ||
      !(parameters.threshold > 0.0 && parameters.threshold < 1.0) || parameters.min_area < 1 ||
      parameters.max_area < parameters.min_area)
    throw UltrasoundSetupError(
        "echo spots: blur in (0, 10] px, threshold in (0, 1) and 1 <= min_area <= "
        "max_area expected");
  const int w = g.columns, h = g.rows;
  const auto index = [w](int c, int r) {
    return static_cast<std::size_t>(r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(c);
  };
  // Separable Gaussian blur, clamped at the borders.
  const int half = static_cast<int>(std::ceil(3.0 * parameters.blur_sigma_px));
  std::vector<double> kernel(static_cast<std::size_t>(2 * half) + 1);
  double sum = 0.0;
  for (std::size_t k = 0; k < kernel.size(); ++k) {
    const double i = static_cast<double>(k) - half;
    kernel[k] = std::exp(-0.5 * i * i / (parameters.blur_sigma_px * parameters.blur_sigma_px));
    sum += kernel[k];
  }
  for (double& k : kernel) k /= sum;
  std::vector<double> rows(g.pixel_count()), blurred(g.pixel_count());
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      double acc = 0.0;
      for (std::size_t k = 0; k < kernel.size(); ++k)
        acc += kernel[k] * image.pixels[index(std::clamp(c + static_cast<int>(k) - half, 0, w - 1), r)];
      rows[index(c, r)] = acc;
    }
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      double acc = 0.0;
      for (std::size_t k = 0; k < kernel.size(); ++k)
        acc += kernel[k] * rows[index(c, std::clamp(r + static_cast<int>(k) - half, 0, h - 1))];
      blurred[index(c, r)] = acc;
    }
  // 8-connected components over the threshold; centroid weighted by the height above it.
  std::vector<unsigned char> seen(g.pixel_count(), 0);
  std::vector<std::pair<int, int>> stack;
  std::vector<EchoSpot> spots;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      if (seen[index(c, r)] || blurred[index(c, r)] <= parameters.threshold) continue;
      seen[index(c, r)] = 1;
      stack.assign(1, {c, r});
      EchoSpot spot;
      double weight = 0.0;
      Eigen::Vector2d moment = Eigen::Vector2d::Zero();
      while (!stack.empty()) {
        const auto [pc, pr] = stack.back();
        stack.pop_back();
        const double v = blurred[index(pc, pr)];
        ++spot.area;
        spot.peak = std::max(spot.peak, v);
        weight += v - parameters.threshold;
        moment += (v - parameters.threshold) * Eigen::Vector2d(pc, pr);
        for (int dr = -1; dr <= 1; ++dr)
          for (int dc = -1; dc <= 1; ++dc) {
            const int nc = pc + dc, nr = pr + dr;
            if (nc < 0 || nr < 0 || nc >= w || nr >= h || seen[index(nc, nr)] ||
                blurred[index(nc, nr)] <= parameters.threshold)
              continue;
            seen[index(nc, nr)] = 1;
            stack.emplace_back(nc, nr);
          }
      }
      if (spot.area < parameters.min_area || spot.area > parameters.max_area || weight <= 0.0) continue;
      spot.pixel = moment / weight;
      spots.push_back(spot);
    }
  std::sort(spots.begin(), spots.end(), [](const EchoSpot& a, const EchoSpot& b) { return a.peak > b.peak; });
  return spots;
}

std::vector<NWireObservation> match_n_wires(const std::vector<EchoSpot>& spots, const NWirePhantom& phantom,
                                            const std::vector<NWireCrossing>& predicted,
                                            const BModeGeometry& geometry, const ImageCalibration& nominal,
                                            double tolerance_px, std::string* why) {
  std::vector<NWireObservation> out;
  std::string notes;
  const auto to_pixel = [&](const Eigen::Vector2d& yz) {
    return Eigen::Vector2d(yz.x() / nominal.s_u + geometry.centre_column(), yz.y() / nominal.s_v);
  };
  for (const auto& p : predicted) {
    const Eigen::Vector2d a = to_pixel(p.in_image[0]), b = to_pixel(p.in_image[2]);
    const Eigen::Vector2d along = (b - a).normalized();
    const double length = (b - a).norm();
    // The spots near the predicted line through A and B, over its length (± the tolerance): the
    // nominal calibration can be millimetres off, more than M's distance to A or B, so the three are
    // told apart by their order along the line, not by which prediction is nearest.
    std::vector<std::pair<double, Eigen::Vector2d>> near;
    for (const auto& s : spots) {
      const Eigen::Vector2d d = s.pixel - a;
      const double t = d.dot(along);
      const double off = std::abs(d.x() * along.y() - d.y() * along.x());
      if (off <= tolerance_px && t >= -tolerance_px && t <= length + tolerance_px)
        near.emplace_back(t, s.pixel);
    }
    if (near.size() != 3) {
      notes += "layer " + std::to_string(p.layer + 1) + ": " + std::to_string(near.size()) +
               " echoes near its wires, 3 expected; ";
      continue;
    }
    std::sort(near.begin(), near.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    NWireObservation o;
    o.layer = p.layer;
    for (std::size_t k = 0; k < 3; ++k) o.pixels[k] = near[k].second;
    const Eigen::Vector2d ab = o.pixels[2] - o.pixels[0];
    const Eigen::Vector2d am = o.pixels[1] - o.pixels[0];
    // A, M and B lie on the line where the image plane meets the layer's plane: check it.
    const double off_line = std::abs(am.x() * ab.y() - am.y() * ab.x()) / ab.norm();
    if (ab.norm() < 8.0 || off_line > 3.0) {
      notes += "layer " + std::to_string(p.layer + 1) + ": its three echoes are not on one line; ";
      continue;
    }
    const double ratio = am.dot(ab) / ab.squaredNorm();  // |AM| / |AB|: unchanged by the pixel scales
    const auto wires = phantom.wires(phantom.layers[static_cast<std::size_t>(p.layer)]);
    o.middle_in_phantom = wires[1][0] + ratio * (wires[1][1] - wires[1][0]);
    out.push_back(o);
  }
  if (why) *why = notes;
  return out;
}

ImageCalibrationFit solve_image_calibration(const std::vector<PixelCorrespondence>& points,
                                            const BModeGeometry& geometry) {
  geometry.validate();
  std::vector<int> images;
  for (const auto& p : points) {
    if (!p.pixel.allFinite() || !p.in_probe.allFinite())
      throw ImageCalibrationError("image calibration: a fiducial's pixel or point is not finite");
    if (std::find(images.begin(), images.end(), p.image) == images.end()) images.push_back(p.image);
  }
  if (points.size() < 6 || images.size() < 2)
    throw ImageCalibrationError(
        "image calibration: " + std::to_string(points.size()) + " fiducials from " +
        std::to_string(images.size()) +
        " images; at least 6 from 2 images are needed (hold the probe over the phantom at "
        "more poses)");
  const double u0 = geometry.centre_column();
  // Scaled pixel coordinates (hundreds of pixels → order 1) keep the normal equations well conditioned.
  constexpr double kUnit = 100.0;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : points) mean += Eigen::Vector2d(p.pixel.x() - u0, p.pixel.y()) / kUnit;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix2d spread = Eigen::Matrix2d::Zero();
  for (const auto& p : points) {
    const Eigen::Vector2d d = Eigen::Vector2d(p.pixel.x() - u0, p.pixel.y()) / kUnit - mean;
    spread += d * d.transpose();
  }
  spread /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eigen(spread);
  // The smallest eigenvalue is the variance across the best line through the fiducials (in 100 px²):
  // below 0.01, a 10-pixel (≈ 1.2 mm) spread, s_u r₂ and s_v r₃ are not separable.
  if (eigen.eigenvalues()(0) < 1e-2)
    throw ImageCalibrationError(
        "image calibration: the fiducials lie (nearly) on one line in the image, which leaves the scales and "
        "the image's rotation undetermined; use poses that put the echoes at several depths and sides");
  // Linear step: q = x·(s_u r₂) + y·(s_v r₃) + t with x = (u − u₀)/100, y = v/100.
  Eigen::Matrix<double, 9, 9> normal = Eigen::Matrix<double, 9, 9>::Zero();
  Eigen::Matrix<double, 9, 1> rhs = Eigen::Matrix<double, 9, 1>::Zero();
  for (const auto& p : points) {
    Eigen::Matrix<double, 3, 9> a;
    const double x = (p.pixel.x() - u0) / kUnit, y = p.pixel.y() / kUnit;
    a << x * Eigen::Matrix3d::Identity(), y * Eigen::Matrix3d::Identity(), Eigen::Matrix3d::Identity();
    normal += a.transpose() * a;
    rhs += a.transpose() * p.in_probe;
  }
  const Eigen::Matrix<double, 9, 1> linear = normal.ldlt().solve(rhs);
  const Eigen::Vector3d column_u = linear.segment<3>(0) / kUnit, column_v = linear.segment<3>(3) / kUnit;
  ImageCalibration c;
  c.s_u = column_u.norm();
  c.s_v = column_v.norm();
  if (!(c.s_u > 1e-6) || !(c.s_v > 1e-6) || !linear.allFinite())
    throw ImageCalibrationError(
        "image calibration: the least-squares solution gives no pixel scale; the data "
        "do not fix the image plane");
  Eigen::Matrix3d r;
  r.col(1) = column_u / c.s_u;
  r.col(2) = column_v / c.s_v;
  r.col(0) = r.col(1).cross(r.col(2));
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d rotation = svd.matrixU() * svd.matrixV().transpose();
  if (rotation.determinant() < 0.0) {
    Eigen::Matrix3d u = svd.matrixU();
    u.col(2) *= -1.0;
    rotation = u * svd.matrixV().transpose();
  }
  Eigen::Vector3d t = linear.segment<3>(6);
  // Gauss–Newton on (rotation increment ω, t, s_u, s_v): residual R·[0, s_u x, s_v y] + t − q.
  int iterations = 0;
  for (; iterations < 30; ++iterations) {
    Eigen::Matrix<double, 8, 8> jtj = Eigen::Matrix<double, 8, 8>::Zero();
    Eigen::Matrix<double, 8, 1> jtr = Eigen::Matrix<double, 8, 1>::Zero();
    for (const auto& p : points) {
      const double x = p.pixel.x() - u0, y = p.pixel.y();
      const Eigen::Vector3d local(0.0, c.s_u * x, c.s_v * y);
      const Eigen::Vector3d rotated = rotation * local;
      const Eigen::Vector3d residual = rotated + t - p.in_probe;
      Eigen::Matrix<double, 3, 8> j;
      j.block<3, 3>(0, 0) = -skew(rotated);
      j.block<3, 3>(0, 3) = Eigen::Matrix3d::Identity();
      j.col(6) = rotation.col(1) * x;
      j.col(7) = rotation.col(2) * y;
      jtj += j.transpose() * j;
      jtr += j.transpose() * residual;
    }
    const Eigen::Matrix<double, 8, 1> step = -jtj.ldlt().solve(jtr);
    if (!step.allFinite())
      throw ImageCalibrationError(
          "image calibration: the refinement is singular; the poses do not fix H_I^U");
    rotation = exp_rotation(step.head<3>()) * rotation;
    t += step.segment<3>(3);
    c.s_u += step(6);
    c.s_v += step(7);
    if (step.norm() < 1e-10) break;
  }
  if (!(c.s_u > 0.0) || !(c.s_v > 0.0))
    throw ImageCalibrationError("image calibration: the fit gives a pixel scale that is not positive (s_u " +
                                number(c.s_u) + ", s_v " + number(c.s_v) + " mm)");
  c.image_in_probe = Eigen::Isometry3d::Identity();
  c.image_in_probe.linear() = rotation;
  c.image_in_probe.translation() = t;
  ImageCalibrationFit fit;
  fit.calibration = c;
  const PointReconstructionError e = point_reconstruction_error(c, points, geometry);
  double squares = 0.0;
  for (const auto& p : points) squares += (c.in_probe(geometry, p.pixel) - p.in_probe).squaredNorm();
  fit.rms_mm = std::sqrt(squares / static_cast<double>(points.size()));
  fit.max_mm = e.max_mm;
  fit.points = static_cast<int>(points.size());
  fit.images = static_cast<int>(images.size());
  fit.iterations = iterations + 1;
  return fit;
}

PointReconstructionError point_reconstruction_error(const ImageCalibration& calibration,
                                                    const std::vector<PixelCorrespondence>& points,
                                                    const BModeGeometry& geometry) {
  PointReconstructionError e;
  for (const auto& p : points) {
    const double d = (calibration.in_probe(geometry, p.pixel) - p.in_probe).norm();
    e.mean_mm += d;
    e.max_mm = std::max(e.max_mm, d);
  }
  e.points = static_cast<int>(points.size());
  if (!points.empty()) e.mean_mm /= static_cast<double>(points.size());
  return e;
}

std::vector<Eigen::Isometry3d> n_wire_calibration_poses(const Eigen::Isometry3d& phantom_pose, int count) {
  if (count < 4)
    throw UltrasoundSetupError("N-wire calibration: at least 4 probe poses are needed, got " +
                               std::to_string(count));
  // A Kronecker sequence (fractional parts of k·α with irrational α per axis): deterministic and evenly
  // spread over the six offsets, with no two poses alike.
  const std::array<double, 6> alpha{0.6180339887, 0.4142135624, 0.7320508076,
                                    0.2360679775, 0.6457513111, 0.1622776602};
  std::vector<Eigen::Isometry3d> poses;
  const double degree = kPi / 180.0;
  for (int k = 0; k < count; ++k) {
    std::array<double, 6> f{};
    for (std::size_t d = 0; d < 6; ++d) {
      const double v = (k + 1) * alpha[d];
      f[d] = 2.0 * (v - std::floor(v)) - 1.0;  // in [−1, 1)
    }
    Eigen::Isometry3d offset = Eigen::Isometry3d::Identity();
    offset.translation() = Eigen::Vector3d(5.0 * f[0], 1.5 * f[1], -0.5 + 1.5 * f[2]);
    offset.linear() = (Eigen::AngleAxisd(3.0 * degree * f[3], Eigen::Vector3d::UnitX()) *
                       Eigen::AngleAxisd(5.0 * degree * f[4], Eigen::Vector3d::UnitY()) *
                       Eigen::AngleAxisd(8.0 * degree * f[5], Eigen::Vector3d::UnitZ()))
                          .toRotationMatrix();
    poses.push_back(phantom_pose * offset);
  }
  return poses;
}

ImageCalibrationRun run_n_wire_calibration(const SimulatedNWireScanner& scanner,
                                           const Eigen::Isometry3d& phantom_pose,
                                           const std::vector<CalibrationShot>& shots,
                                           const ImageCalibration& nominal, std::uint64_t seed,
                                           const std::function<bool(int, int)>& progress) {
  nominal.validate();
  if (!is_rigid(phantom_pose))
    throw ImageCalibrationError("N-wire calibration: the phantom's pose is not rigid");
  const BModeGeometry& g = scanner.geometry();
  const Eigen::Isometry3d to_phantom = phantom_pose.inverse();
  ImageCalibrationRun run;
  std::vector<PixelCorrespondence> fit_points, check_points;
  // 2 mm of nominal error (offset, tilt and scale at 35 mm depth) fits well inside 3 mm.
  const double tolerance_px = 3.0 / std::min(nominal.s_u, nominal.s_v);
  for (std::size_t k = 0; k < shots.size(); ++k) {
    const CalibrationShot& shot = shots[k];
    if (!is_rigid(shot.measured) || !is_rigid(shot.simulated_true))
      throw ImageCalibrationError("N-wire calibration: probe pose " + std::to_string(k + 1) +
                                  " is not rigid");
    const BModeImage image = scanner.render(to_phantom * shot.simulated_true, seed * 1'000'003ULL + k);
    ++run.images;
    const std::vector<EchoSpot> spots = detect_echo_spots(image);
    const std::vector<NWireCrossing> predicted =
        n_wire_crossings(scanner.phantom(), to_phantom * shot.measured * nominal.image_in_probe,
                         nominal.s_u * g.columns, nominal.s_v * g.rows);
    std::string why;
    const std::vector<NWireObservation> seen =
        match_n_wires(spots, scanner.phantom(), predicted, g, nominal, tolerance_px, &why);
    if (progress && !progress(static_cast<int>(k + 1), static_cast<int>(shots.size())))
      throw ImageCalibrationError("N-wire calibration: stopped after " + std::to_string(k + 1) + " of " +
                                  std::to_string(shots.size()) + " images");
    if (!why.empty()) run.notes.push_back("image " + std::to_string(k + 1) + ": " + why);
    if (seen.empty()) continue;
    ++run.images_used;
    const bool held_out = k % 4 == 3;
    run.images_validation += held_out ? 1 : 0;
    const Eigen::Isometry3d probe_T_phantom = shot.measured.inverse() * phantom_pose;
    for (const auto& o : seen) {
      PixelCorrespondence c;
      c.pixel = o.pixels[1];
      c.in_probe = probe_T_phantom * o.middle_in_phantom;
      c.image = static_cast<int>(k);
      (held_out ? check_points : fit_points).push_back(c);
    }
  }
  run.fit = solve_image_calibration(fit_points, g);
  run.validation = point_reconstruction_error(run.fit.calibration, check_points, g);
  return run;
}

}  // namespace tendril::ultrasound
