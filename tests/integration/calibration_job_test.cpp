// Shape calibration jobs (Abah 2022, §4.5.2): the request reader's refusals, the fit from tangent data
// and from pictures of the SIMULATED side-view camera, and the new robot file the result is written
// to, loaded back into a runtime.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>

#include "json_api.hpp"
#include "steerable_catheter/calibration_job.hpp"
#include "steerable_catheter/calibration_request.hpp"
#include "tendril/drivers/sim/simulated_side_view_camera.hpp"
#include "tendril/server/imaging_worker.hpp"
#include "tendril/server/robot_runtime.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;
const std::filesystem::path kSrmc = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";
constexpr double kDeg = std::numbers::pi / 180.0;

// A bare proximal tip of 22 mm that is not quite constant curvature (cubic in s, linear in q).
Eigen::MatrixXd true_matrix() {
  Eigen::MatrixXd A(4, 2);
  A << std::numbers::pi / 2, 0.0,  //
      0.0, -0.055,                 //
      0.0, -0.0012,                //
      0.0, 0.00002;
  return A;
}

double angle(const Eigen::MatrixXd& A, double s, double q) {
  double theta = 0.0;
  for (Eigen::Index i = 0; i < A.rows(); ++i)
    for (Eigen::Index j = 0; j < A.cols(); ++j) theta += A(i, j) * std::pow(s, i) * std::pow(q, j);
  return theta;
}

class CalibrationJobTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir = std::filesystem::temp_directory_path() /
          ("tendril-calibration-" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "-" +
           ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    std::filesystem::copy_file(kSrmc, dir / "srmc.json");
    robot = load_robot_config(dir / "srmc.json");
  }
  void TearDown() override { std::filesystem::remove_all(dir); }

  ApiResult refusal(const json& request) {
    auto job = make_calibration_job(robot, request);
    if (auto* e = std::get_if<ApiResult>(&job)) return *e;
    return ApiResult::success(nullptr);
  }
  json run(const json& request) {
    auto job = make_calibration_job(robot, request);
    if (auto* e = std::get_if<ApiResult>(&job)) {
      ADD_FAILURE() << e->status << " " << e->message;
      return nullptr;
    }
    double last_progress = 0.0;
    std::atomic<bool> cancel{false};
    teleop::JobControl control{[&](double f) { last_progress = f; }, &cancel};
    json result = std::get<JobQueue::Work>(job)(control);
    EXPECT_EQ(last_progress, 1.0);
    return result;
  }

  std::filesystem::path dir;
  RobotConfig robot;
};

TEST_F(CalibrationJobTest, RefusesMalformedRequestsAndNamesTheKey) {
  const json samples = {{1.0, 0.1, 1.5}, {2.0, 0.1, 1.4}};
  const auto check = [&](const json& request, int status, const char* says) {
    const auto r = refusal(request);
    EXPECT_EQ(r.status, status) << request.dump();
    EXPECT_NE(r.message.find(says), std::string::npos) << r.message << "\n  for " << request.dump();
  };
  check(json(json::array()), 400, "JSON object");
  check(json({{"samples", samples}}), 400, "segment");
  check(json({{"segment", "middle"}, {"samples", samples}}), 400, "segment");
  check(json({{"segment", "proximal"}}), 400, "exactly one of");
  check(json({{"segment", "proximal"}, {"samples", samples}, {"grid", json::object()}}), 400,
        "exactly one of");
  check(json({{"segment", "proximal"}, {"samples", {{1.0, 0.1}}}}), 400, "samples[0]");
  check(json({{"segment", "proximal"}, {"samples", {{1.0, 0.1, 1.5}, {1.0, "x", 1.5}}}}), 400, "samples[1]");
  check(json({{"segment", "proximal"}, {"samples", samples}, {"modal_order", 9}}), 400, "modal_order");
  check(json({{"segment", "proximal"}, {"samples", samples}, {"save_as", "../escape.json"}}), 400, "save_as");
  check(json({{"segment", "proximal"}, {"samples", samples}, {"save_as", "srmc.json"}}), 409,
        "never replaces");
  check(json({{"segment", "distal"}, {"images", {{{"actuation_mm", 0.1}, {"data", "iVBORw0K"}}}}}), 400,
        "mm_per_pixel");
  check(json({{"segment", "distal"},
              {"mm_per_pixel", 0.02},
              {"images", {{{"actuation_mm", 0.1}, {"data", "no!"}}}}}),
        400, "base64");
  check(json({{"segment", "distal"},
              {"mm_per_pixel", 0.0},
              {"images", {{{"actuation_mm", 0.1}, {"data", "AAAA"}}}}}),
        422, "mm_per_pixel");
  check(json({{"segment", "distal"},
              {"mm_per_pixel", 0.02},
              {"entry", "north"},
              {"images", {{{"actuation_mm", 0.1}, {"data", "AAAA"}}}}}),
        400, "entry");
  check(json({{"segment", "distal"}, {"outlines", {{{"actuation_mm", 0.1}, {"points", {{0.0, 0.0}}}}}}}), 400,
        "at least 8");
  check(json({{"segment", "proximal"},
              {"grid",
               {{"arc_length_mm", {0.0, 1.0}}, {"actuation_mm", {0.0}}, {"tangent_angle_rad", {{1.5}}}}}}),
        400, "2 rows");
  RobotConfig arm = robot;
  arm.settings.erase("catheter");
  auto job = make_calibration_job(arm, {{"segment", "proximal"}, {"samples", samples}});
  ASSERT_TRUE(std::holds_alternative<ApiResult>(job));
  EXPECT_EQ(std::get<ApiResult>(job).code, "not_a_catheter");
}

// Tangent data of the dissertation's experiment (dq = 0.1 mm to ≈ 80°, θ sampled every 0.5 mm) with 0.02°
// of noise: the fit gives A back, its mean error is of the dissertation's 0.021° order, and the robot file
// it writes loads into a runtime whose configuration map uses the calibrated tip.
TEST_F(CalibrationJobTest, TangentDataFitBackAndTheWrittenRobotFileLoads) {
  const auto A = true_matrix();
  std::mt19937 rng(21);
  std::normal_distribution<double> noise(0.0, 0.02 * kDeg);
  json samples = json::array();
  for (int k = 0; k <= 10; ++k)
    for (int j = 0; j <= 44; ++j)
      samples.push_back({0.5 * j, 0.1 * k, angle(A, 0.5 * j, 0.1 * k) + noise(rng)});
  const json result =
      run({{"segment", "proximal"}, {"samples", samples}, {"save_as", "srmc-calibrated.json"}});
  ASSERT_TRUE(result.is_object());
  EXPECT_EQ(result["samples"], 11 * 45);
  EXPECT_LT(result["mean_abs_error_deg"].get<double>(), 0.03);
  EXPECT_EQ(result["seed_mean_abs_error_deg"], 0.021);
  Eigen::MatrixXd fitted(4, 2);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 2; ++j) fitted(i, j) = result["shape_matrix"][i][j].get<double>();
  for (double q : {0.2, 0.6, 1.0})
    EXPECT_NEAR(angle(fitted, 22.0, q), angle(A, 22.0, q), 0.05 * kDeg) << "tip angle at q = " << q;

  const auto file = dir / "srmc-calibrated.json";
  ASSERT_EQ(result["written"]["file"], file.string());
  EXPECT_EQ(result["written"]["key"], "catheter.model.proximal_shape_matrix");
  // The old file is untouched; the new one carries the matrix and loads into a runtime.
  EXPECT_FALSE(
      load_robot_config(dir / "srmc.json").settings["catheter"]["model"].contains("proximal_shape_matrix"));
  const auto calibrated = load_robot_config(file);
  EXPECT_EQ(calibrated.settings["catheter"]["model"]["proximal_shape_matrix"], result["shape_matrix"]);
  RuntimeOptions o;
  o.stepped = true;
  RobotRuntime runtime({calibrated}, o, builtin_robot_types());
  // The proximal bend range follows the calibrated tip through the loss line (4.13) at q3 = 10 mm.
  const double tip_bend_at_10 = std::numbers::pi / 2 - angle(fitted, 22.0, 10.0);
  EXPECT_NEAR(json_api(runtime)->robots()[0]["configuration"]["upper"][2].get<double>(),
              0.063 * tip_bend_at_10 - 0.049, 1e-3);
  // The 3D view, the fluoroscope and the API draw the model the robot uses: the calibrated (not
  // constant-curvature) shape through the loss lines, at what reaches the tubes.
  {
    auto api = json_api(runtime);
    runtime.start();
    for (int i = 0; i < 20; ++i) runtime.step();
    ASSERT_EQ(api->state_command("srmc", {{"command", "enable"}}).status, 200);
    for (int i = 0; i < 3000 && !api->operating_state("srmc").body["drives_ready"].get<bool>(); ++i)
      runtime.step();
    ASSERT_EQ(api->move_jp("srmc", {{"goal", {10.0, 0.0, 4.0, 0.0}}}).status, 202);
    for (int i = 0; i < 4000; ++i) runtime.step();
    const auto state = api->operating_state("srmc").body;
    const auto q = api->measured_js("srmc").body["position"];
    const auto settings = parse_catheter_settings(calibrated);
    const teleop::ModalCatheterKinematics model(assembled_shape(settings));
    const double d0 = state["spring_deflection_mm"][0].get<double>();
    const double d1 = state["spring_deflection_mm"][1].get<double>();
    const double c3 = q[2].get<double>() - d0;
    const double coupling = 0.6 * std::cos(-0.76);  // proximal_outer_radius · cos δ2 (srmc.json)
    const double c4 =
        q[3].get<double>() - d1 +
        coupling * (std::numbers::pi / 2 - model.tip_angle(teleop::CatheterSegment::kProximal, c3));
    std::vector<Eigen::Vector3d> expected(model.backbone_point_count(20));
    expected.resize(
        model.backbone(Eigen::Vector4d(q[0].get<double>(), q[1].get<double>(), c3, c4), 20, expected));
    const auto drawn = api->shape("srmc").body["points"];
    ASSERT_EQ(drawn.size(), expected.size());
    double worst = 0.0;
    for (std::size_t i = 0; i < expected.size(); ++i) {
      const Eigen::Vector3d p(drawn[i][0].get<double>(), drawn[i][1].get<double>(),
                              drawn[i][2].get<double>());
      worst = std::max(worst, (p - expected[i]).norm());
    }
    EXPECT_LT(worst, 1e-6) << "the drawn backbone is the calibrated model's";
    // And that differs from constant curvature with the same tip: the middle of the proximal segment.
    const Eigen::Vector3d base = expected.front(), mid = expected[10], end = expected[20];
    const double chord_offset = ((mid - base).cross(end - base)).norm() / (end - base).norm();
    EXPECT_GT(q[2].get<double>(), 3.9) << "the bend drive reached its goal";
    EXPECT_GT(chord_offset, 0.1) << "the segment is bent";
    runtime.stop();
  }
  // The same name again is refused before any work, and nothing is replaced.
  const auto again =
      refusal({{"segment", "proximal"}, {"samples", samples}, {"save_as", "srmc-calibrated.json"}});
  EXPECT_EQ(again.status, 409);
  EXPECT_EQ(again.code, "file_exists");
}

// Pictures of the SIMULATED side-view camera at dq = 0.1 mm steps to ≈ 80°, fitted as the dissertation did.
TEST_F(CalibrationJobTest, SideViewPicturesFitBackToTheSegmentTheyShow) {
  teleop::ModalCatheterParameters shape;
  shape.proximal = {true_matrix(), 22.0};
  shape.distal = {true_matrix(), 22.0};
  sim::SimulatedSideViewCamera camera(shape, {});
  json images = json::array();
  for (int k = 1; k <= 10; ++k) {
    const auto png = camera.capture_png(teleop::CatheterSegment::kProximal, 0.1 * k);
    std::string data;
    append_base64(png.data(), png.size(), data);
    images.push_back({{"actuation_mm", 0.1 * k}, {"data", data}});
  }
  const json result = run({{"segment", "proximal"},
                           {"images", images},
                           {"mm_per_pixel", camera.options().mm_per_pixel},
                           {"straight_mm", camera.options().straight_mm}});
  ASSERT_TRUE(result.is_object());
  std::printf("[ measured ] calibration from 10 simulated pictures: mean fit %.4f deg, max %.4f deg\n",
              result["mean_abs_error_deg"].get<double>(), result["max_abs_error_deg"].get<double>());
  EXPECT_LT(result["mean_abs_error_deg"].get<double>(), 0.08);  // seed: 0.021° (proximal)
  ASSERT_EQ(result["pictures"].size(), 10U);
  EXPECT_NEAR(result["pictures"][0]["tube_width_mm"].get<double>(), 0.6, 0.1);
  Eigen::MatrixXd fitted(4, 2);
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 2; ++j) fitted(i, j) = result["shape_matrix"][i][j].get<double>();
  for (double q : {0.3, 0.7, 1.0})
    EXPECT_NEAR(angle(fitted, 22.0, q), angle(true_matrix(), 22.0, q), 0.5 * kDeg)
        << "tip angle at q = " << q;
  EXPECT_TRUE(result["written"].is_null());
}

TEST_F(CalibrationJobTest, APictureWithoutACatheterFailsTheJobAndSaysWhich) {
  const std::string blank_png_of_white =  // 1×1 white PNG
      "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAAAAAA6fptVAAAACklEQVR4nGP4DwABAQEAWk1v8QAAAABJRU5ErkJggg==";
  auto job =
      make_calibration_job(robot, {{"segment", "distal"},
                                   {"mm_per_pixel", 0.02},
                                   {"images", {{{"actuation_mm", 0.4}, {"data", blank_png_of_white}}}}});
  ASSERT_TRUE(std::holds_alternative<JobQueue::Work>(job));
  try {
    std::get<JobQueue::Work>(job)(teleop::JobControl{});
    FAIL() << "a blank picture was fitted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("images[0]"), std::string::npos) << e.what();
  }
}

TEST(Base64, DecodesTheStandardAndUrlAlphabetsAndRefusesGarbage) {
  std::vector<std::uint8_t> out;
  ASSERT_TRUE(decode_base64("TWFu", out));
  EXPECT_EQ(std::string(out.begin(), out.end()), "Man");
  ASSERT_TRUE(decode_base64("TWE=", out));
  EXPECT_EQ(std::string(out.begin(), out.end()), "Ma");
  ASSERT_TRUE(decode_base64("TQ", out));
  EXPECT_EQ(std::string(out.begin(), out.end()), "M");
  ASSERT_TRUE(decode_base64("-_8", out));
  EXPECT_EQ(out, (std::vector<std::uint8_t>{0xfb, 0xff}));
  EXPECT_FALSE(decode_base64("T", out));
  EXPECT_FALSE(decode_base64("TW=E", out));
  EXPECT_FALSE(decode_base64("TW E", out));
  EXPECT_FALSE(decode_base64("TQ===", out));
}

}  // namespace
}  // namespace tendril::server
