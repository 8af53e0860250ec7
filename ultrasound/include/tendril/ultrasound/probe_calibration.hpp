// Image-to-probe calibration of the ultrasound (US) probe (Heunis et al. 2021, §2.3): the transform
// H_I^U of the image frame {I} in the probe frame {U} and the pixel scales s_u, s_v (mm per pixel), so
// that pixel (u, v) lies at H_I^U · [0, s_u (u − u₀), s_v v] in {U} (u₀ the centre column; an offset of
// the true origin is part of H_I^U).
//
// The calibrator is an N-wire phantom [our choice; the article's "custom-designed calibrator object" is
// in a supplement we do not have, and it names N-wire and cross-wire]: per layer, two parallel wires and
// a diagonal between them, all along the phantom's x axis. The image plane cuts a layer's three wires in
// three collinear echoes A, M, B, and the ratio |AM| / |AB| — unchanged by any affine map, hence by
// unknown pixel scales — places M on the diagonal in 3D (Comeau et al. 2000; Chen et al. 2009). So
// every image gives one known 3D point per layer without aligning the plane on anything, whereas a
// cross-wire needs the plane driven exactly through the crossing, pose after pose.
//
// What is here:
//   * NWirePhantom — the wires in the phantom frame {N} (z down into the water bath, the probe's depth
//     direction when it sits on top);
//   * SimulatedNWireScanner — SIMULATED B-mode images of the phantom: water (dark, speckled), each wire
//     a bright echo blurred by the point-spread function, in the image geometry's pixels but through the
//     scanner's TRUE calibration (which a test or the robot file sets off the nominal one);
//   * detect_echo_spots() — bright compact blobs, sub-pixel (blur, threshold, 8-connected components,
//     intensity-weighted centroid);
//   * match_n_wires() — each layer's three echoes picked by where the nominal calibration predicts them,
//     and M's 3D point from the ratio;
//   * solve_image_calibration() — linear least squares for [s_u r₂, s_v r₃, t] (9 unknowns, 3 rows per
//     point), then Gauss–Newton on the 8 parameters (rotation, translation, two scales); refuses
//     degenerate data (too few points, points on one line in the image, images that all look alike)
//     with a sentence;
//   * run_n_wire_calibration() — the whole SIMULATED routine over a list of probe poses: render, detect,
//     match, fit on three images in four, and validate on the fourth (point-reconstruction error on
//     images not used in the fit).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "tendril/ultrasound/bmode_image.hpp"

namespace tendril::ultrasound {

// Data that cannot give a calibration (too few points, degenerate poses); the message is for a person.
class ImageCalibrationError : public UltrasoundSetupError {
 public:
  using UltrasoundSetupError::UltrasoundSetupError;
};

// H_I^U and the pixel scales. Pixel (u, v) → {I}: [0, s_u (u − u₀), s_v v], u₀ = geometry.centre_column().
struct ImageCalibration {
  Eigen::Isometry3d image_in_probe = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.5));
  double s_u = 0.125;  // mm per pixel along a row (lateral)
  double s_v = 0.125;  // mm per pixel down a column (depth)

  // The nominal calibration of a geometry: the plane 0.5 mm below the face, the geometry's pixel size.
  static ImageCalibration nominal(const BModeGeometry& geometry);
  Eigen::Vector3d in_image(const BModeGeometry& geometry, const Eigen::Vector2d& pixel) const noexcept {
    return {0.0, s_u * (pixel.x() - geometry.centre_column()), s_v * pixel.y()};
  }
  Eigen::Vector3d in_probe(const BModeGeometry& geometry, const Eigen::Vector2d& pixel) const noexcept {
    return image_in_probe * in_image(geometry, pixel);
  }
  // Throws UltrasoundSetupError unless H_I^U is rigid and the scales are in (0, 10] mm.
  void validate() const;
};

// One layer of an N-wire phantom, in {N}: wires W1 at y = y_first and W3 at y = y_last, both along x at
// depth z; the diagonal W2 from (x_start, y_first) to (x_end, y_last).
struct NWireLayer {
  double depth = 20.0;  // z (mm)
  double y_first = -10.0, y_last = 0.0;
  double x_start = -10.0, x_end = 10.0;
};

struct NWirePhantom {
  // Three layers at 15, 25 and 35 mm (about the scanner's 20–40 mm focus, inside its 50 mm depth), the
  // parallel wires 30 mm apart across the 40 mm image, the diagonals over 30 mm along the wires and
  // alternating in direction: as the probe moves along the wires the three M echoes move across the
  // image independently of their depth (the scales and the in-plane rotation stay separable), and M
  // stays ≥ 7 mm from A and B for the poses below (the plane cuts the layers within ±8 mm of the middle).
  std::vector<NWireLayer> layers{
      {15.0, -15.0, 15.0, -15.0, 15.0}, {25.0, -15.0, 15.0, 15.0, -15.0}, {35.0, -15.0, 15.0, -15.0, 15.0}};
  double wire_half_length = 25.0;  // the wires run over x ∈ [−25, 25] mm
  // A wire's three segments (start, end) in {N}: 0 = W1, 1 = W2 (diagonal), 2 = W3.
  std::array<std::array<Eigen::Vector3d, 2>, 3> wires(const NWireLayer& layer) const;
  // Throws UltrasoundSetupError for no layers, non-finite values, or wires closer than 4 mm apart.
  void validate() const;
};

// Where an image plane cuts one layer: the three crossings in {I} (y, z mm) and M in {N}.
struct NWireCrossing {
  int layer = 0;
  std::array<Eigen::Vector2d, 3> in_image{};  // A (W1), M (W2), B (W3)
  Eigen::Vector3d middle_in_phantom = Eigen::Vector3d::Zero();
};
// The layers whose three wires the plane `phantom_T_image` ({I} in {N}) cuts inside the image (a layer
// whose crossing lies outside a wire's length or outside the field of view is left out).
std::vector<NWireCrossing> n_wire_crossings(const NWirePhantom& phantom,
                                            const Eigen::Isometry3d& phantom_T_image, double field_width_mm,
                                            double field_depth_mm);

struct SimulatedNWireParameters {
  double water_echo = 0.06;      // mean echo of the water bath (nearly anechoic)
  double wire_echo = 0.9;        // peak echo of a wire
  double lateral_psf_mm = 0.45;  // σ of the point-spread function along the array
  double axial_psf_mm = 0.25;    // σ along the beam (axial resolution beats lateral)
  double noise_sigma = 0.03;     // additive Gaussian (of the [0, 1] scale)
  double wire_speckle = 0.25;    // fraction of a wire's echo that is speckled (the rest is specular)
};

// SIMULATED B-mode scanner looking at the phantom. Images come out in `geometry`'s pixels; the echoes sit
// where the TRUE calibration `truth` puts them. Deterministic for a seed (its own Box–Muller, as in
// simulated_bmode.hpp).
class SimulatedNWireScanner {
 public:
  // Throws UltrasoundSetupError for an invalid geometry, phantom, calibration or parameters.
  SimulatedNWireScanner(NWirePhantom phantom, const BModeGeometry& geometry, const ImageCalibration& truth,
                        const SimulatedNWireParameters& parameters = {});
  const NWirePhantom& phantom() const noexcept { return phantom_; }
  const BModeGeometry& geometry() const noexcept { return geometry_; }
  const ImageCalibration& truth() const noexcept { return truth_; }
  // `phantom_T_probe`: the TRUE probe pose {U} in {N}.
  BModeImage render(const Eigen::Isometry3d& phantom_T_probe, std::uint64_t seed) const;
  // The true crossings (in TRUE {I}) for the same pose.
  std::vector<NWireCrossing> crossings(const Eigen::Isometry3d& phantom_T_probe) const;

 private:
  NWirePhantom phantom_;
  BModeGeometry geometry_;
  ImageCalibration truth_;
  SimulatedNWireParameters parameters_;
};

struct EchoSpot {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // sub-pixel (column, row) of the centroid
  double peak = 0.0;                                // brightest blurred value
  int area = 0;                                     // pixels over the threshold
};
struct EchoSpotParameters {
  double blur_sigma_px = 1.5;  // speckle averaged before thresholding
  double threshold = 0.3;      // of the blurred [0, 1] intensity
  int min_area = 6;            // fewer pixels: a speckle peak
  int max_area = 2000;         // more: not a wire (a wall, a reverberation)
};
// The spots, brightest first. Throws UltrasoundSetupError for an image whose pixels do not match its
// geometry or parameters out of range.
std::vector<EchoSpot> detect_echo_spots(const BModeImage& image, const EchoSpotParameters& parameters = {});

// A layer seen in one image: the three echoes (pixels) and M's point in {N}.
struct NWireObservation {
  int layer = 0;
  std::array<Eigen::Vector2d, 3> pixels{};
  Eigen::Vector3d middle_in_phantom = Eigen::Vector3d::Zero();
};
// Pairs each predicted crossing (from the nominal calibration at the measured pose, in pixels of the
// nominal calibration) with the nearest spot within `tolerance_px`; a layer counts only when all three
// are found, distinct, and nearly collinear. `why` (if given) receives a sentence for layers left out.
std::vector<NWireObservation> match_n_wires(const std::vector<EchoSpot>& spots, const NWirePhantom& phantom,
                                            const std::vector<NWireCrossing>& predicted,
                                            const BModeGeometry& geometry, const ImageCalibration& nominal,
                                            double tolerance_px, std::string* why = nullptr);

// A fiducial's pixel and its point in {U} (the phantom point through the measured probe pose).
struct PixelCorrespondence {
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  Eigen::Vector3d in_probe = Eigen::Vector3d::Zero();
  int image = 0;  // which image it came from (the distinct-images check)
};

struct ImageCalibrationFit {
  ImageCalibration calibration;
  double rms_mm = 0.0;  // of the fit's residuals (in {U})
  double max_mm = 0.0;
  int points = 0;
  int images = 0;
  int iterations = 0;  // Gauss–Newton
};
// Least squares for H_I^U, s_u, s_v. Throws ImageCalibrationError for fewer than 6 points from at least
// 2 images, non-finite data, points that (nearly) lie on one line in the image or give an
// ill-conditioned system, or a fit whose scales come out non-positive.
ImageCalibrationFit solve_image_calibration(const std::vector<PixelCorrespondence>& points,
                                            const BModeGeometry& geometry);

struct PointReconstructionError {
  double mean_mm = 0.0, max_mm = 0.0;
  int points = 0;
};
// Distance between each pixel mapped by `calibration` and its point in {U}.
PointReconstructionError point_reconstruction_error(const ImageCalibration& calibration,
                                                    const std::vector<PixelCorrespondence>& points,
                                                    const BModeGeometry& geometry);

// One probe pose of the routine: where the arm says the probe is (forward kinematics) and where it
// truly is (SIMULATED: the kinematics ⊕ the robot's positioning error), both {U} in the frame the
// phantom's pose is given in.
struct CalibrationShot {
  Eigen::Isometry3d measured = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d simulated_true = Eigen::Isometry3d::Identity();
};

// Probe poses over a phantom at `phantom_pose` ({N} in the reference frame), `count` of them: the probe
// on the phantom's top, its image plane across the wires, shifted along the wires (±5 mm), across them
// (±1.5 mm) and in depth (−2..+1 mm), turned ±3° in the image plane, ±5° about the lateral axis and ±8°
// about the beam — spread so that M runs
// along each diagonal and the echoes cover the image. Deterministic. Throws UltrasoundSetupError for count
// < 4.
std::vector<Eigen::Isometry3d> n_wire_calibration_poses(const Eigen::Isometry3d& phantom_pose, int count);

struct ImageCalibrationRun {
  ImageCalibrationFit fit;
  PointReconstructionError validation;  // on the images held out of the fit (every 4th)
  int images = 0;                       // rendered
  int images_used = 0;                  // with at least one layer
  int images_validation = 0;
  std::vector<std::string> notes;  // per image left out, a sentence
};
// The SIMULATED routine: at each shot, render the phantom at the true pose, detect and match with the
// nominal calibration at the measured pose, fit on the images k with k % 4 ≠ 3 and validate on the
// others. `progress` (optional) is called after each image with (images done, images) and stops the
// routine when it returns false. Throws ImageCalibrationError when the fit cannot be made (with the
// reason) or the routine was stopped.
ImageCalibrationRun run_n_wire_calibration(const SimulatedNWireScanner& scanner,
                                           const Eigen::Isometry3d& phantom_pose,
                                           const std::vector<CalibrationShot>& shots,
                                           const ImageCalibration& nominal, std::uint64_t seed = 1,
                                           const std::function<bool(int, int)>& progress = {});

}  // namespace tendril::ultrasound
