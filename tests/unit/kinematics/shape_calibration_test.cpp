#include "tendril/teleop/shape_calibration.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>
#include <vector>

#include "tendril/teleop/modal_catheter_kinematics.hpp"

namespace tendril::teleop {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

// Proximal-like shape (L = 10.5 mm): cubic in s, linear in q; the tip bends ~80° near q = 0.95 mm.
Eigen::MatrixXd proximal_like_shape() {
  Eigen::MatrixXd A(4, 2);
  A << std::numbers::pi / 2, 0.0,  //
      0.0, -0.10,                  //
      0.0, -0.006,                 //
      0.0, 0.0002;
  return A;
}

double model_angle(const Eigen::MatrixXd& A, double s, double q) {
  Eigen::VectorXd psi(A.rows()), eta(A.cols());
  for (Eigen::Index i = 0; i < A.rows(); ++i) psi(i) = std::pow(s, static_cast<double>(i));
  for (Eigen::Index j = 0; j < A.cols(); ++j) eta(j) = std::pow(q, static_cast<double>(j));
  return psi.dot(A * eta);
}

// The dissertation's experiment: q stepped by 0.1 mm until the tip bend reaches ≈ 80°, r = 50 points on s.
struct Grid {
  Eigen::VectorXd s, q;
  Eigen::MatrixXd phi;
};
Grid make_grid(const Eigen::MatrixXd& A, double length, double noise_deg, unsigned seed) {
  std::vector<double> qs;
  for (int k = 0;; ++k) {
    const double q = 0.1 * k;
    qs.push_back(q);
    if (std::abs(std::numbers::pi / 2 - model_angle(A, length, q)) >= 80.0 * kDeg) break;
  }
  Grid g;
  g.s = Eigen::VectorXd::LinSpaced(50, 0.0, length);
  g.q = Eigen::Map<Eigen::VectorXd>(qs.data(), static_cast<Eigen::Index>(qs.size()));
  g.phi.resize(g.s.size(), g.q.size());
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_deg * kDeg);
  for (Eigen::Index k = 0; k < g.q.size(); ++k) {
    for (Eigen::Index j = 0; j < g.s.size(); ++j) g.phi(j, k) = model_angle(A, g.s(j), g.q(k)) + noise(rng);
  }
  return g;
}

TEST(FitShapeMatrix, NoiseFreeGridRecoversShapeMatrixExactly) {
  const Eigen::MatrixXd A = proximal_like_shape();
  const Grid g = make_grid(A, 10.5, 0.0, 1);
  EXPECT_GE(g.q.size(), 5);
  const ShapeFitResult fit = fit_shape_matrix(g.s, g.q, g.phi);
  ASSERT_EQ(fit.shape_matrix.rows(), 4);
  ASSERT_EQ(fit.shape_matrix.cols(), 2);
  EXPECT_LT((fit.shape_matrix - A).cwiseAbs().maxCoeff(), 1e-9) << fit.shape_matrix;
  EXPECT_LT(fit.max_abs_error_deg, 1e-9);
  EXPECT_EQ(fit.sample_count, static_cast<std::size_t>(g.s.size() * g.q.size()));
}

TEST(FitShapeMatrix, NoiseFreeHigherOrderScatteredSamplesRecoverShapeMatrix) {
  Eigen::MatrixXd A(3, 3);
  A << 1.5, 0.02, -0.01,  //
      0.0, -0.12, 0.03,   //
      0.001, -0.004, 0.0007;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> s_dist(0.0, 13.8), q_dist(-1.0, 1.0);
  std::vector<ShapeSample> samples;
  for (int i = 0; i < 200; ++i) {
    const double s = s_dist(rng), q = q_dist(rng);
    samples.push_back({s, q, model_angle(A, s, q)});
  }
  const ShapeFitResult fit = fit_shape_matrix(samples, {.modal_order = 3, .actuation_order = 3});
  EXPECT_LT((fit.shape_matrix - A).cwiseAbs().maxCoeff(), 1e-9) << fit.shape_matrix;
}

TEST(FitShapeMatrix, NoisyExperimentRecoversShapeWithDissertationLevelFitError) {
  const Eigen::MatrixXd A = proximal_like_shape();
  const Grid g = make_grid(A, 10.5, 0.03, 2024);
  const ShapeFitResult fit = fit_shape_matrix(g.s, g.q, g.phi);
  const double relative_error = (fit.shape_matrix - A).norm() / A.norm();
  RecordProperty("mean_fit_error_deg", std::to_string(fit.mean_abs_error_deg));
  RecordProperty("max_fit_error_deg", std::to_string(fit.max_abs_error_deg));
  RecordProperty("rms_fit_error_deg", std::to_string(fit.rms_error_deg));
  RecordProperty("relative_A_error", std::to_string(relative_error));
  std::printf("[ measured ] r=%ld z=%ld mean %.4f deg, max %.4f deg, rms %.4f deg, |dA|/|A| %.2e\n",
              static_cast<long>(g.s.size()), static_cast<long>(g.q.size()), fit.mean_abs_error_deg,
              fit.max_abs_error_deg, fit.rms_error_deg, relative_error);
  EXPECT_LT(relative_error, 1e-3);
  EXPECT_LE(fit.mean_abs_error_deg, 0.05);
  EXPECT_GT(fit.mean_abs_error_deg, 0.01);  // residuals reflect the 0.03° noise, not a degenerate fit
  // The fitted model reproduces the noise-free shape far better than the noise level.
  double worst_model_error = 0.0;
  for (double q = 0.0; q <= g.q.maxCoeff(); q += 0.05) {
    for (double s = 0.0; s <= 10.5; s += 0.5) {
      worst_model_error =
          std::max(worst_model_error, std::abs(model_angle(fit.shape_matrix, s, q) - model_angle(A, s, q)));
    }
  }
  EXPECT_LT(worst_model_error / kDeg, 0.03);
}

TEST(FitShapeMatrix, RejectsTooFewSamples) {
  std::vector<ShapeSample> samples = {{0.0, 0.0, 1.5}, {1.0, 0.1, 1.4}, {2.0, 0.2, 1.3}};
  try {
    fit_shape_matrix(samples);
    FAIL() << "3 samples accepted for 8 unknowns";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("cannot determine"), std::string::npos) << error.what();
  }
}

TEST(FitShapeMatrix, RejectsRankDeficientDesign) {
  // Plenty of samples but one actuation value only: the q-dependence is unobservable.
  Eigen::VectorXd s = Eigen::VectorXd::LinSpaced(50, 0.0, 10.5), q(1);
  q << 0.5;
  const Eigen::MatrixXd phi = Eigen::MatrixXd::Constant(50, 1, 1.0);
  Eigen::VectorXd q_repeated = Eigen::VectorXd::Constant(3, 0.5);
  const Eigen::MatrixXd phi3 = Eigen::MatrixXd::Constant(50, 3, 1.0);
  EXPECT_THROW(fit_shape_matrix(s, q, phi), std::invalid_argument);
  try {
    fit_shape_matrix(s, q_repeated, phi3);
    FAIL() << "rank-deficient design accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("rank deficient"), std::string::npos) << error.what();
  }
}

TEST(FitShapeMatrix, RejectsNaNAndSizeMismatch) {
  const Grid g = make_grid(proximal_like_shape(), 10.5, 0.0, 3);
  Eigen::MatrixXd phi = g.phi;
  phi(3, 2) = std::nan("");
  try {
    fit_shape_matrix(g.s, g.q, phi);
    FAIL() << "NaN accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("NaN"), std::string::npos) << error.what();
  }
  EXPECT_THROW(fit_shape_matrix(g.s, g.q, g.phi.leftCols(2)), std::invalid_argument);
  EXPECT_THROW(fit_shape_matrix(g.s, g.q, g.phi, {.modal_order = 7, .actuation_order = 2}),
               std::invalid_argument);
}

// --- Tangent-angle extraction -------------------------------------------------------------------

// A thresholded-image-like outline: a 5 mm straight tube along +z, then a circular arc bending
// toward +x by `bend` over `length`, sampled every pixel, with Gaussian noise and pixel rounding,
// shuffled so the extractor must order it.
std::vector<Eigen::Vector2d> arc_outline(double straight, double length, double bend, double pixel,
                                         double noise_pixels, unsigned seed) {
  const double R = length / bend;
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_pixels * pixel);
  std::vector<Eigen::Vector2d> points;
  for (double u = -straight; u <= length + 1e-12; u += pixel) {
    Eigen::Vector2d p = u <= 0.0 ? Eigen::Vector2d(0.0, straight + u)
                                 : Eigen::Vector2d(R * (1 - std::cos(u / R)), straight + R * std::sin(u / R));
    p += Eigen::Vector2d(noise(rng), noise(rng));
    p = (p / pixel).array().round().matrix() * pixel;
    points.push_back(p);
  }
  std::shuffle(points.begin(), points.end(), rng);
  return points;
}

TEST(ExtractTangentAngles, CircularArcWithPixelNoiseWithinOneDegree) {
  const double straight = 5.0, length = 10.5, bend = 80.0 * kDeg, R = length / bend;
  for (unsigned seed : {11u, 12u, 13u, 14u, 15u}) {
    SCOPED_TRACE(seed);
    const auto outline = arc_outline(straight, length, bend, 0.02, 0.5, seed);
    const TangentProfile profile = extract_tangent_angles(outline);
    ASSERT_FALSE(profile.arc_length.empty());
    EXPECT_NEAR(profile.base_arc_length, straight, 0.1);
    double worst = 0.0, worst_s = 0.0, sum = 0.0;
    for (std::size_t i = 0; i < profile.arc_length.size(); ++i) {
      const double u = profile.base_arc_length + profile.arc_length[i] - straight;  // true arc position
      const double truth = std::numbers::pi / 2 - std::clamp(u, 0.0, length) / R;
      const double error = std::abs(profile.tangent_angle[i] - truth);
      sum += error;
      if (error > worst) worst = error, worst_s = profile.arc_length[i];
    }
    std::printf(
        "[ measured ] arc extraction: %zu samples, base %.3f mm (true 5), mean |dtheta| %.3f deg, worst %.3f "
        "deg at s = %.2f mm\n",
        profile.arc_length.size(), profile.base_arc_length, sum / profile.arc_length.size() / kDeg,
        worst / kDeg, worst_s);
    EXPECT_LT(worst, 1.0 * kDeg);
    EXPECT_NEAR(profile.base_arc_length + profile.arc_length.back(), straight + length, 0.25);
  }
}

TEST(ExtractTangentAngles, WithoutSmoothingPixelNoiseRuinsTheAngle) {
  // Shows the smoother is doing the work: forward differences on raw pixels are far off.
  const auto outline = arc_outline(5.0, 10.5, 80.0 * kDeg, 0.02, 0.5, 11);
  TangentExtractionOptions raw;
  raw.smoothing_length = 0.0;
  raw.straight_tolerance = 0.5;  // the noisy straight part would otherwise never look straight
  const TangentProfile profile = extract_tangent_angles(outline, raw);
  const double R = 10.5 / (80.0 * kDeg);
  double worst = 0.0;
  for (std::size_t i = 0; i < profile.arc_length.size(); ++i) {
    const double u = profile.base_arc_length + profile.arc_length[i] - 5.0;
    worst = std::max(
        worst, std::abs(profile.tangent_angle[i] - (std::numbers::pi / 2 - std::clamp(u, 0.0, 10.5) / R)));
  }
  EXPECT_GT(worst, 5.0 * kDeg);
}

TEST(ExtractTangentAngles, RejectsBadOutlines) {
  std::vector<Eigen::Vector2d> few(5, Eigen::Vector2d::Zero());
  EXPECT_THROW(extract_tangent_angles(few), std::invalid_argument);
  std::vector<Eigen::Vector2d> straight;
  for (int i = 0; i < 200; ++i) straight.emplace_back(0.0, 0.02 * i);
  try {
    extract_tangent_angles(straight);
    FAIL() << "straight outline accepted";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("straight"), std::string::npos) << error.what();
  }
  auto with_nan = arc_outline(5.0, 10.5, 1.0, 0.02, 0.0, 1);
  with_nan[10].x() = std::nan("");
  EXPECT_THROW(extract_tangent_angles(with_nan), std::invalid_argument);
  TangentExtractionOptions negative_base;
  negative_base.base_arc_length = -1.0;
  EXPECT_THROW(extract_tangent_angles(arc_outline(5.0, 10.5, 1.0, 0.02, 0.0, 1), negative_base),
               std::invalid_argument);
}

// Outlines rendered from a known modal model at q = 0.1, …, 0.9 (3 mm of straight tube first),
// extracted, then fitted. known_base: the rig fixes where the segment starts.
ShapeFitResult run_pipeline(const Eigen::MatrixXd& A, bool known_base, double& tip_error_deg) {
  // Outlines rendered from a known modal model at q = 0, 0.1, …, extracted, then fitted.
  ModalCatheterParameters parameters;
  parameters.proximal = {A, 10.5};
  parameters.distal = {A, 10.5};
  parameters.simpson_intervals = 64;
  const ModalCatheterKinematics model(parameters);
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.005);
  std::vector<ShapeSample> samples;
  for (int k = 1; k <= 9; ++k) {
    const double q = 0.1 * k;
    std::vector<Eigen::Vector2d> outline;
    for (double u = -3.0; u <= 10.5; u += 0.02) {
      const Eigen::Vector3d d =
          u <= 0 ? Eigen::Vector3d(0, 0, u) : model.segment_displacement(CatheterSegment::kProximal, u, q);
      outline.emplace_back(d.x() + noise(rng), 3.0 + d.z() + noise(rng));
    }
    TangentExtractionOptions options;
    if (known_base) options.base_arc_length = 3.0;
    append_shape_samples(extract_tangent_angles(outline, options), q, samples);
  }
  const ShapeFitResult fit = fit_shape_matrix(samples);
  tip_error_deg = 0.0;
  for (int k = 1; k <= 9; ++k) {
    tip_error_deg = std::max(tip_error_deg, std::abs(model_angle(fit.shape_matrix, 10.5, 0.1 * k) -
                                                     model.tip_angle(CatheterSegment::kProximal, 0.1 * k)) /
                                                kDeg);
  }
  std::printf(
      "[ measured ] pipeline (%s base): %zu samples, mean fit %.3f deg, max %.3f deg, worst tip error %.3f "
      "deg\n",
      known_base ? "known" : "detected", fit.sample_count, fit.mean_abs_error_deg, fit.max_abs_error_deg,
      tip_error_deg);
  return fit;
}

TEST(ShapeCalibrationPipeline, OutlinesOfAKnownModelFitBackToIt) {
  double tip_error = 0.0;
  const ShapeFitResult known = run_pipeline(proximal_like_shape(), true, tip_error);
  EXPECT_LT(known.mean_abs_error_deg, 0.2);
  EXPECT_LT(tip_error, 0.5);
  const ShapeFitResult detected = run_pipeline(proximal_like_shape(), false, tip_error);
  EXPECT_LT(detected.mean_abs_error_deg, 0.5);
  EXPECT_LT(tip_error, 2.0);
}

// --- Loss, coupling and the configuration rate law ----------------------------------------------

using Vector4 = ConfigurationRateMap::Vector4;

TEST(ActuationLoss, InverseLossMapRoundTrips) {
  const ActuationLoss proximal{0.063, -0.049};
  const double nominal = 1.2;
  EXPECT_NEAR(proximal.assembled_angle(nominal), 0.063 * 1.2 - 0.049, 1e-15);
  EXPECT_NEAR(proximal.nominal_angle(proximal.assembled_angle(nominal)), nominal, 1e-12);
  EXPECT_NEAR(proximal.nominal_angle(0.0), 0.049 / 0.063, 1e-12);
  EXPECT_THROW((ActuationLoss{0.0, 0.1}.nominal_angle(0.3)), std::invalid_argument);
}

TEST(ConfigurationRateMap, PureProximalRateWithoutCoupling) {
  ConfigurationRateParameters p;
  p.coupling_enabled = false;
  const ConfigurationRateMap map(p);
  const double dtheta1_dq3 = -1.4, dtheta2_dq4 = -1.1;  // constant-curvature J_ψq entries (rad/mm)
  Vector4 q_dot;
  ASSERT_TRUE(map.configuration_rates_to_joint_rates(Vector4(0, 0, 0.2, 0), dtheta1_dq3, dtheta2_dq4, q_dot));
  EXPECT_NEAR(q_dot[2], 0.2 / (0.063 * -1.4), 1e-12);
  EXPECT_DOUBLE_EQ(q_dot[3], 0.0);
  EXPECT_DOUBLE_EQ(q_dot[0], 0.0);
  EXPECT_DOUBLE_EQ(q_dot[1], 0.0);
  // Insertion and roll pass straight through; the distal rate uses a2.
  ASSERT_TRUE(
      map.configuration_rates_to_joint_rates(Vector4(1.5, -0.3, 0, 0.1), dtheta1_dq3, dtheta2_dq4, q_dot));
  EXPECT_DOUBLE_EQ(q_dot[0], 1.5);
  EXPECT_DOUBLE_EQ(q_dot[1], -0.3);
  EXPECT_NEAR(q_dot[3], 0.1 / (0.17 * -1.1), 1e-12);
}

TEST(ConfigurationRateMap, CouplingTermIsMinusRadiusCosOffset) {
  const ConfigurationRateMap map(ConfigurationRateParameters{});
  EXPECT_NEAR(map.coupling(), -0.6 * std::cos(-0.44), 1e-15);
  Vector4 q_dot;
  const double theta_rate = 0.2;
  ASSERT_TRUE(map.configuration_rates_to_joint_rates(Vector4(0, 0, theta_rate, 0), -1.4, -1.1, q_dot));
  EXPECT_NEAR(q_dot[3], -0.6 * std::cos(-0.44) * theta_rate, 1e-15);
  EXPECT_NEAR(q_dot[2], theta_rate / (0.063 * -1.4), 1e-12);
}

TEST(ConfigurationRateMap, CouplingCancelsInducedDistalActuationDisplacement) {
  // Plant model (the sign convention documented in shape_calibration.hpp): the distal line's
  // effective actuation is q4 + r1·cos δ2·(θ_L1 − θ_L1(0)). Drive θ_L1 along a quintic in stepped
  // time with θ_L2 held; with coupling the effective distal actuation (hence θ_L2) stays put.
  auto run = [](bool coupling) {
    ConfigurationRateParameters p;
    p.coupling_enabled = coupling;
    const ConfigurationRateMap map(p);
    const double r1_cos = p.proximal_outer_radius * std::cos(p.plane_offset);
    const double k1 = -1.4;
    double q3 = 0.0, q4 = 0.0;
    const double dt = 1e-3, duration = 2.0, swing = 0.3;  // θ_L1 changes by 0.3 rad over 2 s
    for (int step = 0; step < static_cast<int>(duration / dt); ++step) {
      const double tau = (step + 0.5) * dt / duration;  // midpoint rule
      const double theta_rate =
          swing * (30 * tau * tau - 60 * tau * tau * tau + 30 * tau * tau * tau * tau) / duration;
      Vector4 q_dot;
      EXPECT_TRUE(map.configuration_rates_to_joint_rates(Vector4(0, 0, theta_rate, 0), k1, -1.1, q_dot));
      q3 += q_dot[2] * dt;
      q4 += q_dot[3] * dt;
    }
    const double theta_L1_change = p.proximal_loss.slope * k1 * q3;  // assembled θ_L1 change
    EXPECT_NEAR(theta_L1_change, swing, 1e-6);
    return q4 + r1_cos * theta_L1_change;  // effective distal actuation
  };
  EXPECT_NEAR(run(true), 0.0, 1e-9);
  EXPECT_NEAR(run(false), 0.6 * std::cos(-0.44) * 0.3, 1e-6);  // uncompensated drift
}

TEST(ConfigurationRateMap, SingularOrInvalidInputHoldsStill) {
  const ConfigurationRateMap map(ConfigurationRateParameters{});
  Vector4 q_dot = Vector4::Constant(9.0);
  EXPECT_FALSE(map.configuration_rates_to_joint_rates(Vector4(1, 1, 1, 1), 0.0, -1.1, q_dot));
  EXPECT_EQ(q_dot, Vector4::Zero());
  q_dot.setConstant(9.0);
  EXPECT_FALSE(map.configuration_rates_to_joint_rates(Vector4(1, NAN, 1, 1), -1.4, -1.1, q_dot));
  EXPECT_EQ(q_dot, Vector4::Zero());
  ConfigurationRateParameters bad;
  bad.distal_loss.slope = 0.0;
  EXPECT_THROW(ConfigurationRateMap{bad}, std::invalid_argument);
  bad = {};
  bad.proximal_outer_radius = -1.0;
  EXPECT_THROW(ConfigurationRateMap{bad}, std::invalid_argument);
}

TEST(ConfigurationRateMap, UsesModalModelJacobianEntries) {
  // J_ψq from a calibrated (m = 2) model is constant; the rate law inverts it exactly.
  ModalCatheterParameters parameters;
  parameters.proximal = {proximal_like_shape(), 10.5};
  parameters.distal = {proximal_like_shape(), 13.8};
  const ModalCatheterKinematics model(parameters);
  const ConfigurationRateMap map(ConfigurationRateParameters{});
  const double j1 = model.tip_angle_rate(CatheterSegment::kProximal, 0.3),
               j2 = model.tip_angle_rate(CatheterSegment::kDistal, 0.3);
  Vector4 q_dot;
  ASSERT_TRUE(map.configuration_rates_to_joint_rates(Vector4(0, 0, 0.05, -0.02), j1, j2, q_dot));
  // Forward check: A_loss·J_ψq·(q̇ − A_coupling·ψ̇) reproduces ψ̇.
  EXPECT_NEAR(0.063 * j1 * q_dot[2], 0.05, 1e-12);
  EXPECT_NEAR(0.17 * j2 * (q_dot[3] - map.coupling() * 0.05), -0.02, 1e-12);
}

}  // namespace
}  // namespace tendril::teleop
