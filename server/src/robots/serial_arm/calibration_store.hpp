// The calibration store of a robot (calibrations are persisted and versioned): one JSON
// file per kind and version in one directory, `<kind>-v<version>.json` (version 1, 2, …; zero-padded
// to six digits so that a directory listing sorts them). Each file holds the kind, the version, when it
// was taken (UTC), the robot's name, the method, the transform(s) as 4×4 homogeneous matrices in row
// order (translation in mm), scalar values (e.g. a pixel size), the residuals, whether it passed its
// validation, and a sentence for a person.
//
// At start every file is read. Per kind the newest version that parses, is rigid and passed its
// validation is the one in use; a file that does not parse (or holds a non-rigid transform, or is
// another robot's) is reported in problems() and never used, and its version number is never reused.
// save() writes a new version (one more than any file of that kind, readable or not) through a
// temporary file and a rename, so that a crash leaves either the old or the new file, never half of
// one; a calibration that failed its validation is stored too (the record of the attempt) but leaves
// the previous valid version in use.
//
// Kinds register themselves; a kind registered as required for a task (the sweep needs "robot" and
// "us") is listed by missing_required() until a valid version exists, with the command that makes it.
//
// Threads: every member may be called from any thread except the control thread (a mutex guards the
// in-memory state; save() does file I/O). The control thread gets the transforms it needs through the
// robot's own mailbox, never from here.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

namespace tendril::server {

// A store that cannot be set up (its directory cannot be made or read) or a calibration that cannot be
// saved (a non-rigid transform, an unknown kind, a failed write). The message is for a person.
class CalibrationStoreError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CalibrationRecord {
  std::string kind;
  int version = 0;                // assigned by save()
  std::int64_t taken_unix_s = 0;  // assigned by save() when 0
  std::string taken_utc;          // ISO 8601, from taken_unix_s
  std::string robot;
  std::string method;  // how it was made, a sentence or a reference (e.g. "Park–Martin + Gauss–Newton")
  // Named rigid transforms, e.g. "H_B^G" (base → global tracker frame). Translation in mm.
  std::map<std::string, Eigen::Isometry3d> transforms;
  std::map<std::string, double> values;  // scalars, e.g. "s_u_mm_per_px"
  double residual_mm = 0.0;              // the headline residual (kind-specific; see the summary)
  nlohmann::json residuals = nlohmann::json::object();  // details (rms, max, per-axis, …)
  bool valid = false;                                   // passed its validation: may be used
  std::string summary;                                  // a sentence for a person
};

// Checks that `transform` is finite and rigid (orthonormal rotation, det +1, last row 0 0 0 1, within
// 1e-6): nullopt when it is, else why not.
std::optional<std::string> rigid_transform_problem(const Eigen::Matrix4d& transform);

nlohmann::json to_json(const CalibrationRecord& record);
// Throws CalibrationStoreError naming the field when the document is not a calibration.
CalibrationRecord calibration_from_json(const nlohmann::json& document);

class CalibrationStore {
 public:
  struct KindInfo {
    std::string kind;
    std::string description;  // what it calibrates, for a person
    std::string command;      // the request that makes one, quoted in refusals
    bool required = false;    // the robot's sweep needs a valid one
  };

  // Makes `directory` if needed and loads every calibration file in it. Throws CalibrationStoreError
  // when the directory cannot be made or read.
  CalibrationStore(std::filesystem::path directory, std::string robot);

  // Registers a kind (set-up). Files of kinds not registered are still loaded and listed.
  void register_kind(KindInfo info);
  std::vector<KindInfo> kinds() const;

  // The version in use (newest valid), if any.
  std::optional<CalibrationRecord> current(std::string_view kind) const;
  // The newest version (valid or not) and the number of versions of a kind.
  std::optional<CalibrationRecord> newest(std::string_view kind) const;

  // Writes `record` as the kind's next version; a valid one becomes the one in use. Returns the stored
  // record (version and time filled in). Throws CalibrationStoreError for a kind that is not registered,
  // a non-rigid or non-finite transform, or a failed write.
  CalibrationRecord save(CalibrationRecord record);

  // Required kinds without a valid version, in registration order.
  std::vector<KindInfo> missing_required() const;
  // Files that were not used, each a sentence naming the file and why.
  std::vector<std::string> problems() const;
  const std::filesystem::path& directory() const noexcept { return directory_; }
  const std::string& robot() const noexcept { return robot_; }

  // The file name of a kind's version.
  static std::string file_name(std::string_view kind, int version);

 private:
  void load();

  std::filesystem::path directory_;
  std::string robot_;
  mutable std::mutex mutex_;
  std::vector<KindInfo> kinds_;
  std::map<std::string, CalibrationRecord, std::less<>> current_;  // newest valid per kind
  std::map<std::string, CalibrationRecord, std::less<>> newest_;   // newest readable per kind
  std::map<std::string, int, std::less<>> highest_version_;        // highest version seen, readable or not
  std::vector<std::string> problems_;
};

// The directory of a robot's store when its file names none: $TENDRIL_STATE_DIR/calibrations/<robot>,
// else $XDG_STATE_HOME/tendril/calibrations/<robot>, else $HOME/.local/state/tendril/calibrations/<robot>,
// else ./tendril-state/calibrations/<robot>.
std::filesystem::path default_calibration_directory(std::string_view robot);

}  // namespace tendril::server
