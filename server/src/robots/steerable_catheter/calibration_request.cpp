#include "steerable_catheter/calibration_request.hpp"

#include <algorithm>
#include <cmath>
#include <optional>
#include <regex>
#include <sstream>

namespace tendril::server {

namespace {

using nlohmann::json;

constexpr std::size_t kMaxPictures = 200;       // the dissertation steps 0.1 mm to ≈ 80°: about 10–60
constexpr std::size_t kMaxSamples = 2'000'000;  // scattered (s, q, θ) triples
constexpr std::size_t kMaxOutlinePoints = 200'000;
ApiResult bad_request(const std::string& message) { return ApiResult::error(400, "bad_request", message); }
ApiResult out_of_range(const std::string& message) { return ApiResult::error(422, "out_of_range", message); }

bool finite_number(const json& v) { return v.is_number() && std::isfinite(v.get<double>()); }

std::variant<double, ApiResult> number_in(const json& object, const char* key, double lo, double hi,
                                          const char* what) {
  const auto& v = object[key];
  if (!finite_number(v)) return bad_request(std::string(key) + ": expected " + what);
  const double x = v.get<double>();
  if (x < lo || x > hi) {
    std::ostringstream m;
    m << key << ": expected " << what << " from " << lo << " to " << hi << ", got " << x;
    return out_of_range(m.str());
  }
  return x;
}

std::optional<ApiResult> read_pictures(const json& r, CalibrationRequest& out) {
  const char* key = out.from_images ? "images" : "outlines";
  const auto& list = r[key];
  if (!list.is_array() || list.empty() || list.size() > kMaxPictures)
    return bad_request(
        std::string(key) + ": expected an array of 1 to " + std::to_string(kMaxPictures) +
        " pictures, each {\"actuation_mm\": q, " +
        (out.from_images ? "\"data\": \"<base64 PNG or JPEG>\"}" : "\"points\": [[x, z], …]}"));
  std::size_t total_points = 0;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const auto& p = list[i];
    const std::string at = std::string(key) + "[" + std::to_string(i) + "]";
    if (!p.is_object() || !finite_number(p.value("actuation_mm", json())))
      return bad_request(at + ".actuation_mm: expected the actuation (mm) the picture was taken at");
    CalibrationRequest::Picture picture;
    picture.actuation = p["actuation_mm"].get<double>();
    if (std::abs(picture.actuation) > 100.0) return out_of_range(at + ".actuation_mm: expected |q| ≤ 100 mm");
    if (out.from_images) {
      if (!p.contains("data") || !p["data"].is_string())
        return bad_request(at + ".data: expected the picture as a base64 string (PNG or JPEG)");
      if (!decode_base64(p["data"].get_ref<const std::string&>(), picture.image) || picture.image.empty())
        return bad_request(at + ".data: not valid base64");
    } else {
      const auto& points = p.value("points", json());
      if (!points.is_array() || points.size() < 8)
        return bad_request(at + ".points: expected at least 8 points [x_mm, z_mm]");
      total_points += points.size();
      if (total_points > kMaxOutlinePoints)
        return out_of_range("outlines: at most " + std::to_string(kMaxOutlinePoints) + " points in all");
      for (std::size_t k = 0; k < points.size(); ++k) {
        const auto& xz = points[k];
        if (!xz.is_array() || xz.size() != 2 || !finite_number(xz[0]) || !finite_number(xz[1]))
          return bad_request(at + ".points[" + std::to_string(k) +
                             "]: expected two finite numbers [x_mm, z_mm]");
        picture.outline.emplace_back(xz[0].get<double>(), xz[1].get<double>());
      }
    }
    out.pictures.push_back(std::move(picture));
  }
  if (r.contains("straight_mm") && !r["straight_mm"].is_null()) {
    auto v = number_in(r, "straight_mm", 0.0, 1000.0, "the visible straight tube before the segment (mm)");
    if (auto* e = std::get_if<ApiResult>(&v)) return *e;
    out.tangent_options.base_arc_length = std::get<double>(v);
  }
  if (r.contains("smoothing_mm")) {
    auto v = number_in(r, "smoothing_mm", 0.0, 10.0, "the smoother's length scale (mm)");
    if (auto* e = std::get_if<ApiResult>(&v)) return *e;
    out.tangent_options.smoothing_length = std::get<double>(v);
  }
  if (!out.from_images) return std::nullopt;
  if (!r.contains("mm_per_pixel"))
    return bad_request("mm_per_pixel: pictures need their scale in the bending plane (mm per pixel)");
  auto scale = number_in(r, "mm_per_pixel", 1e-4, 10.0, "the picture scale (mm per pixel)");
  if (auto* e = std::get_if<ApiResult>(&scale)) return *e;
  auto& io = out.image_options;
  io.mm_per_pixel = std::get<double>(scale);
  // The tangent samples are spaced like the pixels unless asked otherwise.
  out.tangent_options.sample_spacing = std::max(io.mm_per_pixel, 0.01);
  if (r.contains("entry")) {
    if (!r["entry"].is_string())
      return bad_request("entry: expected \"bottom\", \"top\", \"left\" or \"right\"");
    try {
      io.entry = teleop::perception::parse_image_edge(r["entry"].get<std::string>());
    } catch (const teleop::perception::SideViewImageError& e) {
      return bad_request(e.what());
    }
  }
  for (const auto& [name, flag] :
       {std::pair{"mirror", &io.mirror}, std::pair{"dark_catheter", &io.dark_catheter}}) {
    if (!r.contains(name)) continue;
    if (!r[name].is_boolean()) return bad_request(std::string(name) + ": expected true or false");
    *flag = r[name].get<bool>();
  }
  if (r.contains("threshold")) {
    if (!r["threshold"].is_number_integer() || r["threshold"].get<double>() < -1 ||
        r["threshold"].get<double>() > 255)
      return bad_request("threshold: expected a grey level 0..255, or -1 for Otsu's automatic level");
    io.threshold = r["threshold"].get<int>();
  }
  return std::nullopt;
}

}  // namespace

std::variant<CalibrationRequest, ApiResult> read_calibration_request(
    const json& r, const std::filesystem::path& robot_directory,
    const std::filesystem::path& robot_file_name) {
  CalibrationRequest out;
  if (!r.is_object()) return bad_request("expected a JSON object");
  const auto segment = r.value("segment", json());
  if (segment != "proximal" && segment != "distal")
    return bad_request("segment: expected \"proximal\" or \"distal\" (the bending segment the data are of)");
  out.segment_name = segment.get<std::string>();
  out.segment =
      out.segment_name == "proximal" ? teleop::CatheterSegment::kProximal : teleop::CatheterSegment::kDistal;
  for (const auto& [key, order] : {std::pair{"modal_order", &out.fit.modal_order},
                                   std::pair{"actuation_order", &out.fit.actuation_order}}) {
    if (!r.contains(key)) continue;
    if (!r[key].is_number_integer() || r[key].get<double>() < 1 ||
        r[key].get<double>() > teleop::kMaxModalOrder)
      return bad_request(std::string(key) + ": expected an integer from 1 to " +
                         std::to_string(teleop::kMaxModalOrder) + " (Abah 2022 uses n = 4, m = 2)");
    *order = r[key].get<int>();
  }
  int forms = 0;
  for (const char* key : {"samples", "grid", "outlines", "images"}) forms += r.contains(key) ? 1 : 0;
  if (forms != 1)
    return bad_request(
        "give the data in exactly one of \"samples\" ([[s_mm, q_mm, theta_rad], …]), \"grid\" "
        "({\"arc_length_mm\", \"actuation_mm\", \"tangent_angle_rad\"}), \"outlines\" ([{\"actuation_mm\", "
        "\"points\"}, …]) or \"images\" ([{\"actuation_mm\", \"data\"}, …] with \"mm_per_pixel\")");
  if (r.contains("samples")) {
    const auto& list = r["samples"];
    if (!list.is_array() || list.empty() || list.size() > kMaxSamples)
      return bad_request("samples: expected 1 to " + std::to_string(kMaxSamples) +
                         " triples [s_mm, q_mm, theta_rad]");
    out.samples.reserve(list.size());
    for (std::size_t i = 0; i < list.size(); ++i) {
      const auto& t = list[i];
      if (!t.is_array() || t.size() != 3 || !finite_number(t[0]) || !finite_number(t[1]) ||
          !finite_number(t[2]))
        return bad_request("samples[" + std::to_string(i) +
                           "]: expected three finite numbers [s_mm, q_mm, theta_rad]");
      out.samples.push_back({t[0].get<double>(), t[1].get<double>(), t[2].get<double>()});
    }
  } else if (r.contains("grid")) {
    const auto& g = r["grid"];
    const auto vector = [](const json& v, Eigen::VectorXd& x) {
      if (!v.is_array() || v.empty() || v.size() > 100'000) return false;
      x.resize(static_cast<Eigen::Index>(v.size()));
      for (std::size_t i = 0; i < v.size(); ++i) {
        if (!finite_number(v[i])) return false;
        x(static_cast<Eigen::Index>(i)) = v[i].get<double>();
      }
      return true;
    };
    if (!g.is_object() || !vector(g.value("arc_length_mm", json()), out.grid_s) ||
        !vector(g.value("actuation_mm", json()), out.grid_q))
      return bad_request(
          "grid: expected {\"arc_length_mm\": [r numbers], \"actuation_mm\": [z numbers], "
          "\"tangent_angle_rad\": [r rows of z numbers]}");
    const auto& phi = g.value("tangent_angle_rad", json());
    if (!phi.is_array() || phi.size() != static_cast<std::size_t>(out.grid_s.size()) ||
        out.grid_s.size() * out.grid_q.size() > static_cast<Eigen::Index>(kMaxSamples))
      return bad_request("grid.tangent_angle_rad: expected " + std::to_string(out.grid_s.size()) +
                         " rows (one per arc length) of " + std::to_string(out.grid_q.size()) + " angles");
    out.grid_phi.resize(out.grid_s.size(), out.grid_q.size());
    for (std::size_t j = 0; j < phi.size(); ++j) {
      Eigen::VectorXd row;
      if (!vector(phi[j], row) || row.size() != out.grid_q.size())
        return bad_request("grid.tangent_angle_rad[" + std::to_string(j) + "]: expected " +
                           std::to_string(out.grid_q.size()) + " finite angles (rad)");
      out.grid_phi.row(static_cast<Eigen::Index>(j)) = row.transpose();
    }
    out.grid = true;
  } else {
    out.from_images = r.contains("images");
    if (auto e = read_pictures(r, out)) return *e;
  }
  if (r.contains("save_as") && !r["save_as"].is_null()) {
    static const std::regex kName("[A-Za-z0-9][A-Za-z0-9._-]{0,100}\\.json");
    const auto& name = r["save_as"];
    if (!name.is_string() || !std::regex_match(name.get<std::string>(), kName))
      return bad_request(
          "save_as: expected a file name such as \"srmc-calibrated.json\" (letters, digits, . _ -; "
          "it is written next to the robot file)");
    out.save_as = robot_directory / name.get<std::string>();
    std::error_code ec;
    if (std::filesystem::exists(out.save_as, ec) || out.save_as.filename() == robot_file_name)
      return ApiResult::error(
          409, "file_exists",
          out.save_as.string() + " exists; a calibration never replaces a file: choose a new name");
  }
  return out;
}

bool decode_base64(std::string_view text, std::vector<std::uint8_t>& out) {
  out.clear();
  out.reserve(text.size() / 4 * 3 + 3);
  std::uint32_t bits = 0;
  int have = 0;
  std::size_t padding = 0;
  for (const char c : text) {
    int v = -1;
    if (c >= 'A' && c <= 'Z')
      v = c - 'A';
    else if (c >= 'a' && c <= 'z')
      v = c - 'a' + 26;
    else if (c >= '0' && c <= '9')
      v = c - '0' + 52;
    else if (c == '+' || c == '-')
      v = 62;  // '-' and '_': the URL-safe alphabet
    else if (c == '/' || c == '_')
      v = 63;
    else if (c == '=') {
      ++padding;
      continue;
    }
    if (v < 0 || padding > 0) return false;  // a bad character, or data after the padding
    bits = (bits << 6) | static_cast<std::uint32_t>(v);
    have += 6;
    if (have >= 8) {
      have -= 8;
      out.push_back(static_cast<std::uint8_t>((bits >> have) & 0xff));
    }
  }
  return padding <= 2 && have < 6;  // a lone trailing character carries no whole byte
}

}  // namespace tendril::server
