// The catheter tip EKF of Abah 2022, §4.9.3: the Jacobian, the filter's
// equations, bad input, and the simulated tracking of §4.9.4 on hand-drawn-like curves (R of 4.43) and
// on an ICA-like vessel in fluoroscopy projection (R of 4.44).
#include "tendril/teleop/perception/tip_ekf.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "allocation_counter.hpp"
#include "tendril/teleop/perception/planar_curvature.hpp"
#include "tendril/teleop/vessel_centerline.hpp"

namespace tendril::teleop::perception {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------------
// A_k of (4.42) is the Jacobian of f of (4.41).

TEST(TipEkf, T4_8_JacobianMatchesFiniteDifferences) {
  const std::vector<Eigen::Vector3d> poses{{0.0, 0.0, 0.0},        {12.5, -3.0, 0.7},    {-40.0, 8.0, -2.5},
                                           {3.0, 4.0, kPi - 0.01}, {1.0, 1.0, -kPi / 2}, {0.0, 5.0, 1.9}};
  const std::vector<double> steps{3.0, 0.5, -2.0, 10.0};
  const std::vector<double> curvatures{0.0, 0.05, -0.2};
  constexpr double h = 1e-6;
  for (const Eigen::Vector3d& pose : poses) {
    for (const double ds : steps) {
      for (const double kappa : curvatures) {
        Eigen::Matrix3d numeric;
        for (int j = 0; j < 3; ++j) {
          const Eigen::Vector3d dx = h * Eigen::Vector3d::Unit(j);
          numeric.col(j) =
              (TipEkf::process_model(pose + dx, ds, kappa) - TipEkf::process_model(pose - dx, ds, kappa)) /
              (2.0 * h);
        }
        const Eigen::Matrix3d analytic = TipEkf::process_jacobian(pose, ds);
        EXPECT_LT((analytic - numeric).cwiseAbs().maxCoeff(), 1e-7)
            << "pose " << pose.transpose() << " ds " << ds << " kappa " << kappa << "\nanalytic\n"
            << analytic << "\nnumeric\n"
            << numeric;
      }
    }
  }
  // (4.42) written out at one state, so a Jacobian that merely agrees with a wrong f fails here.
  const Eigen::Matrix3d a = TipEkf::process_jacobian({1.0, 2.0, 0.3}, 3.0);
  EXPECT_DOUBLE_EQ(a(0, 2), -std::sin(0.3) * 3.0);
  EXPECT_DOUBLE_EQ(a(1, 2), std::cos(0.3) * 3.0);
  EXPECT_TRUE((a.leftCols<2>().isApprox(Eigen::Matrix<double, 3, 2>::Identity())));
  EXPECT_DOUBLE_EQ(a(2, 2), 1.0);
  // And f itself, (4.41).
  const Eigen::Vector3d f = TipEkf::process_model({1.0, 2.0, 0.3}, 3.0, 0.1);
  EXPECT_DOUBLE_EQ(f.x(), 1.0 + std::cos(0.3) * 3.0);
  EXPECT_DOUBLE_EQ(f.y(), 2.0 + std::sin(0.3) * 3.0);
  EXPECT_DOUBLE_EQ(f.z(), 0.3 + 0.1 * 3.0);
}

// ---------------------------------------------------------------------------------------------------
// The filter's equations.

TEST(TipEkf, PresetsAreTheDissertationsMatrices) {
  const TipEkfNoise fine = TipEkfNoise::fine_scale();
  const TipEkfNoise vessel = TipEkfNoise::vessel_scale();
  EXPECT_TRUE(
      fine.process.isApprox(Eigen::Vector3d(1e-4, 1e-4, 0.0175 * 0.0175).asDiagonal().toDenseMatrix()));
  EXPECT_TRUE(fine.measurement.isApprox(
      Eigen::Vector3d(0.0625, 0.0625, 0.0873 * 0.0873).asDiagonal().toDenseMatrix()));
  EXPECT_TRUE(vessel.process.isApprox(fine.process));
  EXPECT_TRUE(
      vessel.measurement.isApprox(Eigen::Vector3d(4.0, 4.0, 0.175 * 0.175).asDiagonal().toDenseMatrix()));
}

TEST(TipEkf, PredictMovesAlongTheHeadingAndGrowsTheCovariance) {
  const TipEkf ekf(TipEkfNoise::fine_scale());
  TipEkfState state = ekf.start_at({1.0, 2.0, 0.4});
  const Eigen::Matrix3d p0 = state.covariance;
  ASSERT_EQ(ekf.predict(state, 3.0, 0.05), TipEkfStatus::ok);
  EXPECT_NEAR(state.pose.x(), 1.0 + 3.0 * std::cos(0.4), 1e-12);
  EXPECT_NEAR(state.pose.y(), 2.0 + 3.0 * std::sin(0.4), 1e-12);
  EXPECT_NEAR(state.pose.z(), 0.4 + 0.15, 1e-12);
  const Eigen::Matrix3d a = TipEkf::process_jacobian({1.0, 2.0, 0.4}, 3.0);
  EXPECT_TRUE(state.covariance.isApprox(a * p0 * a.transpose() + ekf.process_noise(), 1e-12));
}

TEST(TipEkf, UpdateIsTheKalmanCorrection) {
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  Eigen::Matrix3d p;
  p << 1.5, 0.2, 0.05,  //
      0.2, 0.9, -0.03,  //
      0.05, -0.03, 0.02;
  TipEkfState state = ekf.start_at({10.0, -4.0, 1.0}, p);
  const Eigen::Vector3d z(11.0, -3.5, 1.2);
  ASSERT_EQ(ekf.update(state, z), TipEkfStatus::ok);
  const Eigen::Matrix3d k = p * (p + ekf.measurement_noise()).inverse();
  const Eigen::Vector3d expected =
      Eigen::Vector3d(10.0, -4.0, 1.0) + k * (z - Eigen::Vector3d(10.0, -4.0, 1.0));
  EXPECT_LT((state.pose - expected).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_TRUE(state.covariance.isApprox((Eigen::Matrix3d::Identity() - k) * p, 1e-10));
  // The correction shrinks every variance.
  for (int i = 0; i < 3; ++i) EXPECT_LT(state.covariance(i, i), p(i, i));
}

TEST(TipEkf, HeadingInnovationIsWrappedAcrossPi) {
  const TipEkf ekf(TipEkfNoise::fine_scale());
  // Estimate just below +π, measurement just above −π: the two are 0.04 rad apart, not 2π − 0.04.
  TipEkfState state = ekf.start_at({0.0, 0.0, kPi - 0.02}, Eigen::Matrix3d::Identity() * 0.01);
  ASSERT_EQ(ekf.update(state, {0.0, 0.0, -kPi + 0.02}), TipEkfStatus::ok);
  // The estimate moved forward across π (towards the measurement) by less than 0.04 rad.
  const double moved = wrap_angle(state.pose.z() - (kPi - 0.02));
  EXPECT_GT(moved, 0.0);
  EXPECT_LT(moved, 0.04);
  EXPECT_GT(state.pose.z(), -kPi);
  EXPECT_LE(state.pose.z(), kPi);
  // Prediction keeps the heading in (−π, π] as well.
  TipEkfState turning = ekf.start_at({0.0, 0.0, 3.0});
  ASSERT_EQ(ekf.predict(turning, 3.0, 0.1), TipEkfStatus::ok);
  EXPECT_NEAR(turning.pose.z(), 3.3 - 2.0 * kPi, 1e-12);
  EXPECT_DOUBLE_EQ(wrap_angle(-kPi), kPi);
  EXPECT_NEAR(wrap_angle(7.0), 7.0 - 2.0 * kPi, 1e-15);
}

TEST(TipEkf, StepIsPredictThenUpdate) {
  const TipEkf ekf(TipEkfNoise::fine_scale());
  TipEkfState stepped = ekf.start_at({0.0, 0.0, 0.2});
  TipEkfState manual = stepped;
  const Eigen::Vector3d z(3.1, 0.5, 0.3);
  ASSERT_EQ(ekf.step(stepped, 3.0, 0.02, z), TipEkfStatus::ok);
  ASSERT_EQ(ekf.predict(manual, 3.0, 0.02), TipEkfStatus::ok);
  ASSERT_EQ(ekf.update(manual, z), TipEkfStatus::ok);
  EXPECT_EQ(stepped.pose, manual.pose);
  EXPECT_EQ(stepped.covariance, manual.covariance);
}

TEST(TipEkf, StepsDoNotAllocate) {
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  TipEkfState state = ekf.start_at({0.0, 0.0, 0.0});
  const long before = tendril::testing::allocation_count.load();
  for (int k = 0; k < 100; ++k) {
    const double s = 3.0 * k;
    EXPECT_EQ(ekf.step(state, 3.0, 0.01, {s, 0.02 * s, 0.01}), TipEkfStatus::ok);
    EXPECT_EQ(ekf.predict(state, 3.0, 0.0), TipEkfStatus::ok);
    EXPECT_EQ(ekf.update(state, {s + 3.0, 0.02 * s, 0.01}), TipEkfStatus::ok);
    EXPECT_EQ(ekf.step(state, kNaN, 0.0, {0.0, 0.0, 0.0}), TipEkfStatus::invalid_step);
  }
  EXPECT_EQ(tendril::testing::allocation_count.load(), before);
  tendril::testing::allocate_probe();  // the counter does see allocations
  EXPECT_GT(tendril::testing::allocation_count.load(), before);
}

// ---------------------------------------------------------------------------------------------------
// Bad input: an error value in the loop, the state untouched; a typed exception at set-up.

void expect_same(const TipEkfState& a, const TipEkfState& b) {
  // Bitwise: not one entry may have been touched.
  EXPECT_EQ(a.pose, b.pose);
  EXPECT_EQ(a.covariance, b.covariance);
}

TEST(TipEkf, NonFiniteInputsAreRejectedAndLeaveTheStateUnchanged) {
  const TipEkf ekf(TipEkfNoise::fine_scale());
  const TipEkfState original = ekf.start_at({5.0, 6.0, 0.3});
  TipEkfState state = original;
  for (const double bad : {kNaN, kInf, -kInf}) {
    EXPECT_EQ(ekf.predict(state, bad, 0.0), TipEkfStatus::invalid_step);
    EXPECT_EQ(ekf.predict(state, 3.0, bad), TipEkfStatus::invalid_step);
    EXPECT_EQ(ekf.step(state, bad, 0.01, {8.0, 6.0, 0.3}), TipEkfStatus::invalid_step);
    EXPECT_EQ(ekf.step(state, 3.0, bad, {8.0, 6.0, 0.3}), TipEkfStatus::invalid_step);
    for (int i = 0; i < 3; ++i) {
      Eigen::Vector3d z(8.0, 6.0, 0.3);
      z(i) = bad;
      EXPECT_EQ(ekf.update(state, z), TipEkfStatus::invalid_measurement);
      // A bad measurement stops the whole step: no predicted-only state is left behind.
      EXPECT_EQ(ekf.step(state, 3.0, 0.01, z), TipEkfStatus::invalid_measurement);
    }
    expect_same(state, original);
  }
  // A finite step so large that the covariance overflows is refused too.
  EXPECT_EQ(ekf.predict(state, 1e300, 0.0), TipEkfStatus::invalid_step);
  expect_same(state, original);
  // A corrupted state is reported, not propagated.
  TipEkfState corrupted = original;
  corrupted.covariance(1, 2) = kNaN;
  const TipEkfState corrupted_copy = corrupted;
  EXPECT_EQ(ekf.predict(corrupted, 3.0, 0.0), TipEkfStatus::invalid_state);
  EXPECT_EQ(ekf.update(corrupted, {1.0, 1.0, 0.0}), TipEkfStatus::invalid_state);
  EXPECT_EQ(ekf.step(corrupted, 3.0, 0.0, {1.0, 1.0, 0.0}), TipEkfStatus::invalid_state);
  EXPECT_TRUE(corrupted.pose == corrupted_copy.pose);
  EXPECT_TRUE(std::isnan(corrupted.covariance(1, 2)));
  EXPECT_STRNE(to_string(TipEkfStatus::invalid_step), to_string(TipEkfStatus::invalid_measurement));
}

void expect_config_error(const TipEkfNoise& noise, const std::string& names) {
  try {
    const TipEkf ekf(noise);
    ADD_FAILURE() << "expected TipEkfConfigError mentioning '" << names << "'";
  } catch (const TipEkfConfigError& error) {
    EXPECT_NE(std::string(error.what()).find(names), std::string::npos) << error.what();
  }
}

TEST(TipEkf, InvalidNoiseMatricesAreRefusedAtSetUp) {
  TipEkfNoise noise = TipEkfNoise::fine_scale();
  noise.process(2, 2) = kNaN;
  expect_config_error(noise, "Q (process noise) holds a NaN");

  noise = TipEkfNoise::fine_scale();
  noise.measurement(0, 0) = kInf;
  expect_config_error(noise, "R (measurement noise) holds a NaN or infinite");

  noise = TipEkfNoise::fine_scale();
  noise.measurement(1, 1) = 0.0;  // a perfect sensor on one axis: singular
  expect_config_error(noise, "R (measurement noise) is not positive definite");

  noise = TipEkfNoise::vessel_scale();
  noise.process(0, 0) = -1e-4;
  expect_config_error(noise, "Q (process noise) is not positive definite");

  noise = TipEkfNoise::vessel_scale();
  noise.measurement(0, 1) = 3.0;  // correlation 0.75 one way, 0 the other
  expect_config_error(noise, "R (measurement noise) is not symmetric");

  noise = TipEkfNoise::vessel_scale();
  noise.measurement(0, 1) = noise.measurement(1, 0) = 4.0;  // correlation 1: singular
  expect_config_error(noise, "R (measurement noise) is not positive definite");

  noise = TipEkfNoise::vessel_scale();
  noise.process.setZero();
  expect_config_error(noise, "Q (process noise) is all zeros");

  const TipEkf ekf(TipEkfNoise::fine_scale());
  EXPECT_THROW((void)ekf.start_at({kNaN, 0.0, 0.0}), TipEkfConfigError);
  EXPECT_THROW((void)ekf.start_at({0.0, 0.0, 0.0}, -Eigen::Matrix3d::Identity()), TipEkfConfigError);
}

// ---------------------------------------------------------------------------------------------------
// Simulated tracking as in the dissertation (§4.9.4): a known path, the tip advanced 3 mm per
// step, measurements = truth + Gaussian noise with σ = sqrt(diag R), κ of the path as the prior.

// Deterministic standard normal draws on every platform: std::mt19937's output is specified by the
// standard, std::normal_distribution's mapping is not. Box–Muller on 53-bit uniforms.
class NormalDraws {
 public:
  explicit NormalDraws(std::uint32_t seed) : engine_(seed) {}
  double next() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double u1 = uniform_open();
    const double u2 = uniform_open();
    const double radius = std::sqrt(-2.0 * std::log(u1));
    spare_ = radius * std::sin(2.0 * kPi * u2);
    has_spare_ = true;
    return radius * std::cos(2.0 * kPi * u2);
  }

 private:
  double uniform_open() {  // (0, 1)
    const std::uint64_t hi = engine_() >> 5U;
    const std::uint64_t lo = engine_() >> 6U;
    return (static_cast<double>((hi << 26U) | lo) + 0.5) / 9007199254740992.0;
  }
  std::mt19937 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

struct TrackingRun {
  double raw_rms = 0.0;       // mm, measurements vs truth
  double filtered_rms = 0.0;  // mm, EKF estimate vs truth
  double reduction() const { return 1.0 - filtered_rms / raw_rms; }
};

// Tracks the tip along `curve` from s = 0, the truth being the curve's point and heading at s_k and
// κ for the step the curve's mean curvature over [s_{k−1}, s_k]. The dissertation's procedure steps ds along
// the planar curve; with `along_vessel` the catheter instead inserts ds along the vessel, and the
// in-plane positions are s_k = in_plane_arc_length(k·ds), as a robot's insertion steps appear in the
// image. The filter starts at the first measurement with covariance R (the dissertation gives no x₀, P₀);
// errors are taken over steps 1..N.
TrackingRun track(const PlanarCurvatureProfile& curve, const TipEkf& ekf, double ds, std::uint32_t seed,
                  bool along_vessel = false) {
  NormalDraws normal(seed);
  const Eigen::Vector3d sigma = ekf.measurement_noise().diagonal().cwiseSqrt();
  auto measure = [&](double s) {
    const Eigen::Vector2d p = curve.point_at(s);
    return Eigen::Vector3d(p.x() + sigma.x() * normal.next(), p.y() + sigma.y() * normal.next(),
                           wrap_angle(curve.heading_at(s) + sigma.z() * normal.next()));
  };
  auto in_plane = [&](int k) { return along_vessel ? curve.in_plane_arc_length(ds * k) : ds * k; };
  TipEkfState state = ekf.start_at(measure(0.0));
  double raw_sq = 0.0;
  double filtered_sq = 0.0;
  const double total = along_vessel ? curve.vessel_length() : curve.length();
  const int steps = static_cast<int>(std::floor(total / ds + 1e-9));
  for (int k = 1; k <= steps; ++k) {
    const double s_prev = in_plane(k - 1);
    const double s = in_plane(k);
    const Eigen::Vector3d z = measure(s);
    EXPECT_EQ(ekf.step(state, s - s_prev, curve.mean_curvature(s_prev, s), z), TipEkfStatus::ok);
    const Eigen::Vector2d truth = curve.point_at(s);
    raw_sq += (z.head<2>() - truth).squaredNorm();
    filtered_sq += (state.pose.head<2>() - truth).squaredNorm();
  }
  return {std::sqrt(raw_sq / steps), std::sqrt(filtered_sq / steps)};
}

struct ReductionSummary {
  double mean = 0.0;
  double min = 1.0;
  double max = -1.0;
};

ReductionSummary summarise(const std::vector<double>& reductions) {
  ReductionSummary summary;
  for (const double r : reductions) {
    summary.mean += r / static_cast<double>(reductions.size());
    summary.min = std::min(summary.min, r);
    summary.max = std::max(summary.max, r);
  }
  return summary;
}

// A planar curve of length `length` from its curvature κ(s), integrated densely (midpoint rule on
// 0.02 mm steps), starting at the origin along +x: the "hand-drawn" test paths of §4.9.4.
std::vector<Eigen::Vector2d> integrate_curve(const std::function<double(double)>& kappa, double length) {
  constexpr double h = 0.02;
  const int n = static_cast<int>(std::lround(length / h));
  std::vector<Eigen::Vector2d> points{{0.0, 0.0}};
  double theta = 0.0;
  for (int i = 0; i < n; ++i) {
    const double s = h * i;
    const double mid_theta = theta + 0.5 * h * kappa(s + 0.25 * h);
    points.push_back(points.back() + h * Eigen::Vector2d(std::cos(mid_theta), std::sin(mid_theta)));
    theta += h * kappa(s + 0.5 * h);
  }
  return points;
}

constexpr std::uint32_t kFirstNoiseSeed = 1;
constexpr int kNoiseSeeds = 10;
constexpr double kInsertionStep = 3.0;  // mm per step, as the autonomous insertion (§4.9.4)

struct NamedCurve {
  std::string name;
  std::function<double(double)> kappa;
};

// κ of 0.01–0.05 rad/mm (bend radii of 20–100 mm): a curve drawn by hand over a 240 mm page.
std::vector<NamedCurve> hand_drawn_curves() {
  return {
      {"sine", [](double s) { return 0.03 * std::sin(2.0 * kPi * s / 120.0); }},
      {"arcs",
       [](double s) {
         if (s < 40.0) return 0.0;
         if (s < 100.0) return 1.0 / 30.0;
         if (s < 140.0) return 0.0;
         if (s < 200.0) return -1.0 / 25.0;
         return 0.0;
       }},
      {"spiral", [](double s) { return 0.045 * s / 240.0; }},
      {"wiggle",
       [](double s) {
         return 0.02 * std::sin(2.0 * kPi * s / 170.0 + 0.4) + 0.015 * std::sin(2.0 * kPi * s / 65.0 + 1.3) +
                0.008 * std::sin(2.0 * kPi * s / 31.0 + 2.1);
       }},
  };
}

// Runs kNoiseSeeds tracks along `curve`, prints and records the reductions, expects each run to
// reduce the error, and returns the summary.
ReductionSummary track_seeds(const std::string& test, const std::string& name,
                             const PlanarCurvatureProfile& curve, const TipEkf& ekf, bool along_vessel,
                             std::vector<double>& all) {
  std::vector<double> reductions;
  for (int i = 0; i < kNoiseSeeds; ++i) {
    const TrackingRun run = track(curve, ekf, kInsertionStep, kFirstNoiseSeed + i, along_vessel);
    EXPECT_GT(run.reduction(), 0.0) << name << " seed " << kFirstNoiseSeed + i;
    reductions.push_back(run.reduction());
  }
  const ReductionSummary summary = summarise(reductions);
  std::printf(
      "%s %-14s %5.1f mm in plane, RMS reduction over %d seeds: mean %.1f %%, min %.1f %%, max %.1f %%\n",
      test.c_str(), name.c_str(), curve.length(), kNoiseSeeds, 100.0 * summary.mean, 100.0 * summary.min,
      100.0 * summary.max);
  ::testing::Test::RecordProperty(test + "_" + name + "_mean_reduction_percent",
                                  std::to_string(100.0 * summary.mean));
  all.insert(all.end(), reductions.begin(), reductions.end());
  return summary;
}

void print_overall(const std::string& test, const std::vector<double>& all) {
  const ReductionSummary overall = summarise(all);
  std::printf("%s all            RMS reduction over %zu runs: mean %.1f %%, min %.1f %%, max %.1f %%\n",
              test.c_str(), all.size(), 100.0 * overall.mean, 100.0 * overall.min, 100.0 * overall.max);
  ::testing::Test::RecordProperty(test + "_mean_reduction_percent", std::to_string(100.0 * overall.mean));
}

TEST(TipEkf, S4_1_ArbitraryCurveReducesTheTrackingError) {
  const TipEkf ekf(TipEkfNoise::fine_scale());
  std::vector<double> all;
  for (const NamedCurve& named : hand_drawn_curves()) {
    const PlanarCurvatureProfile curve =
        PlanarCurvatureProfile::from_polyline(integrate_curve(named.kappa, 240.0));
    const ReductionSummary summary = track_seeds("hand-drawn", named.name, curve, ekf, false, all);
    // The dissertation: 68.8 % on its hand-drawn curve; an independent reimplementation got 45–57 % on
    // synthetic ones.
    EXPECT_GE(summary.mean, 0.40) << named.name;
  }
  print_overall("hand-drawn", all);
}

// An ICA seen with its bends in the image plane, as the dissertation's lateral projection shows the siphon:
// straight runs of 10–30 mm alternating with circular bends of 5–15 mm radius (the range of
// teleop::make_synthetic_ica) that turn 40–115°, in alternating directions, over 150 mm. Deterministic
// for a seed on every platform (its own mapping of std::mt19937's output).
std::function<double(double)> in_plane_ica_curvature(std::uint32_t seed) {
  std::mt19937 engine(seed);
  auto uniform = [&](double lo, double hi) {
    return lo + (hi - lo) * (static_cast<double>(engine()) / 4294967296.0);
  };
  struct Piece {
    double end;
    double kappa;
  };
  std::vector<Piece> pieces;
  double s = 0.0;
  double direction = (engine() & 1U) != 0U ? 1.0 : -1.0;
  while (s < 150.0) {
    s += uniform(10.0, 30.0);
    pieces.push_back({s, 0.0});
    const double radius = uniform(5.0, 15.0);
    s += radius * uniform(40.0, 115.0) * kPi / 180.0;
    pieces.push_back({s, direction / radius});
    direction = -direction;
  }
  return [pieces](double at) {
    for (const Piece& piece : pieces) {
      if (at < piece.end) return piece.kappa;
    }
    return 0.0;
  };
}

TEST(TipEkf, S4_2_VesselScaleReducesTheTrackingError) {
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  std::vector<double> all;
  for (const std::uint32_t vessel_seed : {1U, 2U, 3U, 4U}) {
    const PlanarCurvatureProfile curve =
        PlanarCurvatureProfile::from_polyline(integrate_curve(in_plane_ica_curvature(vessel_seed), 150.0));
    const std::string name = "ica_plane" + std::to_string(vessel_seed);
    const ReductionSummary summary = track_seeds("ICA", name, curve, ekf, false, all);
    // The dissertation: 65 % (60 % in its conclusions); an independent reimplementation got 63–75 %.
    EXPECT_GE(summary.mean, 0.55) << name;
  }
  print_overall("ICA", all);
}

// Simulated tracking on the 3D ICA-like vessel of config/vessels/synthetic_ica.csv (make_synthetic_ica seed 7
// at 0.2 mm) and two more of its kind, whose bends lie in randomly rolled planes, seen in both fluoroscopy
// views (the dissertation's text says its ICA run used the lateral view, its figure caption AP). Axes as the
// simulated fluoroscope's: AP images (x, z), lateral images (−y, z); the vessel starts at the origin along
// +z. The catheter inserts 3 mm per step along the vessel, so where the vessel turns out of the plane the
// in-plane step shrinks with the foreshortening (stepping 3 mm in the plane instead crosses such
// foreshortened bends, 1–2.5 rad of in-plane turn, in one step of (4.41), and gave 38–55 % on these views).
TEST(TipEkf, S4_2_ProjectedVesselWithInsertionSteps) {
  const TipEkf ekf(TipEkfNoise::vessel_scale());
  std::vector<double> all;
  for (const std::uint32_t vessel_seed : {7U, 11U, 23U}) {
    SyntheticIcaOptions options;
    options.point_spacing = 0.2;
    const CenterlinePolyline vessel = make_synthetic_ica(vessel_seed, options);
    const PlanarCurvatureProfile lateral = PlanarCurvatureProfile::from_projection(
        vessel.points, -Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ());
    const PlanarCurvatureProfile ap = PlanarCurvatureProfile::from_projection(
        vessel.points, Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitZ());
    const std::string name = "ica" + std::to_string(vessel_seed);
    EXPECT_GE(track_seeds("ICA 3D", name + "_lateral", lateral, ekf, true, all).mean, 0.55) << name;
    EXPECT_GE(track_seeds("ICA 3D", name + "_AP", ap, ekf, true, all).mean, 0.55) << name;
  }
  print_overall("ICA 3D", all);
}

}  // namespace
}  // namespace tendril::teleop::perception
