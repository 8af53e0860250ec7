#include "serial_arm/calibration_store.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <sstream>
#include <system_error>
#include <utility>

namespace tendril::server {

namespace {

using nlohmann::json;

constexpr const char* kFormat = "tendril.calibration/1";

std::string utc_string(std::int64_t unix_s) {
  const std::time_t t = static_cast<std::time_t>(unix_s);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

bool valid_kind_name(std::string_view kind) {
  if (kind.empty() || kind.size() > 32) return false;
  return std::all_of(kind.begin(), kind.end(),
                     [](char c) { return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_'; });
}

// "<kind>-v<digits>.json" → (kind, version); nullopt for any other name (not ours: left alone).
std::optional<std::pair<std::string, int>> parse_file_name(const std::string& name) {
  constexpr std::string_view suffix = ".json";
  if (name.size() <= suffix.size() || name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0)
    return std::nullopt;
  const auto stem = name.substr(0, name.size() - suffix.size());
  const auto dash = stem.rfind("-v");
  if (dash == std::string::npos || dash + 2 >= stem.size()) return std::nullopt;
  const auto kind = stem.substr(0, dash);
  const auto digits = stem.substr(dash + 2);
  if (!valid_kind_name(kind) || digits.size() > 9 ||
      !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
    return std::nullopt;
  return std::pair{kind, std::stoi(digits)};
}

json matrix_json(const Eigen::Isometry3d& transform) {
  json rows = json::array();
  const Eigen::Matrix4d& m = transform.matrix();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) rows.push_back(m(r, c));
  return rows;
}

[[noreturn]] void bad(const std::string& what) { throw CalibrationStoreError(what); }

}  // namespace

std::optional<std::string> rigid_transform_problem(const Eigen::Matrix4d& m) {
  if (!m.allFinite()) return "it holds a value that is not a finite number";
  if (std::abs(m(3, 0)) > 1e-9 || std::abs(m(3, 1)) > 1e-9 || std::abs(m(3, 2)) > 1e-9 ||
      std::abs(m(3, 3) - 1.0) > 1e-9)
    return "its last row is not 0 0 0 1";
  const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
  const double orthogonality = (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthogonality > 1e-6) {
    char text[128];
    std::snprintf(text, sizeof text, "its rotation is not orthonormal (RᵀR differs from I by %.3g)",
                  orthogonality);
    return std::string(text);
  }
  if (r.determinant() < 0.0) return "its rotation is a reflection (determinant −1)";
  return std::nullopt;
}

json to_json(const CalibrationRecord& record) {
  json transforms = json::object();
  for (const auto& [name, transform] : record.transforms)
    transforms[name] = {{"matrix_row_major", matrix_json(transform)}};
  json values = json::object();
  for (const auto& [name, value] : record.values) values[name] = value;
  return {{"format", kFormat},
          {"kind", record.kind},
          {"version", record.version},
          {"taken_utc", record.taken_utc},
          {"taken_unix_s", record.taken_unix_s},
          {"robot", record.robot},
          {"method", record.method},
          {"units", "mm, rad; transforms are 4x4 homogeneous matrices in row order"},
          {"transforms", transforms},
          {"values", values},
          {"residual_mm", record.residual_mm},
          {"residuals", record.residuals},
          {"valid", record.valid},
          {"summary", record.summary}};
}

CalibrationRecord calibration_from_json(const json& document) {
  if (!document.is_object()) bad("it is not a JSON object");
  auto field = [&](const char* key) -> const json& {
    const auto it = document.find(key);
    if (it == document.end()) bad(std::string("it has no \"") + key + "\"");
    return *it;
  };
  if (field("format") != kFormat) bad(std::string("its \"format\" is not \"") + kFormat + "\"");
  CalibrationRecord record;
  try {
    record.kind = field("kind").get<std::string>();
    record.version = field("version").get<int>();
    record.taken_unix_s = field("taken_unix_s").get<std::int64_t>();
    record.taken_utc = field("taken_utc").get<std::string>();
    record.robot = field("robot").get<std::string>();
    record.method = field("method").get<std::string>();
    record.residual_mm = field("residual_mm").get<double>();
    record.residuals = field("residuals");
    record.valid = field("valid").get<bool>();
    record.summary = field("summary").get<std::string>();
    for (const auto& [name, value] : field("values").items()) record.values[name] = value.get<double>();
    for (const auto& [name, value] : field("transforms").items()) {
      const auto& rows = value.at("matrix_row_major");
      if (!rows.is_array() || rows.size() != 16) bad("transform \"" + name + "\" is not 16 numbers");
      Eigen::Matrix4d m;
      for (int i = 0; i < 16; ++i) m(i / 4, i % 4) = rows[static_cast<std::size_t>(i)].get<double>();
      if (const auto problem = rigid_transform_problem(m))
        bad("transform \"" + name + "\" is not rigid: " + *problem);
      Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
      transform.matrix() = m;
      record.transforms[name] = transform;
    }
  } catch (const json::exception& e) {
    bad(std::string("a field has the wrong type (") + e.what() + ")");
  }
  if (!valid_kind_name(record.kind)) bad("its \"kind\" is not a lower-case name");
  if (record.version < 1) bad("its \"version\" is not a positive number");
  if (!std::isfinite(record.residual_mm)) bad("its \"residual_mm\" is not a finite number");
  return record;
}

std::string CalibrationStore::file_name(std::string_view kind, int version) {
  char digits[16];
  std::snprintf(digits, sizeof digits, "%06d", version);
  return std::string(kind) + "-v" + digits + ".json";
}

CalibrationStore::CalibrationStore(std::filesystem::path directory, std::string robot)
    : directory_(std::move(directory)), robot_(std::move(robot)) {
  std::error_code ec;
  std::filesystem::create_directories(directory_, ec);
  if (ec || !std::filesystem::is_directory(directory_))
    throw CalibrationStoreError("calibration store: cannot make the directory " + directory_.string() + " (" +
                                ec.message() + ")");
  load();
}

void CalibrationStore::load() {
  std::error_code ec;
  std::vector<std::filesystem::path> files;
  for (const auto& entry : std::filesystem::directory_iterator(directory_, ec))
    if (entry.is_regular_file()) files.push_back(entry.path());
  if (ec)
    throw CalibrationStoreError("calibration store: cannot read the directory " + directory_.string() + " (" +
                                ec.message() + ")");
  std::sort(files.begin(), files.end());
  for (const auto& path : files) {
    const auto name = parse_file_name(path.filename().string());
    if (!name) continue;  // not a calibration file (e.g. a temporary one of an interrupted save)
    auto& highest = highest_version_[name->first];
    highest = std::max(highest, name->second);
    try {
      std::ifstream in(path);
      if (!in) bad("it cannot be opened");
      json document;
      try {
        document = json::parse(in);
      } catch (const json::exception&) {
        bad("it is not valid JSON");
      }
      auto record = calibration_from_json(document);
      if (record.kind != name->first || record.version != name->second)
        bad("its kind and version (" + record.kind + " v" + std::to_string(record.version) +
            ") are not those of its name");
      if (record.robot != robot_) bad("it is robot \"" + record.robot + "\"'s, not \"" + robot_ + "\"'s");
      auto& newest = newest_[record.kind];
      if (record.version > newest.version) newest = record;
      if (record.valid) {
        auto& current = current_[record.kind];
        if (record.version > current.version) current = std::move(record);
      }
    } catch (const CalibrationStoreError& e) {
      problems_.push_back("calibration file " + path.string() + " was not used: " + e.what());
    }
  }
}

void CalibrationStore::register_kind(KindInfo info) {
  if (!valid_kind_name(info.kind))
    throw CalibrationStoreError("calibration kind \"" + info.kind + "\" is not a lower-case name");
  std::lock_guard lock(mutex_);
  for (const auto& k : kinds_)
    if (k.kind == info.kind)
      throw CalibrationStoreError("calibration kind \"" + info.kind + "\" registered twice");
  kinds_.push_back(std::move(info));
}

std::vector<CalibrationStore::KindInfo> CalibrationStore::kinds() const {
  std::lock_guard lock(mutex_);
  return kinds_;
}

std::optional<CalibrationRecord> CalibrationStore::current(std::string_view kind) const {
  std::lock_guard lock(mutex_);
  const auto it = current_.find(kind);
  if (it == current_.end()) return std::nullopt;
  return it->second;
}

std::optional<CalibrationRecord> CalibrationStore::newest(std::string_view kind) const {
  std::lock_guard lock(mutex_);
  const auto it = newest_.find(kind);
  if (it == newest_.end()) return std::nullopt;
  return it->second;
}

CalibrationRecord CalibrationStore::save(CalibrationRecord record) {
  std::lock_guard lock(mutex_);
  if (std::none_of(kinds_.begin(), kinds_.end(), [&](const KindInfo& k) { return k.kind == record.kind; }))
    throw CalibrationStoreError("calibration kind \"" + record.kind + "\" is not one of this robot's");
  for (const auto& [name, transform] : record.transforms)
    if (const auto problem = rigid_transform_problem(transform.matrix()))
      throw CalibrationStoreError("calibration \"" + record.kind + "\" not saved: transform \"" + name +
                                  "\" is not rigid: " + *problem);
  if (!std::isfinite(record.residual_mm))
    throw CalibrationStoreError("calibration \"" + record.kind +
                                "\" not saved: its residual is not a number");
  record.robot = robot_;
  record.version = highest_version_[record.kind] + 1;
  if (record.taken_unix_s == 0) record.taken_unix_s = static_cast<std::int64_t>(std::time(nullptr));
  record.taken_utc = utc_string(record.taken_unix_s);

  const auto path = directory_ / file_name(record.kind, record.version);
  const auto temporary = directory_ / ("." + file_name(record.kind, record.version) + ".tmp");
  {
    std::ofstream out(temporary, std::ios::trunc);
    out << to_json(record).dump(2) << '\n';
    out.flush();
    if (!out)
      throw CalibrationStoreError("calibration \"" + record.kind + "\" not saved: cannot write " +
                                  temporary.string());
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::filesystem::remove(temporary, ec);
    throw CalibrationStoreError("calibration \"" + record.kind + "\" not saved: cannot rename it to " +
                                path.string());
  }
  highest_version_[record.kind] = record.version;
  newest_[record.kind] = record;
  if (record.valid) current_[record.kind] = record;
  return record;
}

std::vector<CalibrationStore::KindInfo> CalibrationStore::missing_required() const {
  std::lock_guard lock(mutex_);
  std::vector<KindInfo> missing;
  for (const auto& k : kinds_)
    if (k.required && current_.find(k.kind) == current_.end()) missing.push_back(k);
  return missing;
}

std::vector<std::string> CalibrationStore::problems() const {
  std::lock_guard lock(mutex_);
  return problems_;
}

std::filesystem::path default_calibration_directory(std::string_view robot) {
  const std::filesystem::path tail = std::filesystem::path("calibrations") / std::string(robot);
  if (const char* state = std::getenv("TENDRIL_STATE_DIR"); state != nullptr && *state != '\0')
    return std::filesystem::path(state) / tail;
  if (const char* xdg = std::getenv("XDG_STATE_HOME"); xdg != nullptr && *xdg != '\0')
    return std::filesystem::path(xdg) / "tendril" / tail;
  if (const char* home = std::getenv("HOME"); home != nullptr && *home != '\0')
    return std::filesystem::path(home) / ".local" / "state" / "tendril" / tail;
  return std::filesystem::path("tendril-state") / tail;
}

}  // namespace tendril::server
