// UltrasoundReconstructionSession (issue 17, imaging part): a simulated set-up like that of Heunis et al.
// 2021, §4, driven through the session as the us_arm's imaging worker drives it — a stream of probe samples
// (probe and limb poses, contact, the gate's acquisition flag, the via-point) — instead of calling the
// algorithms one by one. The phantom, plan and probe motion are those of digital_twin_test.cpp (copied, not
// shared, so that either test can change its scenario alone); the session adds the §4.3 measurement
// errors itself. Expectations are the article's reported numbers (§4.2).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <vector>

#include "tendril/teleop/task_space_velocity.hpp"
#include "tendril/ultrasound/reconstruction_session.hpp"

namespace {

using namespace tendril::ultrasound;
using Eigen::Isometry3d;
using Eigen::Vector3d;
namespace teleop = tendril::teleop;

constexpr double kPi = 3.14159265358979323846;

Vector3d vessel_centre(double x) {
  const double v = x / 125.0;
  return {x, -30.0 + 3.0 * v * v - 2.0 * v * v * v * v, 4.0 * v - 6.0 * v * v + 3.0 * v * v * v * v};
}

teleop::CenterlinePolyline vessel() {
  teleop::CenterlinePolyline line;
  for (double x = -30.0; x <= 160.0; x += 0.5) {
    line.points.push_back(vessel_centre(x));
    line.radii.push_back(5.0);
  }
  return line;
}

double skin_height(double x, double z) {
  return -60.0 + std::sqrt(60.0 * 60.0 - z * z) + 1.0 * std::sin(x / 15.0) * std::cos(z / 10.0);
}

Isometry3d pose(const Eigen::Matrix3d& r, const Vector3d& t) {
  Isometry3d p = Isometry3d::Identity();
  p.linear() = r;
  p.translation() = t;
  return p;
}

Eigen::Matrix3d rotation(double angle, const Vector3d& axis) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

struct LimbMotion {
  double amplitude = 0.0;
  double period = 30.0;
  Isometry3d at(double t) const {
    const double w = 2.0 * kPi / period;
    auto fourier = [&](double a1, double b1, double a2, double b2) {
      return amplitude * (a1 * std::cos(w * t) + b1 * std::sin(w * t) + a2 * std::cos(2 * w * t) +
                          b2 * std::sin(2 * w * t));
    };
    const double y = fourier(3.5, 1.5, 0.8, 0.6), z = fourier(-1.0, 3.8, 0.5, -0.9);
    const double roll = fourier(1.5, 1.8, 0.3, -0.4) * kPi / 180.0;
    return pose(rotation(roll, Vector3d::UnitX()), Vector3d(0.0, y, z));
  }
};

ProbeSample sample_at(double t, const Isometry3d& probe, const Isometry3d& limb, bool contact, bool acquiring,
                      int via_point) {
  ProbeSample s;
  s.t = t;
  s.world_T_probe = probe;
  s.world_T_limb = limb;
  s.in_contact = contact;
  s.acquiring = acquiring;
  s.via_point = via_point;
  return s;
}

const Isometry3d kTissueAtRest = pose(rotation(0.3, Vector3d::UnitY()), Vector3d(400.0, 100.0, -50.0));

// Our set-up (CT with noise, ICP on the stick, Algorithm 1, a noisy depth-camera surface,
// Algorithm 2), as in digital_twin_test.cpp.
SweepPlan make_plan() {
  std::mt19937 engine(2026);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> ct_noise(0.0, 0.2 / std::sqrt(3.0)),
      camera_noise(0.0, 0.5 / std::sqrt(3.0));
  const Isometry3d tissue_to_ct = pose(rotation(0.26, Vector3d(1, 2, 0.5)), Vector3d(12.0, -10.0, 12.0));
  std::vector<Vector3d> stick, stick_ct, wall_ct;
  for (double t = 0.0; t <= 80.0; t += 1.0) stick.emplace_back(t - 40.0, 20.0, 0.0);
  for (double t = 1.0; t <= 40.0; t += 1.0) stick.emplace_back(-40.0, 20.0 + t, 0.0);
  for (double t = 1.0; t <= 20.0; t += 1.0) stick.emplace_back(-40.0, 20.0, t);
  for (const auto& p : stick)
    stick_ct.push_back(tissue_to_ct * p + Vector3d(ct_noise(engine), ct_noise(engine), ct_noise(engine)));
  for (int i = 0; i < 5000; ++i) {
    const double x = -5.0 + 140.0 * unit(engine), a = 2.0 * kPi * unit(engine);
    wall_ct.push_back(tissue_to_ct * (vessel_centre(x) + 5.0 * Vector3d(0.0, std::cos(a), std::sin(a))) +
                      Vector3d(ct_noise(engine), ct_noise(engine), ct_noise(engine)));
  }
  const IcpResult registration = icp(stick, stick_ct);
  CentroidPlanOptions options;
  options.start_x = 0.0;
  options.end_x = 125.0;
  SweepPlan plan;
  plan.centroids = arterial_centroids(wall_ct, registration.transform, options);
  for (double x = -10.0; x <= 140.0; x += 1.0) {
    for (double z = -40.0; z <= 40.0; z += 1.0) {
      plan.surface.push_back(Vector3d(x, skin_height(x, z), z) +
                             Vector3d(camera_noise(engine), camera_noise(engine), camera_noise(engine)));
    }
  }
  plan.via_points = probe_via_points(plan.surface, plan.centroids);
  return plan;
}

const SweepPlan& plan() {
  static const SweepPlan p = make_plan();
  return p;
}

// The catheter of the twin, {P}: straight outside the tube, then along it, drifting to 0.5 mm from
// the wall from x = 100 mm to its tip.
double catheter_offset(double x) {
  if (x <= 40.0) return 0.0;
  const double u = std::min(1.0, (x - 40.0) / 60.0);
  return 4.5 * u * u * u * (10.0 - 15.0 * u + 6.0 * u * u);
}

std::vector<Vector3d> catheter_path() {
  const Vector3d entry = vessel_centre(0.0), tangent = (vessel_centre(0.1) - vessel_centre(0.0)).normalized();
  std::vector<Vector3d> catheter;
  for (int k = 1500; k >= 1; --k) catheter.push_back(entry - 0.1 * k * tangent);
  for (int k = 0; k <= 1300; ++k)
    catheter.push_back(vessel_centre(0.1 * k) - catheter_offset(0.1 * k) * Vector3d::UnitY());
  return catheter;
}

ReconstructionSessionConfig session_config(std::uint64_t seed) {
  ReconstructionSessionConfig c;
  c.artery = vessel();
  c.catheter_path = catheter_path();
  c.fiber_in_base = pose(rotation(0.2, Vector3d(1, 1, 0)), Vector3d(0.0, 0.0, 15.0));
  c.errors.seed = seed;
  return c;
}

struct SweepRun {
  std::unique_ptr<UltrasoundReconstructionSession> session;
  std::vector<double> dice_truth;  // per stored slice: segmented mask vs the SIMULATED true lumen
  int live_frames = 0;             // images between acquisitions
  double duration = 0.0;
};

// The probe tracks the plan under motion compensation (the twin's Cartesian integrator at 125 Hz) and
// the session gets a live sample once a second and the acquisition sample when the gate opens.
SweepRun run_sweep(const LimbMotion& motion, std::uint64_t seed) {
  SweepRun run;
  run.session = std::make_unique<UltrasoundReconstructionSession>(session_config(seed));
  run.session->set_plan(plan());
  const SimulatedBModeProbe truth_scanner(vessel(), BModeGeometry{});
  const teleop::TaskSpaceGains gains{};
  const double dt = 0.008;
  Isometry3d probe = kTissueAtRest * motion.at(0.0) * plan().via_points.front().pose();
  double t = 0.0;
  long step = 0;
  for (std::size_t i = 0; i < plan().via_points.size(); ++i) {
    double held = 0.0;
    const double start = t;
    for (;;) {
      const Isometry3d target = kTissueAtRest * motion.at(t) * plan().via_points[i].pose();
      const teleop::Twist twist = teleop::pose_tracking_twist(probe, target, gains, dt);
      const teleop::OrientationError e = teleop::orientation_error(probe.linear(), target.linear());
      const bool conditions =
          (target.translation() - probe.translation()).norm() < 0.5 && e.about_y < 0.01 && e.about_z < 0.01;
      held = conditions ? held + dt : 0.0;
      if (held >= 0.1) break;
      if (++step % 125 == 0) {
        const ProbeSample live =
            sample_at(t, probe, kTissueAtRest * motion.at(t), true, false, static_cast<int>(i));
        const SessionOutcome o = run.session->process(live);
        EXPECT_FALSE(o.stored_slice);
        ++run.live_frames;
      }
      probe.translation() += twist.head<3>() * dt;
      const Vector3d w = twist.tail<3>() * dt;
      if (w.norm() > 0.0) probe.linear() = rotation(w.norm(), w) * probe.linear();
      t += dt;
      if (t - start > 60.0) {
        ADD_FAILURE() << "the gate did not open within 60 s at via-point " << i;
        return run;
      }
    }
    const ProbeSample acquisition =
        sample_at(t, probe, kTissueAtRest * motion.at(t), true, true, static_cast<int>(i));
    const std::size_t before = run.session->slices().size();
    const SessionOutcome o = run.session->process(acquisition);
    EXPECT_TRUE(o.ok()) << o.message;
    EXPECT_TRUE(o.stored_slice) << "via-point " << i;
    EXPECT_EQ(run.session->slices().size(), before + 1);
    // A second sample with the gate still open at the same via-point adds nothing.
    EXPECT_FALSE(run.session->process(acquisition).stored_slice);
    const SessionFrame& f = *run.session->last_frame();
    const auto& stored =
        *std::find_if(run.session->slices().begin(), run.session->slices().end(),
                      [&](const StoredSlice& s) { return s.via_point == static_cast<int>(i); });
    run.dice_truth.push_back(
        dice_coefficient(stored.mask, truth_scanner.lumen_mask(f.simulated_true_tissue_T_image)));
  }
  run.duration = t;
  return run;
}

const SweepRun& stationary() {
  static const SweepRun r = run_sweep(LimbMotion{0.0}, 11);
  return r;
}
const SweepRun& moving() {
  static const SweepRun r = run_sweep(LimbMotion{1.0}, 12);
  return r;
}

struct Summary {
  double mean = 0.0, max = 0.0, dice_min = 1.0;
};

Summary summarise(const SweepRun& run) {
  Summary s;
  const auto& slices = run.session->slices();
  for (const auto& a : slices) {
    EXPECT_GE(a.centroid_error, 0.0);
    s.mean += a.centroid_error / static_cast<double>(slices.size());
    s.max = std::max(s.max, a.centroid_error);
  }
  for (double d : run.dice_truth) s.dice_min = std::min(s.dice_min, d);
  return s;
}

// Heunis et al. 2021, §4.2: stationary centroid error ≤ 1.1 mm, Dice ≥ 0.84; one slice per via-point, a
// lofted mesh.
TEST(ReconstructionSession, StationarySweepReproducesCentroidErrorAndDice) {
  const SweepRun& run = stationary();
  ASSERT_EQ(run.session->slices().size(), 16u);
  const Summary s = summarise(run);
  std::printf(
      "session ST: centroid error mean %.3f mm, max %.3f mm; Dice vs truth min %.3f; %d live frames, %.1f "
      "s\n",
      s.mean, s.max, s.dice_min, run.live_frames, run.duration);
  EXPECT_LE(s.mean, 1.1);
  EXPECT_GE(s.dice_min, 0.84);
  for (std::size_t i = 0; i < 16; ++i) EXPECT_EQ(run.session->slices()[i].via_point, static_cast<int>(i));
  EXPECT_EQ(run.session->mesh().vertices.size(), 16u * 30u);
  EXPECT_EQ(run.session->mesh().triangles.size(), 15u * 2u * 30u);
  EXPECT_GT(run.live_frames, 0);
}

// Heunis et al. 2021, §4.2: under limb motion ≤ 1.9 mm, Dice ≥ 0.84 (vs truth and ST-vs-VS per via-point).
TEST(ReconstructionSession, MovingLimbSweepReproducesCentroidErrorAndDice) {
  const SweepRun& st = stationary();
  const SweepRun& vs = moving();
  ASSERT_EQ(vs.session->slices().size(), 16u);
  ASSERT_EQ(st.session->slices().size(), 16u);
  const Summary s = summarise(vs);
  double reproducibility = 0.0;
  for (std::size_t i = 0; i < 16; ++i)
    reproducibility += dice_coefficient(st.session->slices()[i].mask, vs.session->slices()[i].mask) / 16.0;
  std::printf(
      "session VS: centroid error mean %.3f mm, max %.3f mm; Dice vs truth min %.3f; ST-vs-VS Dice mean "
      "%.3f; %.1f s\n",
      s.mean, s.max, s.dice_min, reproducibility, vs.duration);
  EXPECT_LE(s.mean, 1.9);
  EXPECT_GE(s.dice_min, 0.84);
  EXPECT_GE(reproducibility, 0.84);
}

// Our set-up: the session's SIMULATED interrogator over one limb period: shape error mean
// ≤ 0.82 mm, max ≤ 1.52 mm; contacts against the session's mesh where the catheter is truly 0.5 mm
// from the wall, none where it is over 2.5 mm from it; no curvature warning for this gentle path.
TEST(ReconstructionSession, CatheterShapeContactsAndCurvatureUnderLimbMotion) {
  UltrasoundReconstructionSession& session = *moving().session;
  const LimbMotion motion{1.0};
  const MulticoreFiber fiber;
  const FiberTruth truth = fiber_truth(fiber, catheter_path());
  double sum = 0.0, worst = 0.0;
  int count = 0, frames = 0, far_flags = 0;
  std::vector<int> flagged(32, 0);
  for (double t = 0.0; t < 30.0; t += 0.25, ++frames) {
    ProbeSample sample;
    sample.t = t;
    sample.world_T_limb = kTissueAtRest * motion.at(t);
    const SessionOutcome o = session.update_catheter(sample);
    ASSERT_TRUE(o.ok()) << o.message;
    const CatheterState& c = session.catheter();
    ASSERT_TRUE(c.valid);
    ASSERT_EQ(c.world.size(), 32u);
    ASSERT_EQ(c.tissue.size(), 32u);
    EXPECT_TRUE(c.over_curvature.empty());
    for (std::size_t g = 0; g < 32; ++g) {
      const double e = (c.world[g] - c.simulated_true_world[g]).norm();
      sum += e;
      worst = std::max(worst, e);
      ++count;
      if (c.wall_distance[g] < 1.25) ++flagged[g];
    }
    for (const auto& contact : c.contacts) {
      const Vector3d p = truth.fiber_pose * truth.points[static_cast<std::size_t>(contact.sensor)];
      if (p.x() >= 0.0 && p.x() <= 125.0 && 5.0 - catheter_offset(p.x()) > 2.5) ++far_flags;
    }
  }
  int near_sensors = 0;
  double near_fraction = 1.0;
  for (std::size_t g = 0; g < 32; ++g) {
    const Vector3d p = truth.fiber_pose * truth.points[g];
    if (p.x() >= 8.0 && p.x() <= 120.0 && 5.0 - catheter_offset(p.x()) < 0.6) {
      ++near_sensors;
      near_fraction = std::min(near_fraction, static_cast<double>(flagged[g]) / frames);
    }
  }
  std::printf(
      "session FBG: shape error mean %.3f mm, max %.3f mm over %d frames; %d near sensors flagged in >= %.0f "
      "%%; %d far flags\n",
      sum / count, worst, frames, near_sensors, 100.0 * near_fraction, far_flags);
  EXPECT_LE(sum / count, 0.82);
  EXPECT_LE(worst, 1.52);
  EXPECT_GT(near_sensors, 0);
  // The article gives no detection rate. A sensor 0.5 mm from the wall is flagged when its measured
  // distance is under 1.25 mm, and two independent tracker errors of 0.56 mm (the catheter base and
  // the limb) move it by about 0.8 mm, so some frames miss; measured: each flagged in ≥ 82 % of frames.
  EXPECT_GE(near_fraction, 0.75);
  EXPECT_EQ(far_flags, 0);
}

// A catheter bent tighter than the fibre's 50 mm limit (a 30 mm arc) raises curvature warnings.
TEST(ReconstructionSession, TightBendRaisesCurvatureWarnings) {
  ReconstructionSessionConfig c = session_config(5);
  c.catheter_path.clear();
  for (double s = 0.0; s <= 150.0; s += 0.2) c.catheter_path.emplace_back(0.0, -40.0, s);
  for (double a = 0.002; a <= 4.3; a += 0.002)  // 30 mm radius, 129 mm of arc
    c.catheter_path.emplace_back(30.0 - 30.0 * std::cos(a), -40.0, 150.0 + 30.0 * std::sin(a));
  UltrasoundReconstructionSession session(c);
  ProbeSample sample;
  sample.world_T_limb = kTissueAtRest;
  ASSERT_TRUE(session.update_catheter(sample).ok());
  EXPECT_FALSE(session.catheter().over_curvature.empty());
  EXPECT_GT(session.catheter().max_curvature, 1.0 / 50.0);
  EXPECT_LT(session.catheter().over_curvature.front(), 32);
  // No mesh yet: no contacts, every distance infinite.
  EXPECT_TRUE(session.catheter().contacts.empty());
  EXPECT_TRUE(std::isinf(session.catheter().wall_distance.front()));
}

// Bad input is refused with a sentence and nothing reconstructed is lost.
TEST(ReconstructionSession, RefusesBadInputAndKeepsWhatItHas) {
  ReconstructionSessionConfig c = session_config(7);
  c.catheter_path.clear();
  UltrasoundReconstructionSession session(c);
  session.set_plan(plan());
  const Isometry3d limb = kTissueAtRest;
  // Two acquisitions exactly at the first two via-points: two slices and a mesh.
  for (int i = 0; i < 2; ++i) {
    const ProbeSample s =
        sample_at(1.0 * i, limb * plan().via_points[static_cast<std::size_t>(i)].pose(), limb, true, true, i);
    ASSERT_TRUE(session.process(s).stored_slice);
  }
  const std::uint64_t revision = session.revision();
  const std::size_t vertices = session.mesh().vertices.size();
  ASSERT_EQ(session.slices().size(), 2u);
  ASSERT_EQ(vertices, 60u);

  ProbeSample nan_pose = sample_at(2.0, limb * plan().via_points[2].pose(), limb, true, true, 2);
  nan_pose.world_T_probe.translation().x() = std::numeric_limits<double>::quiet_NaN();
  SessionOutcome o = session.process(nan_pose);
  EXPECT_EQ(o.status, SessionStatus::invalid_pose);
  EXPECT_NE(o.message.find("not finite"), std::string::npos) << o.message;
  ProbeSample skewed = sample_at(2.0, limb * plan().via_points[2].pose(), limb, true, true, 2);
  skewed.world_T_limb.linear() *= 1.1;  // not a rotation
  EXPECT_EQ(session.process(skewed).status, SessionStatus::invalid_pose);
  EXPECT_EQ(session.update_catheter(skewed).status, SessionStatus::invalid_pose);

  const ProbeSample good = sample_at(2.0, limb * plan().via_points[2].pose(), limb, true, true, 2);
  BModeImage empty;
  empty.geometry = c.geometry;
  o = session.process(good, empty);
  EXPECT_EQ(o.status, SessionStatus::invalid_image);
  EXPECT_NE(o.message.find("no pixels"), std::string::npos) << o.message;
  BModeImage wrong;
  wrong.geometry.columns = 64;
  wrong.pixels.assign(wrong.geometry.pixel_count(), 0.5f);
  o = session.process(good, wrong);
  EXPECT_EQ(o.status, SessionStatus::invalid_image);
  EXPECT_NE(o.message.find("expects 320 × 400"), std::string::npos) << o.message;
  BModeImage poisoned;
  poisoned.geometry = c.geometry;
  poisoned.pixels.assign(c.geometry.pixel_count(), 0.3f);
  poisoned.pixels[17] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(session.process(good, poisoned).status, SessionStatus::invalid_image);
  // Off the skin: no image, nothing stored.
  ProbeSample lifted = good;
  lifted.in_contact = false;
  EXPECT_EQ(session.process(lifted).status, SessionStatus::no_contact);

  EXPECT_EQ(session.revision(), revision);
  EXPECT_EQ(session.slices().size(), 2u);
  EXPECT_EQ(session.mesh().vertices.size(), vertices);
  // …and the session still works afterwards.
  EXPECT_TRUE(session.process(good).stored_slice);
  EXPECT_EQ(session.slices().size(), 3u);
  session.reset();
  EXPECT_TRUE(session.slices().empty());
  EXPECT_TRUE(session.mesh().vertices.empty());
}

// The scanner images the limb where it truly is, the slice is mapped where the tracker says it is: a
// tracked limb 3 mm off (latency) moves the stored centroid by those 3 mm; a NaN true pose is refused.
TEST(ReconstructionSession, ImagesAtTheTrueLimbAndMapsThroughTheTrackedOne) {
  ReconstructionSessionConfig c = session_config(9);
  c.catheter_path.clear();
  c.errors.enabled = false;
  UltrasoundReconstructionSession exact(c), lagging(c);
  exact.set_plan(plan());
  lagging.set_plan(plan());
  const Isometry3d limb = kTissueAtRest;
  const Isometry3d probe = limb * plan().via_points[5].pose();
  ProbeSample s = sample_at(0.0, probe, limb, true, true, 5);
  s.world_T_limb_true = limb;
  ASSERT_TRUE(exact.process(s).stored_slice);
  // The true limb is 3 mm further along its own y than the tracked one, the probe moved with it.
  const Isometry3d moved = limb * pose(Eigen::Matrix3d::Identity(), Vector3d(0.0, 3.0, 0.0));
  ProbeSample late = sample_at(0.0, moved * plan().via_points[5].pose(), limb, true, true, 5);
  late.world_T_limb_true = moved;
  ASSERT_TRUE(lagging.process(late).stored_slice);
  const double exact_error = exact.slices().front().centroid_error;
  const double lag_error = lagging.slices().front().centroid_error;
  std::printf("true = tracked: %.3f mm; tracked 3 mm behind: %.3f mm\n", exact_error, lag_error);
  EXPECT_LT(exact_error, 0.5);
  EXPECT_NEAR(lag_error, 3.0, 0.5);
  ProbeSample broken = s;
  broken.via_point = 6;
  broken.world_T_limb_true->translation().z() = std::numeric_limits<double>::infinity();
  EXPECT_EQ(exact.process(broken).status, SessionStatus::invalid_pose);
  EXPECT_EQ(exact.update_catheter(broken).status, SessionStatus::invalid_pose);
  EXPECT_EQ(exact.slices().size(), 1u);
}

// Image-to-probe calibration in the reconstruction: the SIMULATED scanner images through its TRUE H_I^U and
// pixel scales (0.8 mm and 1° off the nominal plane, scales 1.6 % off), the session maps through the
// calibration it is given. With the nominal one the centroids are off; with the N-wire calibration's result
// they are not.
TEST(ReconstructionSession, MapsWithTheCalibratedImagePlaneWhileTheScannerImagesWithTheTrueOne) {
  ReconstructionSessionConfig c = session_config(11);
  c.catheter_path.clear();
  c.errors.enabled = false;
  ImageCalibration truth;
  truth.image_in_probe = pose(rotation(kPi / 180.0, Vector3d(1.0, 0.4, -0.3)),
                              Vector3d(0.0, 0.0, 0.5) + 0.8 * Vector3d(0.5, -0.7, 0.5).normalized());
  truth.s_u = 0.127;
  truth.s_v = 0.123;
  c.simulated_true_image = truth;
  UltrasoundReconstructionSession nominal(c), calibrated(c), perfect(c);
  perfect.set_image_calibration(truth);
  // The calibration of the scanner on the SIMULATED N-wire phantom (no robot error here: the pose
  // errors are tested with the routine itself).
  const SimulatedNWireScanner phantom_scanner(NWirePhantom{}, c.geometry, truth);
  std::vector<CalibrationShot> shots;
  for (const Isometry3d& p : n_wire_calibration_poses(Isometry3d::Identity(), 16)) shots.push_back({p, p});
  const ImageCalibrationRun run = run_n_wire_calibration(phantom_scanner, Isometry3d::Identity(), shots,
                                                         ImageCalibration::nominal(c.geometry));
  calibrated.set_image_calibration(run.fit.calibration);
  EXPECT_NEAR(calibrated.image_calibration().s_u, 0.127, 0.001);
  nominal.set_plan(plan());
  calibrated.set_plan(plan());
  perfect.set_plan(plan());
  // The same images (one seed) in the three sessions: the centroids differ only by the mapping.
  double nominal_sum = 0.0, calibrated_sum = 0.0, perfect_sum = 0.0, nominal_offset = 0.0,
         calibrated_offset = 0.0;
  const std::vector<int> via_points{2, 5, 8, 11, 14};
  for (const int i : via_points) {
    const Isometry3d probe = kTissueAtRest * plan().via_points[static_cast<std::size_t>(i)].pose();
    const ProbeSample s = sample_at(0.0, probe, kTissueAtRest, true, true, i);
    ASSERT_TRUE(nominal.process(s).stored_slice);
    ASSERT_TRUE(calibrated.process(s).stored_slice);
    ASSERT_TRUE(perfect.process(s).stored_slice);
    nominal_sum += nominal.slices().back().centroid_error;
    calibrated_sum += calibrated.slices().back().centroid_error;
    perfect_sum += perfect.slices().back().centroid_error;
    const Vector3d& truly = perfect.slices().back().slice.centroid;
    nominal_offset = std::max(nominal_offset, (nominal.slices().back().slice.centroid - truly).norm());
    calibrated_offset =
        std::max(calibrated_offset, (calibrated.slices().back().slice.centroid - truly).norm());
  }
  const double n = static_cast<double>(via_points.size());
  std::printf(
      "centroid error vs the plan with the nominal H_I^U %.3f mm, with the N-wire calibration %.3f mm, "
      "with the truth %.3f mm (mean of %d); centroids off the true mapping's by up to %.3f (nominal) and "
      "%.3f mm (calibrated)\n",
      nominal_sum / n, calibrated_sum / n, perfect_sum / n, static_cast<int>(n), nominal_offset,
      calibrated_offset);
  EXPECT_GT(nominal_offset, 0.8);     // the calibration error shows in the reconstruction
  EXPECT_LT(calibrated_offset, 0.2);  // and the calibration removes it
  EXPECT_LT(calibrated_sum, nominal_sum);
  ImageCalibration bad = truth;
  bad.s_v = -0.1;
  EXPECT_THROW(calibrated.set_image_calibration(bad), UltrasoundSetupError);
  EXPECT_NEAR(calibrated.image_calibration().s_v, run.fit.calibration.s_v, 1e-12);  // unchanged
}

// Mold calibration in the reconstruction: the fibre truly sits at one H_F^C, Eq. 2 uses the configured one; a
// new calibration (set_fiber_in_base) takes effect at the next catheter update.
TEST(ReconstructionSession, MapsTheCatheterWithTheCalibratedFibreInBase) {
  ReconstructionSessionConfig c = session_config(13);
  c.errors.enabled = false;
  const Isometry3d truth = c.fiber_in_base;
  c.simulated_true_fiber_in_base = truth;
  c.fiber_in_base = truth * pose(rotation(0.5 * kPi / 180.0, Vector3d::UnitX()), Vector3d(1.0, 0.0, 0.0));
  UltrasoundReconstructionSession session(c);
  ProbeSample s;
  s.world_T_limb = kTissueAtRest;
  const auto worst = [&]() {
    double w = 0.0;
    const CatheterState& state = session.catheter();
    for (std::size_t g = 0; g < state.world.size(); ++g)
      w = std::max(w, (state.world[g] - state.simulated_true_world[g]).norm());
    return w;
  };
  ASSERT_TRUE(session.update_catheter(s).ok());
  const double wrong = worst();
  session.set_fiber_in_base(truth);
  ASSERT_TRUE(session.update_catheter(s).ok());
  const double right = worst();
  std::printf("catheter with a wrong H_F^C (1 mm, 0.5 deg): %.3f mm worst; calibrated: %.3f mm\n", wrong,
              right);
  EXPECT_GT(wrong, 1.5);
  EXPECT_LT(right, 0.6);  // the interrogator's noise alone (1.2 pm per frame, one frame)
  Isometry3d skew = Isometry3d::Identity();
  skew.linear()(0, 1) = 0.3;
  EXPECT_THROW(session.set_fiber_in_base(skew), UltrasoundSetupError);
}

TEST(ReconstructionSession, RefusesABadSetUp) {
  ReconstructionSessionConfig short_catheter = session_config(1);
  short_catheter.catheter_path.resize(100);  // 10 mm, the fibre spans 270 mm
  EXPECT_THROW(UltrasoundReconstructionSession{short_catheter}, UltrasoundSetupError);
  ReconstructionSessionConfig skewed = session_config(1);
  skewed.image_in_probe.linear() *= 2.0;
  EXPECT_THROW(UltrasoundReconstructionSession{skewed}, UltrasoundSetupError);
  ReconstructionSessionConfig no_artery = session_config(1);
  no_artery.artery.points.resize(1);
  no_artery.artery.radii.resize(1);
  EXPECT_THROW(UltrasoundReconstructionSession{no_artery}, UltrasoundSetupError);
  UltrasoundReconstructionSession session(session_config(1));
  SweepPlan mismatched = plan();
  mismatched.via_points.pop_back();
  EXPECT_THROW(session.set_plan(mismatched), PlanningInputError);
}

}  // namespace
