// Shape calibration jobs (Abah 2022, §4.5.2, eqs. 4.10–4.12) behind POST /api/v1/robots/{r}/calibrations:
// the request is read and checked at once (400/422 with the key at fault), then the fit runs on the
// planning worker pool. Data come in one of four forms:
//   "samples":  [[s_mm, q_mm, theta_rad], …]                       scattered tangent data
//   "grid":     {"arc_length_mm": [r], "actuation_mm": [z], "tangent_angle_rad": [[z] × r]}  Φ of (4.10)
//   "outlines": [{"actuation_mm": q, "points": [[x_mm, z_mm], …]}, …]  backbone points per picture
//   "images":   [{"actuation_mm": q, "data": "<base64 PNG or JPEG>"}, …] side-view pictures, with
//               "mm_per_pixel" and optionally "entry", "mirror", "dark_catheter", "threshold"
// Outlines and images go through teleop::extract_tangent_angles ("straight_mm": the visible straight
// tube before the segment when the rig fixes it, "smoothing_mm"). The result holds the shape matrix
// A (n×m, rows powers of s, columns powers of q, mm), the mean/max/RMS fit error against the dissertation's
// 0.021° / 0.057°, and per picture what was extracted. With "save_as": "<name>.json" the robot file
// is written anew next to the old one with catheter.model.<segment>_shape_matrix set; an existing
// file is never replaced (409 at once, or the job fails if one appears meanwhile).
#pragma once

#include <filesystem>
#include <string>
#include <variant>

#include <nlohmann/json.hpp>

#include "tendril/server/config.hpp"
#include "tendril/server/control_api.hpp"
#include "tendril/server/job_queue.hpp"

namespace tendril::server {

// The work of a calibration job for `robot`, or the error that refuses the request.
std::variant<JobQueue::Work, ApiResult> make_calibration_job(const RobotConfig& robot,
                                                             const nlohmann::json& request);

}  // namespace tendril::server
