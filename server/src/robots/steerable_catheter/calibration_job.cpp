#include "steerable_catheter/calibration_job.hpp"

#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <numbers>

#include "steerable_catheter/calibration_request.hpp"
#include "steerable_catheter/catheter_settings.hpp"
#include "tendril/teleop/perception/side_view_outline.hpp"
#include "tendril/teleop/shape_calibration.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

// The dissertation's mean fit errors (§4.5.2), reported next to ours.
constexpr std::array<double, 2> kSeedMeanFitErrorDeg{0.021, 0.057};

json matrix_json(const Eigen::MatrixXd& A) {
  json rows = json::array();
  for (Eigen::Index i = 0; i < A.rows(); ++i) {
    json row = json::array();
    for (Eigen::Index j = 0; j < A.cols(); ++j) row.push_back(A(i, j));
    rows.push_back(std::move(row));
  }
  return rows;
}

// The robot file again, with the fitted matrix; created exclusively, then read back as a robot.
json write_robot_file(const RobotConfig& robot, const CalibrationRequest& request, const Eigen::MatrixXd& A,
                      const teleop::ShapeFitResult& fit) {
  std::ifstream in(robot.file);
  if (!in) throw std::runtime_error("cannot read " + robot.file.string() + " to write the calibrated copy");
  json file = json::parse(in, nullptr, true, true);
  auto& model = file["catheter"]["model"];
  model[request.segment_name + "_shape_matrix"] = matrix_json(A);
  model[request.segment_name + "_shape_matrix_fit"] = {{"samples", fit.sample_count},
                                                       {"mean_abs_error_deg", fit.mean_abs_error_deg},
                                                       {"max_abs_error_deg", fit.max_abs_error_deg},
                                                       {"source", request.grid               ? "grid"
                                                                  : request.from_images      ? "images"
                                                                  : request.pictures.empty() ? "samples"
                                                                                             : "outlines"},
                                                       {"from", robot.file.filename().string()}};
  const std::string text = file.dump(2) + "\n";
  // "x": fail if the file exists, so a file that appeared since the request is not replaced either.
  struct Close {
    void operator()(std::FILE* f) const { std::fclose(f); }
  };
  std::unique_ptr<std::FILE, Close> out(std::fopen(request.save_as.c_str(), "wx"));
  if (!out)
    throw std::runtime_error("cannot create " + request.save_as.string() + ": " + std::strerror(errno) +
                             " (an existing file is never replaced)");
  if (std::fwrite(text.data(), 1, text.size(), out.get()) != text.size() || std::fflush(out.get()) != 0) {
    out.reset();
    std::filesystem::remove(request.save_as);
    throw std::runtime_error("writing " + request.save_as.string() + " failed");
  }
  out.reset();
  try {
    (void)parse_catheter_settings(load_robot_config(request.save_as));
  } catch (const std::exception& e) {
    std::filesystem::remove(request.save_as);
    throw std::runtime_error(std::string("the calibrated robot file would not load, so it was removed: ") +
                             e.what());
  }
  return {{"file", request.save_as.string()},
          {"key", "catheter.model." + request.segment_name + "_shape_matrix"}};
}

json run(const RobotConfig& robot, CalibrationRequest request, const teleop::JobControl& control) {
  json pictures = json::array();
  std::vector<teleop::ShapeSample> samples = std::move(request.samples);
  const std::size_t count = request.pictures.size();
  for (std::size_t i = 0; i < count; ++i) {
    control.check_cancelled();
    auto& p = request.pictures[i];
    json info = {{"actuation_mm", p.actuation}};
    const std::string at =
        std::string(request.from_images ? "images[" : "outlines[") + std::to_string(i) + "]";
    try {
      if (request.from_images) {
        const auto outline = teleop::perception::extract_side_view_outline(p.image, request.image_options);
        p.outline = outline.points;
        info["threshold"] = outline.threshold;
        info["catheter_pixels"] = outline.catheter_pixels;
        info["tube_width_mm"] = outline.tube_width_mm;
        std::vector<std::uint8_t>().swap(p.image);
      }
      const auto profile = teleop::extract_tangent_angles(p.outline, request.tangent_options);
      const std::size_t before = samples.size();
      teleop::append_shape_samples(profile, p.actuation, samples);
      info["outline_points"] = p.outline.size();
      info["base_arc_length_mm"] = profile.base_arc_length;
      info["samples"] = samples.size() - before;
      info["tip_bend_deg"] = (std::numbers::pi / 2 - profile.tangent_angle.back()) * 180.0 / std::numbers::pi;
      info["arc_length_mm"] = profile.arc_length.back();
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(at + " (actuation " + std::to_string(p.actuation) + " mm): " + e.what());
    }
    pictures.push_back(std::move(info));
    control.report(0.9 * static_cast<double>(i + 1) / static_cast<double>(count));
  }
  control.check_cancelled();
  const teleop::ShapeFitResult fit =
      request.grid ? teleop::fit_shape_matrix(request.grid_s, request.grid_q, request.grid_phi, request.fit)
                   : teleop::fit_shape_matrix(samples, request.fit);
  json result = {{"robot", robot.name},
                 {"segment", request.segment_name},
                 {"modal_order", request.fit.modal_order},
                 {"actuation_order", request.fit.actuation_order},
                 {"shape_matrix", matrix_json(fit.shape_matrix)},
                 {"units", "theta(s, q) = [1, s, …]·A·[1, q, …]ᵀ in rad, s and q in mm"},
                 {"samples", fit.sample_count},
                 {"mean_abs_error_deg", fit.mean_abs_error_deg},
                 {"max_abs_error_deg", fit.max_abs_error_deg},
                 {"rms_error_deg", fit.rms_error_deg},
                 {"seed_mean_abs_error_deg", kSeedMeanFitErrorDeg[static_cast<std::size_t>(request.segment)]},
                 {"pictures", std::move(pictures)},
                 {"written", nullptr}};
  if (!request.save_as.empty()) result["written"] = write_robot_file(robot, request, fit.shape_matrix, fit);
  control.report(1.0);
  return result;
}

}  // namespace

std::variant<JobQueue::Work, ApiResult> make_calibration_job(const RobotConfig& robot, const json& request) {
  if (!robot.settings.contains("catheter"))
    return ApiResult::error(
        422, "not_a_catheter",
        "robot '" + robot.name + "' has no catheter settings: shape calibration is for steerable catheters");
  auto parsed = read_calibration_request(request, robot.directory(), robot.file.filename());
  if (auto* e = std::get_if<ApiResult>(&parsed)) return *e;
  auto shared = std::make_shared<CalibrationRequest>(std::move(std::get<CalibrationRequest>(parsed)));
  return JobQueue::Work(
      [robot, shared](const teleop::JobControl& control) { return run(robot, std::move(*shared), control); });
}

}  // namespace tendril::server
