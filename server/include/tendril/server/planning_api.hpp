// PlanningApi: long computations a robot type offers over REST as jobs (never on the
// control thread) — vessel uploads, plans, designs, calibrations and the jobs that run them. The
// HTTP front end routes /vessels, /plans, /designs, /jobs and /robots/{robot}/calibrations to it
// (planning_routes.hpp); the steerable catheter's type provides the implementation.
#pragma once

#include <cstddef>
#include <map>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "tendril/server/control_api.hpp"

namespace tendril::server {

using QueryParameters = std::map<std::string, std::string>;

class PlanningApi {
 public:
  virtual ~PlanningApi() = default;

  // Largest vessel file accepted as a request body (uploads and plans with the file as body).
  virtual std::size_t max_vessel_bytes() const = 0;

  // POST /vessels: body = the file, content_type "text/csv" or "model/stl". 201 vessel summary.
  virtual ApiResult upload_vessel(std::string_view body, const std::string& content_type,
                                  const QueryParameters& query) = 0;
  virtual ApiResult vessels() const = 0;                                                    // GET /vessels
  virtual ApiResult vessel(const std::string& id, const QueryParameters& query) const = 0;  // GET one
  virtual ApiResult delete_vessel(const std::string& id) = 0;

  // POST /plans with the vessel file as body (query robot, branch | end, ds, dq1, design, name).
  virtual ApiResult submit_plan_file(std::string_view body, const std::string& content_type,
                                     const QueryParameters& query) = 0;
  // POST /plans with JSON {"robot","vessel","branch"|"end","ds","dq1","design"}. 202 job.
  virtual ApiResult submit_plan(const nlohmann::json& request) = 0;
  // POST /designs with JSON {"vessel","branch","flexure","robot"}. 202 job.
  virtual ApiResult submit_design(const nlohmann::json& request) = 0;

  virtual ApiResult jobs() const = 0;                       // GET /jobs (results left out)
  virtual ApiResult job(const std::string& id) const = 0;   // GET /jobs/{id}
  virtual ApiResult cancel_job(const std::string& id) = 0;  // DELETE /jobs/{id}

  // The result of a succeeded plan job, for loading into path following: 404 unknown job, 409 not
  // finished or not succeeded, 422 not a plan job.
  virtual ApiResult plan_result(const std::string& job_id) const = 0;

  // POST /robots/{robot}/calibrations (calibration_job.hpp). 202 job.
  virtual ApiResult submit_calibration(const std::string& robot, const nlohmann::json& request) = 0;
  // GET /robots/{robot}/calibration/side_view?segment=&actuation_mm=: a picture of the SIMULATED
  // calibration camera (robots on a virtual bus only), base64 PNG in JSON, ready for "images".
  virtual ApiResult simulated_side_view(const std::string& robot, const QueryParameters& query) = 0;

  // Stops the workers (running jobs are cancelled). Called before the runtime goes away.
  virtual void shutdown() {}
};

}  // namespace tendril::server
