#include "serial_arm/calibration_runner.hpp"

#include <algorithm>
#include <utility>

namespace tendril::server {

using nlohmann::json;

void CalibrationRunner::add(CalibrationStore::KindInfo info, Start start) {
  const std::string kind = info.kind;
  if (kind == "running" || kind == "last" || kind == "missing")
    throw CalibrationStoreError("calibration kind \"" + kind +
                                "\" clashes with a field of operating_state.calibration");
  store_.register_kind(std::move(info));  // throws for a duplicate or a bad name
  std::lock_guard lock(mutex_);
  routines_.emplace_back(kind, std::move(start));
}

std::vector<std::string> CalibrationRunner::kinds() const {
  std::lock_guard lock(mutex_);
  std::vector<std::string> out;
  for (const auto& [kind, start] : routines_) out.push_back(kind);
  return out;
}

bool CalibrationRunner::has(std::string_view kind) const {
  std::lock_guard lock(mutex_);
  return std::any_of(routines_.begin(), routines_.end(), [&](const auto& r) { return r.first == kind; });
}

std::optional<std::string> CalibrationRunner::run(std::string_view kind, const OperatingStateView& state) {
  Start start;
  std::optional<Outcome> previous;
  {
    std::lock_guard lock(mutex_);
    const auto it =
        std::find_if(routines_.begin(), routines_.end(), [&](const auto& r) { return r.first == kind; });
    if (it == routines_.end())
      return "calibrate: this robot has no calibration of kind \"" + std::string(kind) + "\"";
    if (running_)
      return "calibrate: the " + running_->kind + " calibration is running (step " +
             std::to_string(running_->step) + " of " + std::to_string(running_->steps) +
             "); wait for it to end";
    running_ = Progress{std::string(kind), 0, 0, "starting"};
    previous = std::move(last_);
    last_.reset();
    start = it->second;
  }
  // Called without the lock: the routine reports progress (or even finishes) from inside.
  auto refusal = start(state);
  if (refusal) {
    // A refused start ran nothing: the last routine's outcome stays what the operator sees.
    std::lock_guard lock(mutex_);
    running_.reset();
    last_ = std::move(previous);
  }
  return refusal;
}

void CalibrationRunner::progress(int step, int steps, std::string message) {
  std::lock_guard lock(mutex_);
  if (!running_) return;
  running_->step = step;
  running_->steps = steps;
  running_->message = std::move(message);
}

void CalibrationRunner::finish(bool ok, int version, std::string message) {
  std::lock_guard lock(mutex_);
  if (!running_) return;
  last_ = Outcome{running_->kind, ok, version, std::move(message)};
  running_.reset();
}

std::optional<CalibrationRunner::Progress> CalibrationRunner::running() const {
  std::lock_guard lock(mutex_);
  return running_;
}

std::optional<CalibrationRunner::Outcome> CalibrationRunner::last() const {
  std::lock_guard lock(mutex_);
  return last_;
}

json calibration_summary_json(const std::optional<CalibrationRecord>& r) {
  if (!r) return nullptr;
  return {{"version", r->version}, {"taken_unix_s", r->taken_unix_s}, {"taken_utc", r->taken_utc},
          {"valid", r->valid},     {"residual_mm", r->residual_mm},   {"summary", r->summary},
          {"method", r->method}};
}

json CalibrationRunner::state_json() const {
  json out = json::object();
  for (const auto& k : store_.kinds()) out[k.kind] = calibration_summary_json(store_.current(k.kind));
  json missing = json::array();
  for (const auto& k : store_.missing_required()) missing.push_back(k.kind);
  out["missing"] = std::move(missing);
  std::lock_guard lock(mutex_);
  out["running"] = running_ ? json{{"kind", running_->kind},
                                   {"step", running_->step},
                                   {"steps", running_->steps},
                                   {"message", running_->message}}
                            : json(nullptr);
  out["last"] = last_ ? json{{"kind", last_->kind},
                             {"ok", last_->ok},
                             {"version", last_->version},
                             {"message", last_->message}}
                      : json(nullptr);
  return out;
}

}  // namespace tendril::server
