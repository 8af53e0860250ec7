// Planning service behind /api/v1/vessels, /plans, /designs, /jobs and the shape calibration jobs:
// a bounded store of uploaded vessel centerlines (CSV, or STL meshes whose centerline is extracted) and
// path-plan / design jobs on a JobQueue. Everything here runs on network or worker threads, never on the
// real-time thread.
//
// PlanningApi is what the HTTP front end calls (it only needs this header, which pulls in no
// algorithm headers); PlanningService implements it with the teleop planner.
#pragma once

#include <cstddef>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/server/config.hpp"
#include "tendril/server/control_api.hpp"
#include "tendril/server/planning_api.hpp"

namespace tendril::server {

struct PlanningOptions {
  std::size_t workers = 1;  // planning threads; the default leaves a 2-core PC's other core to control
  std::size_t max_pending_jobs = 8;
  std::size_t max_finished_jobs = 32;
  std::size_t max_vessels = 16;                          // the oldest upload is forgotten first
  std::size_t max_vessel_bytes = std::size_t{32} << 20;  // per file (413 above)
  // All stored centerlines together (the oldest upload is forgotten first; one vessel larger than this
  // is refused with 413). A 28 MiB CSV of 750 000 points keeps 23 MiB; an STL keeps only its centerline.
  std::size_t max_stored_vessel_bytes = std::size_t{256} << 20;
  std::size_t max_vessel_branches = 1000;  // a file that splits into more is refused (400 bad_vessel)
};

class PlanningService final : public PlanningApi {
 public:
  // `robots`: the configured robots; plans are made for those whose kinematics is the SRMC's
  // constant-curvature catheter, within their joint limits.
  PlanningService(std::vector<RobotConfig> robots, PlanningOptions options = {});
  ~PlanningService() override;
  PlanningService(const PlanningService&) = delete;
  PlanningService& operator=(const PlanningService&) = delete;

  std::size_t max_vessel_bytes() const override;
  ApiResult upload_vessel(std::string_view body, const std::string& content_type,
                          const QueryParameters& query) override;
  ApiResult vessels() const override;
  ApiResult vessel(const std::string& id, const QueryParameters& query) const override;
  ApiResult delete_vessel(const std::string& id) override;
  ApiResult submit_plan_file(std::string_view body, const std::string& content_type,
                             const QueryParameters& query) override;
  ApiResult submit_plan(const nlohmann::json& request) override;
  ApiResult submit_design(const nlohmann::json& request) override;
  ApiResult jobs() const override;
  ApiResult job(const std::string& id) const override;
  ApiResult cancel_job(const std::string& id) override;
  ApiResult plan_result(const std::string& job_id) const override;
  ApiResult submit_calibration(const std::string& robot, const nlohmann::json& request) override;
  ApiResult simulated_side_view(const std::string& robot, const QueryParameters& query) override;

  // Stops the workers (running jobs are cancelled). Called before the runtime goes away.
  void shutdown() override;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::server
