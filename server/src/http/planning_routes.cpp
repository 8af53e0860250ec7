#include "tendril/server/http/planning_routes.hpp"

#include <algorithm>
#include <cctype>

#include "tendril/server/http/request_codec.hpp"

namespace tendril::server::http {

namespace {

using Route = std::vector<std::string>;

PlanningReply reply(ApiResult result) { return {std::move(result), {}, {}}; }

PlanningReply method_not_allowed(const PlanningCall& call, const char* allow) {
  std::string path = "/api/v1";
  for (const auto& s : call.route) path += "/" + s;
  return {ApiResult::error(405, "method_not_allowed",
                           std::string(call.method) + " is not allowed on " + path + "; allowed: " + allow),
          {},
          allow};
}

ApiResult viewer_refused() {
  return ApiResult::error(403, "forbidden_role", "this session is a viewer (read-only); only operators plan");
}

ApiResult unknown_robot(const std::string& robot) {
  return ApiResult::error(404, "unknown_robot",
                          "no robot named \"" + robot + "\"; GET /api/v1/robots lists them");
}

ApiResult no_planning() {
  return ApiResult::error(503, "planning_unavailable", "this server runs no planning service");
}

bool is_json(std::string_view content_type) {
  std::string m(content_type.substr(0, content_type.find(';')));
  std::transform(m.begin(), m.end(), m.begin(), [](unsigned char c) { return std::tolower(c); });
  m.erase(0, m.find_first_not_of(" \t"));
  m.erase(m.find_last_not_of(" \t") + 1);
  return m.empty() || m == "application/json";
}

// 202 jobs point at themselves.
PlanningReply job_reply(ApiResult result) {
  PlanningReply out = reply(std::move(result));
  if (out.result.ok() && out.result.body.contains("id"))
    out.location = "/api/v1/jobs/" + out.result.body["id"].get<std::string>();
  return out;
}

std::optional<PlanningReply> route_path_following(PlanningApi* planning, ControlApi& api,
                                                  const PlanningCall& call) {
  const Route& r = call.route;
  const std::string& robot = r[1];
  if (!api.has_robot(robot)) return reply(unknown_robot(robot));
  if (r.size() == 3) {
    if (call.method == "GET") return reply(api.path_following(robot));
    if (call.method != "POST") return method_not_allowed(call, "GET, POST");
  } else if (call.method != "POST") {
    return method_not_allowed(call, "POST");
  }
  if (auto refused = call.authorize_command(robot)) return reply(*refused);
  const std::size_t limit =
      planning != nullptr && r.size() == 3 ? planning->max_vessel_bytes() : call.max_json_bytes;
  const ApiResult body = parse_json_body(call.body, limit);
  if (!body.ok()) return reply(body);
  if (r.size() == 4) return reply(api.path_step(robot, body.body));
  // Load: {"plan": "<job id>"} or {"plan": {"steps": […]}}.
  const auto& b = body.body;
  if (!b.contains("plan") || !(b["plan"].is_string() || b["plan"].is_object()))
    return reply(
        ApiResult::error(400, "bad_request",
                         "expected {\"plan\": \"<id of a succeeded plan job>\"} or {\"plan\": {\"steps\": "
                         "[{\"q\": [insertion, roll, proximal_bend, distal_bend]}, …]}}"));
  if (b["plan"].is_object()) return reply(api.load_path(robot, b["plan"], {}));
  if (planning == nullptr) return reply(no_planning());
  const auto id = b["plan"].get<std::string>();
  const ApiResult plan = planning->plan_result(id);
  if (!plan.ok()) return reply(plan);
  if (plan.body.value("robot", robot) != robot)
    return reply(ApiResult::error(422, "wrong_robot",
                                  "plan " + id + " was made for robot '" +
                                      plan.body["robot"].get<std::string>() + "', not '" + robot + "'"));
  return reply(api.load_path(robot, plan.body, id));
}

// Shape calibration: a fit job from tangent data, outlines or pictures, and the SIMULATED camera.
std::optional<PlanningReply> route_calibration(PlanningApi* planning, ControlApi& api,
                                               const PlanningCall& call) {
  const Route& r = call.route;
  const std::string& robot = r[1];
  if (!api.has_robot(robot)) return reply(unknown_robot(robot));
  if (r.size() == 4) {
    if (call.method != "GET") return method_not_allowed(call, "GET");
    if (planning == nullptr) return reply(no_planning());
    return reply(planning->simulated_side_view(robot, call.query));
  }
  if (call.method != "POST") return method_not_allowed(call, "POST");
  if (!call.operator_role)
    return reply(ApiResult::error(403, "forbidden_role",
                                  "this session is a viewer (read-only); only operators calibrate"));
  if (planning == nullptr) return reply(no_planning());
  const ApiResult body = parse_json_body(call.body, planning->max_vessel_bytes());
  if (!body.ok()) return reply(body);
  return job_reply(planning->submit_calibration(robot, body.body));
}

}  // namespace

std::optional<PlanningReply> route_planning(PlanningApi* planning, ControlApi& api,
                                            const PlanningCall& call) {
  const Route& r = call.route;
  if (r.empty()) return std::nullopt;
  if (r[0] == "robots" && (r.size() == 3 || r.size() == 4) && r[2] == "path_following" &&
      (r.size() == 3 || r[3] == "step"))
    return route_path_following(planning, api, call);
  if (r[0] == "robots" && ((r.size() == 3 && r[2] == "calibrations") ||
                           (r.size() == 4 && r[2] == "calibration" && r[3] == "side_view")))
    return route_calibration(planning, api, call);
  const bool ours = r[0] == "vessels" || r[0] == "plans" || r[0] == "designs" || r[0] == "jobs";
  if (!ours || r.size() > 2) return std::nullopt;
  if (planning == nullptr) return reply(no_planning());
  const bool get = call.method == "GET", post = call.method == "POST", del = call.method == "DELETE";
  if ((post || del) && !call.operator_role) return reply(viewer_refused());

  if (r[0] == "vessels" && r.size() == 1) {
    if (get) return reply(planning->vessels());
    if (!post) return method_not_allowed(call, "GET, POST");
    PlanningReply out = reply(planning->upload_vessel(call.body, std::string(call.content_type), call.query));
    if (out.result.ok()) out.location = "/api/v1/vessels/" + out.result.body["id"].get<std::string>();
    return out;
  }
  if (r[0] == "vessels") {
    if (get) return reply(planning->vessel(r[1], call.query));
    if (del) return reply(planning->delete_vessel(r[1]));
    return method_not_allowed(call, "GET, DELETE");
  }
  if (r[0] == "plans" && r.size() == 1) {
    if (!post) return method_not_allowed(call, "POST");
    if (!is_json(call.content_type))
      return job_reply(planning->submit_plan_file(call.body, std::string(call.content_type), call.query));
    const ApiResult body = parse_json_body(call.body, call.max_json_bytes);
    if (!body.ok()) return reply(body);
    return job_reply(planning->submit_plan(body.body));
  }
  if (r[0] == "designs" && r.size() == 1) {
    if (!post) return method_not_allowed(call, "POST");
    const ApiResult body = parse_json_body(call.body, call.max_json_bytes);
    if (!body.ok()) return reply(body);
    return job_reply(planning->submit_design(body.body));
  }
  if (r[0] == "jobs" && r.size() == 1) {
    if (!get) return method_not_allowed(call, "GET");
    return reply(planning->jobs());
  }
  if (r[0] == "jobs") {
    if (get) return reply(planning->job(r[1]));
    if (del) return reply(planning->cancel_job(r[1]));
    return method_not_allowed(call, "GET, DELETE");
  }
  return std::nullopt;
}

std::vector<std::pair<std::string, std::string>> planning_route_list() {
  return {{"GET", "/api/v1/vessels"},
          {"POST", "/api/v1/vessels"},
          {"GET", "/api/v1/vessels/{id}"},
          {"DELETE", "/api/v1/vessels/{id}"},
          {"POST", "/api/v1/plans"},
          {"POST", "/api/v1/designs"},
          {"GET", "/api/v1/jobs"},
          {"GET", "/api/v1/jobs/{id}"},
          {"DELETE", "/api/v1/jobs/{id}"},
          {"GET", "/api/v1/robots/{robot}/path_following"},
          {"POST", "/api/v1/robots/{robot}/path_following"},
          {"POST", "/api/v1/robots/{robot}/path_following/step"},
          {"POST", "/api/v1/robots/{robot}/calibrations"},
          {"GET", "/api/v1/robots/{robot}/calibration/side_view"}};
}

bool takes_large_body(std::string_view method, std::string_view path) {
  if (method != "POST") return false;
  const auto segments = split_path(path);
  if (segments.size() == 3 && segments[0] == "api" && segments[1] == "v1")
    return segments[2] == "vessels" || segments[2] == "plans";
  // Whole plans, and calibration pictures (base64 in JSON).
  return segments.size() == 5 && segments[0] == "api" && segments[1] == "v1" && segments[2] == "robots" &&
         (segments[4] == "path_following" || segments[4] == "calibrations");
}

}  // namespace tendril::server::http
