// Typed reading of JSON configuration with errors that name the file and the key path (private to
// the server library: config.cpp and the robot-specific settings parsers share it).
#pragma once

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "tendril/server/config.hpp"

namespace tendril::server::detail {

// Reads typed values out of one JSON object and reports mistakes with the file and the key path.
class Reader {
 public:
  Reader(const nlohmann::json& j, std::string file, std::string path)
      : j_(j), file_(std::move(file)), path_(std::move(path)) {
    if (!j_.is_object()) fail("", "an object", j_);
  }

  [[noreturn]] void fail(const std::string& key, const std::string& expected,
                         const nlohmann::json& got) const {
    std::string where = path_;
    if (!key.empty()) where += (where.empty() ? "" : ".") + key;
    std::string got_text = got.is_null() ? std::string("nothing") : got.dump();
    if (got_text.size() > 60) got_text = got_text.substr(0, 57) + "...";
    throw ConfigError(file_ + ": " + (where.empty() ? std::string("top level") : where) + ": expected " +
                      expected + ", got " + got_text);
  }

  bool has(const std::string& key) const { return j_.contains(key); }
  const nlohmann::json& raw(const std::string& key) const {
    if (!j_.contains(key)) fail(key, "this key to be present", nullptr);
    return j_.at(key);
  }

  std::string string(const std::string& key) const {
    const auto& v = raw(key);
    if (!v.is_string() || v.get<std::string>().empty()) fail(key, "a non-empty string", v);
    return v.get<std::string>();
  }
  std::string string_or(const std::string& key, std::string fallback) const {
    return has(key) ? string(key) : std::move(fallback);
  }

  double number(const std::string& key) const {
    const auto& v = raw(key);
    if (!v.is_number() || !std::isfinite(v.get<double>())) fail(key, "a finite number", v);
    return v.get<double>();
  }
  double number_or(const std::string& key, double fallback) const {
    return has(key) ? number(key) : fallback;
  }
  double positive(const std::string& key) const {
    double v = number(key);
    if (!(v > 0)) fail(key, "a number greater than 0", raw(key));
    return v;
  }
  double positive_or(const std::string& key, double fallback) const {
    return has(key) ? positive(key) : fallback;
  }
  double non_negative_or(const std::string& key, double fallback) const {
    if (!has(key)) return fallback;
    double v = number(key);
    if (v < 0) fail(key, "a number of at least 0", raw(key));
    return v;
  }
  long integer_in(const std::string& key, long lo, long hi) const {
    const auto& v = raw(key);
    if (!v.is_number_integer() || v.get<long>() < lo || v.get<long>() > hi)
      fail(key, "an integer from " + std::to_string(lo) + " to " + std::to_string(hi), v);
    return v.get<long>();
  }
  long integer_in_or(const std::string& key, long lo, long hi, long fallback) const {
    return has(key) ? integer_in(key, lo, hi) : fallback;
  }
  bool boolean_or(const std::string& key, bool fallback) const {
    if (!has(key)) return fallback;
    const auto& v = raw(key);
    if (!v.is_boolean()) fail(key, "true or false", v);
    return v.get<bool>();
  }
  const nlohmann::json& array(const std::string& key, bool non_empty) const {
    const auto& v = raw(key);
    if (!v.is_array() || (non_empty && v.empty())) fail(key, non_empty ? "a non-empty array" : "an array", v);
    return v;
  }
  Reader child(const std::string& key) const { return Reader(raw(key), file_, join(key)); }
  Reader element(const std::string& key, std::size_t i) const {
    return Reader(j_.at(key).at(i), file_, join(key) + "[" + std::to_string(i) + "]");
  }
  std::string join(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  const std::string& file() const { return file_; }

 private:
  const nlohmann::json& j_;
  std::string file_;
  std::string path_;
};

// Three finite numbers at `key` (a position in mm, an axis), or `fallback` when the key is absent.
inline Eigen::Vector3d vector3(const Reader& r, const std::string& key, const Eigen::Vector3d& fallback) {
  if (!r.has(key)) return fallback;
  const auto& v = r.raw(key);
  if (!v.is_array() || v.size() != 3 || !std::all_of(v.begin(), v.end(), [](const nlohmann::json& x) {
        return x.is_number() && std::isfinite(x.get<double>());
      }))
    r.fail(key, "three finite numbers", v);
  return {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
}

}  // namespace tendril::server::detail
