// The request of a shape calibration job (calibration_job.hpp), read and checked before anything
// is queued: every refusal is a 400 (malformed) or 422 (out of range) naming the key at fault, or 409
// when save_as names a file that exists. Outside input: fuzzed (tests/fuzz/fuzz_calibration_request).
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"
#include "tendril/teleop/modal_catheter_kinematics.hpp"
#include "tendril/teleop/perception/side_view_outline.hpp"
#include "tendril/teleop/shape_calibration.hpp"

namespace tendril::server {

// What a job needs.
struct CalibrationRequest {
  teleop::CatheterSegment segment = teleop::CatheterSegment::kProximal;
  std::string segment_name;
  teleop::ShapeFitOptions fit;
  std::vector<teleop::ShapeSample> samples;  // "samples"
  bool grid = false;                         // "grid"
  Eigen::VectorXd grid_s, grid_q;
  Eigen::MatrixXd grid_phi;
  struct Picture {
    double actuation = 0.0;
    std::vector<std::uint8_t> image;       // "images": encoded bytes
    std::vector<Eigen::Vector2d> outline;  // "outlines": points (x, z) mm
  };
  std::vector<Picture> pictures;
  bool from_images = false;
  teleop::perception::SideViewImageOptions image_options;
  teleop::TangentExtractionOptions tangent_options;
  std::filesystem::path save_as;  // empty: do not write
};

// `robot_directory`: where save_as is written; `robot_file_name`: the robot's own file, never a target.
std::variant<CalibrationRequest, ApiResult> read_calibration_request(
    const nlohmann::json& request, const std::filesystem::path& robot_directory,
    const std::filesystem::path& robot_file_name);

// Standard or URL-safe base64 (RFC 4648), padding optional, no white space; false on anything else.
bool decode_base64(std::string_view text, std::vector<std::uint8_t>& out);

}  // namespace tendril::server
