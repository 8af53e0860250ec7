// REST routes of planning and path following: /vessels, /plans, /designs,
// /jobs and /robots/{robot}/path_following. HttpServer::Impl::handle_api hands every request it does
// not route itself to route_planning(); this file owns the paths, methods and roles of these routes.
#pragma once

#include <cstddef>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "tendril/server/control_api.hpp"
#include "tendril/server/planning_api.hpp"

namespace tendril::server::http {

struct PlanningCall {
  std::string_view method;                          // "GET", "POST", "DELETE", …
  const std::vector<std::string>& route;            // path segments after /api/v1
  const std::map<std::string, std::string>& query;  // decoded query parameters
  std::string_view content_type;
  std::string_view body;
  std::size_t max_json_bytes;  // ordinary JSON bodies
  bool operator_role;          // viewers may read but not upload, plan or cancel
  // The role and lease check every robot command passes (same answers as the other commands);
  // nullopt when the caller may command `robot`.
  std::function<std::optional<ApiResult>(const std::string& robot)> authorize_command;
};

struct PlanningReply {
  ApiResult result;
  std::string location;  // Location header for 201/202, empty for none
  std::string allow;     // Allow header for 405, empty for none
};

// nullopt when the route is not a planning route. `planning` may be null (no planning service):
// then only the path-following routes that need no job answer.
std::optional<PlanningReply> route_planning(PlanningApi* planning, ControlApi& api, const PlanningCall& call);

// (method, path template) of every route above, for HttpServer::api_routes() and the OpenAPI check.
std::vector<std::pair<std::string, std::string>> planning_route_list();

// Whether a request to `path` may carry a vessel file or a whole plan as its body (the body limit is
// then PlanningApi::max_vessel_bytes() instead of HttpOptions::max_body_bytes).
bool takes_large_body(std::string_view method, std::string_view path);

}  // namespace tendril::server::http
