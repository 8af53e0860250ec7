// The calibration routines of a robot (network threads): each kind registers with the robot's
// CalibrationStore (calibration_store.hpp) and names a routine that starts it; POST …/calibrate
// {"kind": k} runs `start` of that kind. At most one routine runs at a time per robot.
//
// A routine's life: begin() (here, before `start` is called; refused when another runs) → `start`
// returns nullopt when it has started (it goes on in its own thread, or on the control thread through
// the robot's mailbox) or a sentence why it cannot (the API answers 409 with it and nothing runs) →
// progress() any number of times from any thread → finish(ok, message) exactly once. The last routine's
// outcome stays in last() until the next one begins; the store holds the result.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "serial_arm/calibration_store.hpp"
#include "tendril/server/robot_service.hpp"

namespace tendril::server {

class CalibrationRunner {
 public:
  // Starts the routine (network thread, the operator's lease already checked; `state` is the robot's
  // operating state): nullopt when started, else the sentence of the refusal.
  using Start = std::function<std::optional<std::string>(const OperatingStateView& state)>;

  struct Progress {
    std::string kind;
    int step = 0, steps = 0;
    std::string message;
  };
  struct Outcome {
    std::string kind;
    bool ok = false;
    int version = 0;  // the version saved (0: none)
    std::string message;
  };

  explicit CalibrationRunner(CalibrationStore& store) : store_(store) {}

  // Set-up: registers the kind with the store and its routine.
  void add(CalibrationStore::KindInfo info, Start start);
  std::vector<std::string> kinds() const;
  bool has(std::string_view kind) const;

  // Runs the kind's routine: nullopt when started, else why not (another routine runs, unknown kind,
  // or the routine's own refusal).
  std::optional<std::string> run(std::string_view kind, const OperatingStateView& state);

  // From the routine, any thread.
  void progress(int step, int steps, std::string message);
  void finish(bool ok, int version, std::string message);

  std::optional<Progress> running() const;
  std::optional<Outcome> last() const;
  CalibrationStore& store() noexcept { return store_; }
  const CalibrationStore& store() const noexcept { return store_; }

  // operating_state's "calibration" object: {"<kind>": null | {"version","taken_unix_s","taken_utc",
  // "valid","residual_mm","summary","method"}, …, "running": null | {"kind","step","steps","message"},
  // "last": null | {"kind","ok","version","message"}, "missing": [kinds required and not valid]}.
  nlohmann::json state_json() const;

 private:
  CalibrationStore& store_;
  mutable std::mutex mutex_;
  std::vector<std::pair<std::string, Start>> routines_;
  std::optional<Progress> running_;
  std::optional<Outcome> last_;
};

// A calibration record as operating_state shows it (null when absent).
nlohmann::json calibration_summary_json(const std::optional<CalibrationRecord>& record);

}  // namespace tendril::server
