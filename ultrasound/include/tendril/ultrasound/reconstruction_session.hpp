// One ultrasound (US) reconstruction session of Heunis et al. 2021 (issue 17): the model behind the us_arm's
// imaging and reconstruction topics, kept free of threads and I/O (the caller — a worker thread,
// never the control thread — owns it and feeds it one probe sample at a time).
//
// Per probe sample in contact: the SIMULATED B-mode slice of the limb's artery at the probe pose, the
// ellipse EKF (Appendix B) seeded by the planned centroid of the current via-point, and Eq. 5 into
// the tissue frame {P} (the limb, which moves: Λ_P = (H_P^G)⁻¹ · H_U^G · H_I^U · Λ_US). At an
// acquisition (the sweep's gate open) the slice is stored, one per via-point, and the artery mesh is
// re-lofted from the stored contours in via-point order. Separately, the catheter lying in the artery
// is read by a SIMULATED FBG interrogator (32 gratings), reconstructed, mapped by Eq. 2 into the world
// and into {P}, checked against the mesh for contacts (under 1.25 mm from the wall) and for curvature
// over the fibre's limit.
//
// SIMULATED measurement errors: the sample's probe pose is the arm's forward kinematics, and the limb
// comes as tracked (world_T_limb: the simulated tracker's sample-and-hold and latency) and, optionally,
// as the simulation's truth (world_T_limb_true). The scanner images at the TRUE poses — the probe's
// forward kinematics ⊕ the robot's error, the true limb — and the slice is mapped through the measured
// ones — the forward kinematics, the tracked limb ⊕ the tracker's noise — with the error budget of
// Heunis et al. 2021, §4.3 (robot 0.3 ± 0.1 mm, tracker 0.56 ± 0.08 mm, 0.02° per axis; a new draw per image,
// as the digital twin does). Set `errors.enabled = false` to add no noise (the latency, if any, stays).
//
// Bad input (a pose that is not finite or not rigid, an image that is empty or of another geometry)
// is refused with a status and a sentence; nothing stored before is changed.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "tendril/teleop/vessel_centerline.hpp"
#include "tendril/teleop/vessel_mesh.hpp"
#include "tendril/ultrasound/artery_model.hpp"
#include "tendril/ultrasound/bmode_image.hpp"
#include "tendril/ultrasound/ellipse_ekf.hpp"
#include "tendril/ultrasound/fbg_shape.hpp"
#include "tendril/ultrasound/preoperative_plan.hpp"
#include "tendril/ultrasound/probe_calibration.hpp"
#include "tendril/ultrasound/simulated_bmode.hpp"

namespace tendril::ultrasound {

// One probe sample, in the world frame {G} (mm): the library's own copy of the arm's probe state.
struct ProbeSample {
  double t = 0.0;                                                   // s
  Eigen::Isometry3d world_T_probe = Eigen::Isometry3d::Identity();  // H_U^G
  Eigen::Isometry3d world_T_limb = Eigen::Isometry3d::Identity();   // H_P^G as tracked (the tissue frame)
  // SIMULATED: the limb's true pose, where the scanner images it; without it, world_T_limb.
  std::optional<Eigen::Isometry3d> world_T_limb_true;
  bool in_contact = false;
  bool acquiring = false;  // the sweep's gate is open: store this slice
  int via_point = -1;      // index into the plan; −1 when none
};

// The sweep plan as the scene shows it and the segmentation seeds from (all in {P}).
struct SweepPlan {
  std::vector<Eigen::Vector3d> surface;    // the skin cloud Algorithm 2 ran on
  std::vector<Eigen::Vector3d> centroids;  // Ψ_CT: Algorithm 1's centroids (the CT centerline)
  std::vector<ProbeViaPoint> via_points;   // Algorithm 2's probe poses, one per centroid
};

struct SimulatedMeasurementErrors {
  bool enabled = true;
  double robot_mm = 0.3, robot_sd_mm = 0.1;        // Heunis et al. 2021, §4.3
  double tracker_mm = 0.56, tracker_sd_mm = 0.08;  // Heunis et al. 2021, §4.3
  double angle_sd_rad =
      0.02 * 3.14159265358979323846 / 180.0;  // per axis [our choice; the article is silent]
  std::uint64_t seed = 1;
};

struct ReconstructionSessionConfig {
  teleop::CenterlinePolyline artery;  // the SIMULATED phantom's artery in {P} (what the scanner images)
  BModeGeometry geometry{};
  SimulatedBModeParameters bmode{};
  EllipseEkfParameters ekf{};
  // H_I^U: the calibrated image-to-probe transform (the image plane 0.5 mm below the probe face).
  Eigen::Isometry3d image_in_probe = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.5));
  // The calibrated pixel scales s_u, s_v (mm per pixel) the slices are mapped with; 0: the geometry's
  // pixel size. The segmentation runs in the geometry's pixels either way.
  double image_scale_u = 0.0, image_scale_v = 0.0;
  // SIMULATED: where the scanner truly images (H_I^U and scales), so that a calibration error shows in
  // the reconstruction; none: exactly where the calibration above says.
  std::optional<ImageCalibration> simulated_true_image;
  // The catheter's centreline in {P}, a dense polyline (≤ 1 mm segments) from the fibre's first
  // grating on, at least the fibre's length; empty: no catheter.
  std::vector<Eigen::Vector3d> catheter_path;
  MulticoreFiber fiber{};
  Eigen::Isometry3d fiber_in_base = Eigen::Isometry3d::Identity();  // H_F^C (calibrated)
  // SIMULATED: where the fibre truly sits in the catheter base; none: exactly at fiber_in_base.
  std::optional<Eigen::Isometry3d> simulated_true_fiber_in_base;
  double fbg_noise_pm = 1.2;
  CatheterContactParameters contact{};
  SimulatedMeasurementErrors errors{};
};

enum class SessionStatus : std::uint8_t {
  ok,
  no_contact,     // the probe is off the skin: no image
  invalid_pose,   // a pose is not finite or its rotation not orthonormal
  invalid_image,  // empty, of another geometry, or with a pixel that is not finite
  no_vessel,      // the slice was imaged but the segmentation found no contour
};
const char* to_string(SessionStatus status) noexcept;

struct SessionOutcome {
  SessionStatus status = SessionStatus::ok;
  std::string message;        // for a person; empty when ok
  bool stored_slice = false;  // this sample added a slice (and re-lofted the mesh)
  bool ok() const noexcept { return status == SessionStatus::ok; }
};

// The newest image and its segmentation.
struct SessionFrame {
  double t = 0.0;
  BModeImage image;
  SliceSegmentation segmentation;                                    // in {I}
  Eigen::Isometry3d tissue_T_image = Eigen::Isometry3d::Identity();  // measured chain (Eq. 5)
  Eigen::Isometry3d world_T_image = Eigen::Isometry3d::Identity();   // H_U^G · H_I^U (measured)
  Eigen::Isometry3d simulated_true_tissue_T_image = Eigen::Isometry3d::Identity();  // SIMULATED truth
  int via_point = -1;
};

struct StoredSlice {
  int via_point = 0;
  double t = 0.0;
  ReconstructedSlice slice;  // contour and centroid in {P}
  Eigen::Isometry3d tissue_T_image = Eigen::Isometry3d::Identity();
  LumenMask mask;                // the segmented lumen in image pixels
  double centroid_error = -1.0;  // ‖ψ − Ψ_CT,i‖ mm when the plan has that centroid, else −1
};

struct CatheterState {
  bool valid = false;
  double t = 0.0;
  std::vector<Eigen::Vector3d> world;                             // Φ_G (Eq. 2)
  std::vector<Eigen::Vector3d> tissue;                            // the same in {P} (measured limb pose)
  std::vector<Eigen::Vector3d> simulated_true_world;              // SIMULATED truth, to score Φ_G against
  std::vector<CatheterContact> contacts;                          // against the mesh, in {P}
  std::vector<double> wall_distance;                              // per grating (+∞ without a mesh)
  std::vector<int> over_curvature;                                // gratings with |κ| over the fibre's limit
  double max_curvature = 0.0;                                     // mm⁻¹
  Eigen::Isometry3d world_T_fbg = Eigen::Isometry3d::Identity();  // {F} in {G} (measured)
};

class UltrasoundReconstructionSession {
 public:
  // Throws UltrasoundSetupError for an artery the scanner cannot image, EKF parameters out of range,
  // an image-to-probe or fibre transform that is not rigid, or a catheter path shorter than the fibre.
  explicit UltrasoundReconstructionSession(ReconstructionSessionConfig config);

  // Replaces the plan (seeds and scene). Throws PlanningInputError for non-finite points or via-points
  // and centroids of different counts. The stored slices stay (they are in {P} already).
  void set_plan(SweepPlan plan);
  // The checks of set_plan() alone, for a caller on another thread than the session's.
  static void check_plan(const SweepPlan& plan);
  const SweepPlan& plan() const noexcept { return plan_; }

  // One probe sample: renders the SIMULATED slice at the sample's poses, segments and maps it, and on
  // an acquisition stores it. Not real-time (renders and allocates).
  SessionOutcome process(const ProbeSample& sample);
  // The same with an image from elsewhere (a scanner): no rendering.
  SessionOutcome process(const ProbeSample& sample, const BModeImage& image);

  // Reads the SIMULATED FBG interrogator for the catheter at the limb pose of `sample`, Eq. 2, contacts
  // and curvature. invalid_pose for a bad limb pose; ok and nothing without a catheter.
  SessionOutcome update_catheter(const ProbeSample& sample);

  // Forgets the slices, the mesh and the catheter (a new sweep).
  void reset();

  // A new image-to-probe calibration (H_I^U, s_u, s_v): images from now on are mapped with it; the
  // stored slices stay as they were mapped. Throws UltrasoundSetupError for an invalid one.
  void set_image_calibration(const ImageCalibration& calibration);
  // The calibration the slices are mapped with.
  ImageCalibration image_calibration() const noexcept;
  // A new H_F^C for Eq. 2 (the next catheter update uses it). Throws UltrasoundSetupError unless rigid.
  void set_fiber_in_base(const Eigen::Isometry3d& fiber_in_base);

  const std::optional<SessionFrame>& last_frame() const noexcept { return frame_; }
  const std::vector<StoredSlice>& slices() const noexcept { return slices_; }  // in via-point order
  const teleop::TriangleMesh& mesh() const noexcept { return mesh_; }          // {P}; empty below 2 slices
  const CatheterState& catheter() const noexcept { return catheter_; }
  const ReconstructionSessionConfig& config() const noexcept { return config_; }
  bool has_catheter() const noexcept { return interrogator_ != nullptr; }
  // Grows with every change of slices, mesh or plan (the scene's topic republishes on a change).
  std::uint64_t revision() const noexcept { return revision_; }

 private:
  Eigen::Isometry3d perturbed(const Eigen::Isometry3d& pose, double mean, double sd);
  double scale_u() const noexcept;  // calibrated s_u over the geometry's pixel size
  double scale_v() const noexcept;
  SliceSegmentation calibrated(const SliceSegmentation& segmentation) const;
  Eigen::Vector2d seed_for(const ProbeSample& sample, const Eigen::Isometry3d& tissue_T_image) const;
  SessionOutcome segment_and_store(const ProbeSample& sample, const BModeImage& image,
                                   const Eigen::Isometry3d& tissue_T_image,
                                   const Eigen::Isometry3d& tissue_T_image_true);

  ReconstructionSessionConfig config_;
  SimulatedBModeProbe scanner_;
  EllipseSliceSegmenter segmenter_;
  SweepPlan plan_;
  std::mt19937_64 engine_;
  std::uint64_t image_count_ = 0;
  std::optional<SessionFrame> frame_;
  std::vector<StoredSlice> slices_;
  teleop::TriangleMesh mesh_;
  std::uint64_t revision_ = 0;
  // Catheter (SIMULATED interrogator) and its reconstruction.
  FiberTruth catheter_truth_;
  std::unique_ptr<SimulatedFbgInterrogator> interrogator_;
  std::unique_ptr<FbgShapeReconstructor> reconstructor_;
  std::uint64_t fbg_sequence_ = 0;
  CatheterState catheter_;
};

// True when the isometry is finite and its rotation orthonormal with determinant +1 (within 1e-6).
bool is_rigid(const Eigen::Isometry3d& pose) noexcept;

}  // namespace tendril::ultrasound
