// Fibre Bragg grating (FBG) catheter shape (Heunis et al. 2021, §2.2 and §3.3): interrogator
// frames of Bragg wavelengths, a standard multicore shape reconstruction (our choice) (the paper
// used the FBGS software's own shape output), Eq. 2 into the global frame, and a SIMULATED interrogator.
//
// Reconstruction, per frame (our choice):
//   1. strain per core and grating: ε = (λ − λ_ref)/λ_ref / (1 − p_e), λ_ref from the straight
//      reference (mold channel I);
//   2. per grating, least squares over the four cores (centre + three outer at radius r_c, angles ψ_k):
//      rows [r_c sin ψ_k, −r_c cos ψ_k, 1] · [κ_x, κ_y, ε₀] = ε_k; the centre core's row is [0, 0, 1].
//      ε₀ takes temperature and axial strain (common mode), so they cancel;
//   3. κ(s) by a natural cubic spline through the gratings (no extrapolation: grating 1 is the base of
//      {F}, the last one the tip, so the 32 gratings span the sensed length);
//   4. integration from R(0) = I, p(0) = 0 in steps ≤ 0.5 mm: R ← R·exp([κ_mid]×Δs) (Rodrigues),
//      p ← p + R(s + Δs/2)·e_z·Δs; twist neglected (an untwisted fibre).
//   5. |κ| above 1/50 mm⁻¹ (the fibre's bend limit, §2.2) at a grating raises a curvature warning.
// The shape Φ_F (one point per grating, {F}: origin at grating 1, z along the fibre there) maps to the
// global frame by Eq. 2: Φ_G = H_C^G · H_F^C · Φ_F.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <random>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace tendril::ultrasound {

// Thrown by parse_fbg_frame for a frame that is not one (message names the field and the value).
class FbgFrameError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

struct MulticoreFiber {
  int gratings = 32;                      // f (§2.2)
  double grating_spacing = 270.0 / 31.0;  // mm: the 32 gratings span the 270 mm catheter (our choice)
  double core_radius = 0.035;             // r_c (mm) of the outer cores (~35 µm, a typical multicore fibre)
  std::array<double, 3> outer_core_angles{0.0, 2.0943951023931953, 4.1887902047863905};  // ψ_k (rad)
  double photoelastic = 0.22;                                                            // p_e of silica
  double max_curvature = 1.0 / 50.0;  // mm⁻¹: the fibre's 50 mm bend radius (§2.2)
  static constexpr int cores = 4;     // core 0 is the centre core, 1..3 the outer ones
  double length() const noexcept { return grating_spacing * (gratings - 1); }
  // Throws std::invalid_argument unless 2 ≤ gratings ≤ 1024 and the lengths are positive and finite.
  void validate() const;
};

// One interrogator frame: Bragg wavelengths (nm), grating-major: wavelengths[g · cores + k].
struct FbgFrame {
  std::uint64_t sequence = 0;
  int gratings = 0;
  int cores = 0;
  std::vector<double> wavelengths;
};

inline constexpr int kMaxFbgGratings = 1024;
inline constexpr int kMaxFbgCores = 16;

// The text frame of the interrogator link (one line):
//   FBG <sequence> <gratings> <cores> <λ₀,₀> <λ₀,₁> … <λ_{g−1},_{c−1}>
// fields separated by single spaces or tabs, wavelengths in nm, an optional trailing "\n" or "\r\n".
// Throws FbgFrameError naming what is wrong: another tag, a field that is not a number, counts outside
// 1..1024 gratings and 1..16 cores, a wavelength that is not finite or outside (0, 10000) nm, or more or
// fewer wavelengths than gratings × cores.
FbgFrame parse_fbg_frame(std::string_view text);
std::string format_fbg_frame(const FbgFrame& frame);

enum class FbgShapeStatus : std::uint8_t {
  ok,
  wrong_dimensions,  // the frame's gratings × cores do not match the fibre
  not_finite,        // a wavelength (or the reference) is not finite or not positive
};
const char* to_string(FbgShapeStatus status) noexcept;

struct FbgShape {
  FbgShapeStatus status = FbgShapeStatus::wrong_dimensions;
  std::uint64_t sequence = 0;
  std::vector<Eigen::Vector3d> points;     // Φ_F: one per grating, mm, {F}
  std::vector<Eigen::Vector2d> curvature;  // (κ_x, κ_y) per grating, mm⁻¹, fibre frame
  std::vector<unsigned char> over_limit;   // 1 where |κ| > max_curvature
  bool curvature_warning = false;          // any grating over the limit
  double max_curvature = 0.0;              // largest |κ| (mm⁻¹)
};

class FbgShapeReconstructor {
 public:
  // `reference` is the straight, unstrained frame (mold channel I). Throws std::invalid_argument for a
  // fibre that does not validate, a reference of other dimensions or with a wavelength that is not
  // positive and finite, or a step that is not in (0, grating_spacing].
  FbgShapeReconstructor(const MulticoreFiber& fiber, const FbgFrame& reference, double step = 0.5);

  // Allocation-free after construction; a bad frame gives status ≠ ok and leaves the points at the
  // last good shape's values.
  const FbgShape& reconstruct(const FbgFrame& frame) noexcept;
  const MulticoreFiber& fiber() const noexcept { return fiber_; }

 private:
  MulticoreFiber fiber_;
  std::vector<double> reference_;
  Eigen::Matrix<double, 3, 4> solver_;  // least-squares pseudo-inverse of the core geometry
  int substeps_ = 1;
  std::vector<Eigen::Vector2d> second_, forward_;  // spline: κ'' per grating, forward-sweep values
  std::vector<double> pivot_, upper_;              // Thomas factors
  FbgShape shape_;
};

// Eq. 2: Φ_G = H_C^G · H_F^C · Φ_F into `out` (resized to in.size()).
void fbg_to_global(const Eigen::Isometry3d& catheter_base_in_global, const Eigen::Isometry3d& fiber_in_base,
                   const std::vector<Eigen::Vector3d>& in, std::vector<Eigen::Vector3d>& out);

// Mold calibration of H_F^C (our recipe): the catheter lies in a curved
// mold channel (channel II) whose centerline is known in the catheter base frame {C} (design
// coordinates through H_M^G, H_L^M and the tracked H_C^G), starting at grating 1 (the known
// base-to-sensor-1 offset). sample_at_arc_lengths() takes the channel's points at the gratings' arc
// lengths from its dense centerline; calibrate_fiber_in_base() fits the FBG shape Φ_F to them by
// Kabsch. A straight channel cannot fix the roll about the fibre (any roll fits), so the channel must
// bend; the fit refuses samples that are (nearly) collinear.
struct FiberCalibration {
  Eigen::Isometry3d fiber_in_base = Eigen::Isometry3d::Identity();  // H_F^C
  double rms = 0.0;                                                 // mm over the gratings
  double max = 0.0;                                                 // mm
};
// Points every `spacing` mm of arc along a polyline from its first point, `count` of them. Throws
// std::invalid_argument when the polyline is too short or not finite, or the arguments are not positive.
std::vector<Eigen::Vector3d> sample_at_arc_lengths(const std::vector<Eigen::Vector3d>& polyline,
                                                   double spacing, int count);
// Throws std::invalid_argument when there are fewer than 3 pairs, the sizes differ, a point is not
// finite, or the channel samples are (nearly) collinear.
FiberCalibration calibrate_fiber_in_base(const std::vector<Eigen::Vector3d>& shape_in_fiber,
                                         const std::vector<Eigen::Vector3d>& channel_at_gratings);

// Validation on another channel (channel III): each point's distance to the channel's centerline
// polyline (same frame), mean, standard deviation and max (the paper: 0.82 ± 0.21 mm, max 1.52 mm).
struct ChannelValidation {
  double mean = 0.0;
  double standard_deviation = 0.0;
  double max = 0.0;
};
ChannelValidation validate_on_channel(const std::vector<Eigen::Vector3d>& points,
                                      const std::vector<Eigen::Vector3d>& channel);

// The fibre's truth for a shape given as a dense polyline (first point = grating 1): the pose of {F}
// in the polyline's frame (z along the first segment), each grating's position in {F} and its
// curvature in the fibre's (parallel-transported, untwisted) frame.
struct FiberTruth {
  Eigen::Isometry3d fiber_pose = Eigen::Isometry3d::Identity();
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> curvature;
};
// Throws std::invalid_argument when the polyline is shorter than the fibre, has non-finite or repeated
// points, or segments longer than 1 mm (too coarse for curvature).
FiberTruth fiber_truth(const MulticoreFiber& fiber, const std::vector<Eigen::Vector3d>& polyline);

// SIMULATED interrogator: Bragg wavelengths of the fibre laid along a polyline, with Gaussian
// wavelength noise (≈ 1 µε, 1.2 pm at 1550 nm) and a uniform temperature
// change (thermo-optic 6.7e-6 /K, common to all cores). Reference wavelengths 1510 + 1.25·g nm.
class SimulatedFbgInterrogator {
 public:
  SimulatedFbgInterrogator(const MulticoreFiber& fiber, double noise_pm = 1.2, std::uint64_t seed = 1);
  // The noise-free straight frame, the reference the interrogator software stores on channel I.
  FbgFrame reference() const;
  FbgFrame measure(const std::vector<Eigen::Vector3d>& polyline, double temperature_change,
                   std::uint64_t sequence);
  FbgFrame measure(const FiberTruth& truth, double temperature_change, std::uint64_t sequence);

 private:
  MulticoreFiber fiber_;
  double noise_pm_;
  std::mt19937_64 engine_;
};

}  // namespace tendril::ultrasound
