#include "rest_routes.hpp"

#include <filesystem>

#include "tendril/server/http/planning_routes.hpp"
#include "tendril/server/version.hpp"

namespace tendril::server {

namespace beast = boost::beast;
using nlohmann::json;
using namespace tendril::server::http;

StringResponse json_response(const Request& req, int status, const json& body) {
  StringResponse res{static_cast<bhttp::status>(status), req.version()};
  res.set(bhttp::field::server, "tendril");
  res.set(bhttp::field::content_type, "application/json");
  res.set(bhttp::field::cache_control, "no-store");
  res.keep_alive(req.keep_alive());
  res.body() = dump(body);
  res.prepare_payload();
  return res;
}

StringResponse error_response(const Request& req, const ApiResult& result) {
  return json_response(req, result.status, result.error_json());
}

namespace {

StringResponse result_response(const Request& req, const ApiResult& result) {
  return result.ok() ? json_response(req, result.status, result.body) : error_response(req, result);
}

StringResponse method_not_allowed(const Request& req, const char* allow) {
  auto res =
      error_response(req, ApiResult::error(405, "method_not_allowed",
                                           std::string(req.method_string()) + " is not allowed on " +
                                               std::string(req.target().substr(0, req.target().find('?'))) +
                                               "; allowed: " + allow));
  res.set(bhttp::field::allow, allow);
  return res;
}

bool origin_refused(const HttpServer::Impl& server, const Request& req) {
  // A request has one origin (RFC 6454 §7.3): two Origin fields are refused, whatever they say, since a
  // check of one and a proxy or handler reading the other could disagree.
  const auto [first, end] = req.equal_range(bhttp::field::origin);
  if (first == end) return false;
  if (std::next(first) != end) return true;
  return !origin_allowed(first->value(), server.allowed_origins);
}

StringResponse origin_refusal(const Request& req) {
  return error_response(req, ApiResult::error(403, "origin_not_allowed",
                                              "Origin \"" + std::string(req[bhttp::field::origin]) +
                                                  "\" is not in the allowlist"));
}

// REST getters under /api/v1/robots/{robot}/... (the commands: core_robot_commands() and the robot
// types' own, ControlApi::robot_commands()).
using Getter = ApiResult (ControlApi::*)(const std::string&) const;
const std::map<std::string, Getter>& robot_getters() {
  static const std::map<std::string, Getter> getters = {
      {"measured_js", &ControlApi::measured_js},         {"setpoint_js", &ControlApi::setpoint_js},
      {"measured_cp", &ControlApi::measured_cp},         {"measured_cv", &ControlApi::measured_cv},
      {"measured_cf", &ControlApi::measured_cf},         {"shape", &ControlApi::shape},
      {"operating_state", &ControlApi::operating_state}, {"schema", &ControlApi::robot_schema}};
  return getters;
}

RouteResult handle_metrics(HttpServer::Impl& server, const Request& req, const RequestTarget& target,
                           std::uint64_t connection_id) {
  if (req.method() != bhttp::verb::get) return method_not_allowed(req, "GET");
  if (origin_refused(server, req)) return origin_refusal(req);
  auto auth = server.authenticate(req, target, connection_id, false, false, /*websocket=*/false);
  if (auth.error) return error_response(req, *auth.error);
  StringResponse res{bhttp::status::ok, req.version()};
  res.set(bhttp::field::content_type, "text/plain; version=0.0.4");
  res.set(bhttp::field::cache_control, "no-store");
  res.keep_alive(req.keep_alive());
  std::string control = server.api.metrics();
  if (!control.empty() && control.back() != '\n') control.push_back('\n');
  res.body() = control + server.metrics();
  res.prepare_payload();
  return res;
}

// /api/v1/lease (every robot's lease) and /api/v1/robots/{robot}/lease (one robot's).
StringResponse handle_lease(HttpServer::Impl& server, const Request& req, const Identity& who,
                            const std::string& robot = {}) {
  const auto method = req.method();
  if (method == bhttp::verb::get) return result_response(req, server.lease_action("status", who, {}, robot));
  if (method == bhttp::verb::post) {
    const ApiResult body = parse_json_body(req.body(), server.opts.max_body_bytes);
    if (!body.ok()) return error_response(req, body);
    std::string takeover_token;
    if (const auto it = body.body.find("takeover_token"); it != body.body.end()) {
      if (!it->is_string()) {
        return error_response(req,
                              ApiResult::error(400, "bad_request",
                                               "\"takeover_token\" must be the string from the 409 answer"));
      }
      takeover_token = it->get<std::string>();
    }
    return result_response(req, server.lease_action("acquire", who, takeover_token, robot));
  }
  if (method == bhttp::verb::delete_)
    return result_response(req, server.lease_action("release", who, {}, robot));
  return method_not_allowed(req, "GET, POST, DELETE");
}

RouteResult handle_api(HttpServer::Impl& server, const Request& req, const RequestTarget& target,
                       std::uint64_t connection_id) {
  const auto segments = split_path(target.path);
  const auto method = req.method();
  if (segments.size() < 2 || segments[1] != "v1") {
    return error_response(req, ApiResult::error(404, "not_found", "the API lives under /api/v1"));
  }
  const std::vector<std::string> route(segments.begin() + 2, segments.end());
  if (route == std::vector<std::string>{"health"}) {
    if (method != bhttp::verb::get) return method_not_allowed(req, "GET");
    const double uptime = std::chrono::duration<double>(SteadyClock::now() - server.started_at).count();
    nlohmann::json body = server.opts.health_details;
    body.update({{"status", "ok"}, {"version", version()}, {"uptime_s", uptime}});
    return json_response(req, 200, body);
  }
  // Public like /health: it documents the interface (the same file is in the repository) and
  // reveals no state, so API tools can read it before they have a token.
  if (route == std::vector<std::string>{"openapi.json"}) {
    if (method != bhttp::verb::get) return method_not_allowed(req, "GET");
    if (server.openapi_document.empty()) {
      return error_response(req, ApiResult::error(404, "not_found",
                                                  "the OpenAPI document is not installed with this server "
                                                  "(server/openapi/openapi.json)"));
    }
    StringResponse res{bhttp::status::ok, req.version()};
    res.set(bhttp::field::server, "tendril");
    res.set(bhttp::field::content_type, "application/json");
    res.set(bhttp::field::cache_control, "no-cache");
    res.keep_alive(req.keep_alive());
    res.body() = server.openapi_document;
    res.prepare_payload();
    return res;
  }
  // A browser page from another origin must not drive the robot with a stolen cookie or token.
  if (origin_refused(server, req)) return origin_refusal(req);
  auto auth = server.authenticate(req, target, connection_id, false, false, /*websocket=*/false);
  if (auth.error) return error_response(req, *auth.error);
  const Identity& who = auth.identity;
  auto& api = server.api;

  if (route == std::vector<std::string>{"robots"}) {
    if (method != bhttp::verb::get) return method_not_allowed(req, "GET");
    return json_response(req, 200, api.robots());
  }
  if (route == std::vector<std::string>{"faults"}) {
    if (method != bhttp::verb::get) return method_not_allowed(req, "GET");
    std::size_t max_events = 200;
    if (const auto it = target.query.find("max"); it != target.query.end()) {
      char* end = nullptr;
      const long value = std::strtol(it->second.c_str(), &end, 10);
      if (it->second.empty() || *end != '\0' || value < 1 || value > 10000) {
        return error_response(req, ApiResult::error(400, "bad_parameter", "max must be an integer 1..10000"));
      }
      max_events = static_cast<std::size_t>(value);
    }
    return json_response(req, 200, api.faults(max_events));
  }
  if (route == std::vector<std::string>{"replay"}) {
    if (method != bhttp::verb::get && method != bhttp::verb::put) return method_not_allowed(req, "GET, PUT");
    if (!server.opts.replay) {
      return error_response(req,
                            ApiResult::error(404, "not_replaying",
                                             "this server runs live; start tendrild --replay FILE_OR_FOLDER "
                                             "to replay a recording"));
    }
    if (method == bhttp::verb::get) return result_response(req, server.opts.replay->replay_status());
    if (who.role != Role::kOperator) {
      return error_response(req, ApiResult::error(403, "forbidden_role",
                                                  "this session is a viewer (read-only); only operators "
                                                  "control the replay"));
    }
    const ApiResult body = parse_json_body(req.body(), server.opts.max_body_bytes);
    if (!body.ok()) return error_response(req, body);
    return result_response(req, server.opts.replay->control_replay(body.body));
  }
  if (route == std::vector<std::string>{"lease"}) return handle_lease(server, req, who);
  if (route == std::vector<std::string>{"estop"} || route == std::vector<std::string>{"estop", "reset"}) {
    if (method != bhttp::verb::post) return method_not_allowed(req, "POST");
    if (route.size() == 1) {
      // Safety first: the e-stop ignores the body and the lease, and works for viewers too.
      return result_response(req, server.execute(Command::kEstop, {}, json::object(), who));
    }
    const ApiResult body = parse_json_body(req.body(), server.opts.max_body_bytes);
    if (!body.ok()) return error_response(req, body);
    return result_response(req, server.execute(Command::kEstopReset, {}, body.body, who));
  }
  if (route.size() == 3 && route[0] == "robots" && route[2] == "lease") {
    if (!api.has_robot(route[1])) return error_response(req, unknown_robot_result(route[1]));
    return handle_lease(server, req, who, route[1]);
  }
  if (route.size() == 3 && route[0] == "robots") {
    const std::string& robot = route[1];
    const std::string& verb = route[2];
    const auto& getters = robot_getters();
    const auto& commands = core_robot_commands();
    if (const auto getter = getters.find(verb); getter != getters.end()) {
      if (method != bhttp::verb::get) return method_not_allowed(req, "GET");
      if (!api.has_robot(robot)) return error_response(req, unknown_robot_result(robot));
      return result_response(req, (api.*(getter->second))(robot));
    }
    std::optional<CommandRef> command;
    if (const auto core = commands.find(verb); core != commands.end()) {
      command = CommandRef(core->second);
    } else if (api.has_robot(robot)) {
      for (const auto& info : api.robot_commands(robot))
        if (info.name == verb) command = CommandRef(Command::kRobotCommand, verb);
    }
    if (command) {
      if (method != bhttp::verb::post) return method_not_allowed(req, "POST");
      if (!api.has_robot(robot)) return error_response(req, unknown_robot_result(robot));
      const ApiResult body = parse_json_body(req.body(), server.opts.max_body_bytes);
      if (!body.ok()) return error_response(req, body);
      return result_response(req, server.execute(*command, robot, body.body, who));
    }
  }
  if (!route.empty() && route[0] == "imaging") {
    // The segmentation editor: anyone reads; a change needs the imaged robot's lease, like a command.
    const bool params = route.size() >= 2 && route[1] == "segmentation";
    const bool roadmap = route.size() == 3 && route[1] == "roadmap";
    if ((params && route.size() <= 3) || roadmap) {
      if (params && route.size() == 2 && method != bhttp::verb::get) return method_not_allowed(req, "GET");
      if (params && route.size() == 3 && method != bhttp::verb::put) return method_not_allowed(req, "PUT");
      if (roadmap && method != bhttp::verb::post) return method_not_allowed(req, "POST");
      if (!server.opts.imaging)
        return error_response(req,
                              ApiResult::error(503, "imaging_unavailable", "this server runs no imaging"));
      ImagingControl& imaging = *server.opts.imaging;
      if (route.size() == 2) return result_response(req, imaging.segmentation());
      if (route[2] != "ap" && route[2] != "lateral")
        return error_response(
            req, ApiResult::error(404, "unknown_plane",
                                  "no imaging plane \"" + route[2] + "\"; the planes are ap and lateral"));
      const ApiResult allowed = server.execute(Command::kAuthorizeOnly, imaging.imaged_robot(), {}, who);
      if (!allowed.ok()) return error_response(req, allowed);
      if (roadmap) return result_response(req, imaging.take_roadmap(route[2]));
      const ApiResult body = parse_json_body(req.body(), server.opts.max_body_bytes);
      if (!body.ok()) return error_response(req, body);
      return result_response(req, imaging.set_segmentation(route[2], body.body));
    }
  }
  const PlanningCall planning_call{req.method_string(),
                                   route,
                                   target.query,
                                   req[bhttp::field::content_type],
                                   req.body(),
                                   server.opts.max_body_bytes,
                                   who.role == Role::kOperator,
                                   [&](const std::string& robot) -> std::optional<ApiResult> {
                                     auto allowed = server.execute(Command::kAuthorizeOnly, robot, {}, who);
                                     return allowed.ok() ? std::nullopt : std::optional<ApiResult>(allowed);
                                   }};
  if (auto planned = route_planning(server.opts.planning, api, planning_call)) {
    auto res = result_response(req, planned->result);
    if (!planned->location.empty()) res.set(bhttp::field::location, planned->location);
    if (!planned->allow.empty()) res.set(bhttp::field::allow, planned->allow);
    return res;
  }
  return error_response(
      req, ApiResult::error(404, "not_found",
                            "no endpoint " + std::string(req.method_string()) + " " + target.path));
}

RouteResult handle_static(HttpServer::Impl& server, const Request& req, const RequestTarget& target,
                          std::uint64_t connection_id) {
  if (req.method() != bhttp::verb::get && req.method() != bhttp::verb::head) {
    return method_not_allowed(req, "GET, HEAD");
  }
  // Opening the console URL with ?token= turns the token into a session cookie.
  std::optional<std::string> set_cookie;
  if (target.query.count("token")) {
    auto auth = server.authenticate(req, target, connection_id, true, true, /*websocket=*/false);
    if (auth.error) return error_response(req, *auth.error);
    set_cookie = auth.set_cookie;
  }
  // Longest matching mount wins; the web root serves everything else.
  std::string prefix;
  std::string root;
  for (const auto& [mount, dir] : server.opts.static_mounts) {
    if (target.path.rfind(mount, 0) == 0 && mount.size() > prefix.size()) {
      prefix = mount;
      root = dir;
    }
  }
  if (root.empty() && !server.opts.web_root.empty()) {
    prefix = "/";
    root = server.opts.web_root;
  }
  std::optional<std::filesystem::path> file;
  if (!root.empty()) file = resolve_static_path(root, target.path, prefix);
  std::error_code fs_error;
  if (file && std::filesystem::is_directory(*file, fs_error)) *file /= "index.html";
  bhttp::file_body::value_type body;
  beast::error_code ec;
  if (file && std::filesystem::is_regular_file(*file, fs_error))
    body.open(file->c_str(), beast::file_mode::scan, ec);
  if (!file || !body.is_open() || ec) {
    return error_response(req, ApiResult::error(404, "not_found", "no file at " + target.path));
  }
  const auto size = body.size();
  const auto content_type = mime_type(file->string());
  auto decorate = [&](auto& res) {
    res.set(bhttp::field::server, "tendril");
    res.set(bhttp::field::content_type, content_type);
    res.set("X-Content-Type-Options", "nosniff");
    res.set("Referrer-Policy", "no-referrer");
    res.set(bhttp::field::cache_control, "no-cache");
    if (set_cookie) res.set(bhttp::field::set_cookie, *set_cookie);
    res.content_length(size);
    res.keep_alive(req.keep_alive());
  };
  if (req.method() == bhttp::verb::head) {
    bhttp::response<bhttp::empty_body> res{bhttp::status::ok, req.version()};
    decorate(res);
    return res;
  }
  bhttp::response<bhttp::file_body> res{std::piecewise_construct, std::make_tuple(std::move(body)),
                                        std::make_tuple(bhttp::status::ok, req.version())};
  decorate(res);
  return res;
}

RouteResult dispatch(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id) {
  const RequestTarget target = parse_target(req.target());
  if (!target.valid)
    return error_response(req, ApiResult::error(400, "bad_request", "malformed request target"));
  const std::string& path = target.path;
  if (path == "/api" || path.rfind("/api/", 0) == 0) return handle_api(server, req, target, connection_id);
  if (path == "/metrics") return handle_metrics(server, req, target, connection_id);
  if (path == "/ws") {
    return error_response(req, ApiResult::error(426, "upgrade_required",
                                                "/ws is a WebSocket endpoint (foxglove.websocket.v1)"));
  }
  return handle_static(server, req, target, connection_id);
}

}  // namespace

RouteResult route_request(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id) {
  try {
    return dispatch(server, req, connection_id);
  } catch (const std::exception& e) {
    // A throwing ControlApi must not take the connection down with it.
    return error_response(req, ApiResult::error(500, "internal_error", e.what()));
  }
}

namespace {

ApiResult origin_error(const Request& header) {
  return ApiResult::error(
      403, "origin_not_allowed",
      "Origin \"" + std::string(header[bhttp::field::origin]) + "\" is not in the allowlist");
}

// The caller a header names, or nullopt with out.refusal set (a foreign origin, no or a wrong token).
std::optional<Identity> caller_from_header(HttpServer::Impl& server, const Request& header,
                                           const RequestTarget& target, std::uint64_t connection_id,
                                           HeaderDecision& out) {
  if (origin_refused(server, header)) {
    out.refusal = origin_error(header);
    return std::nullopt;
  }
  auto auth = server.authenticate(header, target, connection_id, false, false, /*websocket=*/false);
  if (auth.error) {
    out.refusal = std::move(auth.error);
    return std::nullopt;
  }
  return std::move(auth.identity);
}

// GET /api/v1/robots/{robot}/calibration/side_view renders a picture (about half a second).
bool slow_picture(const std::vector<std::string>& route) {
  return route.size() == 4 && route[0] == "robots" && route[2] == "calibration" && route[3] == "side_view";
}

// Routes under /api/v1/robots/{robot}/ whose POST needs that robot's lease: the core commands, the robot
// type's own and path following (ControlApi::robot_commands; planning_routes.cpp).
bool needs_robot_lease(HttpServer::Impl& server, const std::vector<std::string>& route) {
  if (route.size() < 3 || route[0] != "robots") return false;
  const std::string& verb = route[2];
  if (route.size() == 3 && core_robot_commands().count(verb) != 0) return true;
  if (verb == "path_following") return route.size() == 3 || (route.size() == 4 && route[3] == "step");
  if (route.size() != 3 || !server.api.has_robot(route[1])) return false;
  for (const auto& info : server.api.robot_commands(route[1]))
    if (info.name == verb) return true;
  return false;
}

}  // namespace

HeaderDecision decide_header(HttpServer::Impl& server, const Request& header, bool has_body,
                             std::uint64_t connection_id) {
  HeaderDecision out;
  out.body_limit = server.opts.max_body_bytes;
  const RequestTarget target = parse_target(header.target());
  if (!target.valid) return out;  // route_request answers 400
  if (target.path != "/api" && target.path.rfind("/api/", 0) != 0) {
    out.lane = target.path == "/metrics" ? RequestLane::kRequests : RequestLane::kInline;
    return out;
  }
  const auto segments = split_path(target.path);
  if (segments.size() < 2 || segments[1] != "v1") return out;
  const std::vector<std::string> route(segments.begin() + 2, segments.end());
  const auto method = header.method();
  if (route == std::vector<std::string>{"health"} || route == std::vector<std::string>{"openapi.json"}) {
    out.lane = RequestLane::kInline;
    return out;
  }
  if (route == std::vector<std::string>{"estop"} && method == bhttp::verb::post) {
    // Safety first: the e-stop is latched now, before its body is read or any other request's work.
    out.lane = RequestLane::kInline;
    auto who = caller_from_header(server, header, target, connection_id, out);
    if (who) out.estop = server.execute(Command::kEstop, {}, json::object(), *who);
    return out;
  }
  if (method == bhttp::verb::get || method == bhttp::verb::head) {
    out.lane = slow_picture(route) ? RequestLane::kUploads : RequestLane::kRequests;
    return out;
  }
  const bool large = takes_large_body(header.method_string(), target.path);
  out.lane = large ? RequestLane::kUploads : RequestLane::kRequests;
  // Without a body there is nothing to hold back: the route answers as usual. With one, whoever may
  // not send it is refused now, before its bytes are read or parsed.
  if (!has_body) return out;
  const auto caller = caller_from_header(server, header, target, connection_id, out);
  if (!caller) return out;
  if (server.opts.replay) return out;  // every command answers 409 replay_mode, whoever sends it
  const Identity& who = *caller;
  if (who.role != Role::kOperator) {
    out.refusal = ApiResult::error(403, "forbidden_role",
                                   "this session is a viewer (read-only): it reads and may press the "
                                   "e-stop, but sends no " +
                                       std::string(header.method_string()) + " " + target.path);
    return out;
  }
  if (needs_robot_lease(server, route)) {
    if (!server.api.has_robot(route[1])) {
      out.refusal = unknown_robot_result(route[1]);
      return out;
    }
    ApiResult allowed = server.execute(Command::kAuthorizeOnly, route[1], {}, who);
    if (!allowed.ok()) {
      out.refusal = std::move(allowed);
      return out;
    }
  }
  if (large && server.opts.planning != nullptr) {
    const std::size_t most =
        static_cast<std::size_t>(std::max(1, server.opts.upload_threads)) + server.opts.upload_queue;
    if (server.large_bodies_in_flight.fetch_add(1) >= most) {
      --server.large_bodies_in_flight;
      out.refusal = ApiResult::error(503, "server_busy",
                                     "the server is already receiving or working on " + std::to_string(most) +
                                         " large requests (vessel files, plans, calibration pictures); send "
                                         "this one again when one of them has finished");
      return out;
    }
    out.large_body_slot =
        std::shared_ptr<void>(nullptr, [&server](void*) { --server.large_bodies_in_flight; });
    out.body_limit = server.largest_body_limit();
  }
  return out;
}

UpgradeDecision decide_upgrade(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id) {
  UpgradeDecision out;
  const RequestTarget target = parse_target(req.target());
  if (!target.valid || target.path != "/ws") {
    out.refusal = error_response(req, ApiResult::error(404, "not_found", "WebSocket endpoint is /ws"));
    return out;
  }
  if (origin_refused(server, req)) {
    out.refusal = error_response(
        req,
        ApiResult::error(403, "origin_not_allowed",
                         req.count(bhttp::field::origin) > 1
                             ? std::string("a WebSocket handshake may carry one Origin header, not several")
                             : "WebSocket Origin \"" + std::string(req[bhttp::field::origin]) +
                                   "\" is not in the allowlist"));
    return out;
  }
  auto auth = server.authenticate(req, target, connection_id, /*accept_query_token=*/true,
                                  /*create_cookie_session=*/false, /*websocket=*/true);
  if (auth.error) {
    out.refusal = error_response(req, *auth.error);
    return out;
  }
  const auto offered = split_header_list(req[bhttp::field::sec_websocket_protocol]);
  if (std::find(offered.begin(), offered.end(), fg::kSubprotocol) == offered.end()) {
    out.refusal =
        error_response(req, ApiResult::error(400, "subprotocol_required",
                                             "offer WebSocket subprotocol \"foxglove.websocket.v1\""));
    return out;
  }
  out.identity = std::move(auth.identity);
  return out;
}

std::vector<HttpServer::Route> HttpServer::api_routes() {
  // What handle_api dispatches itself (the planning routes are added by planning_routes.cpp).
  std::vector<Route> routes = {
      {"GET", "/api/v1/health"},   {"GET", "/api/v1/openapi.json"}, {"GET", "/api/v1/robots"},
      {"GET", "/api/v1/faults"},   {"GET", "/api/v1/lease"},        {"POST", "/api/v1/lease"},
      {"DELETE", "/api/v1/lease"}, {"POST", "/api/v1/estop"},       {"POST", "/api/v1/estop/reset"},
  };
  for (const char* verb : {"GET", "POST", "DELETE"}) routes.push_back({verb, "/api/v1/robots/{robot}/lease"});
  for (const auto& [verb, getter] : robot_getters())
    routes.push_back({"GET", "/api/v1/robots/{robot}/" + verb});
  for (const auto& [verb, command] : core_robot_commands())
    routes.push_back({"POST", "/api/v1/robots/{robot}/" + verb});
  routes.push_back({"POST", "/api/v1/robots/{robot}/{command}"});  // the robot types' own commands
  for (const auto& [verb, path] : planning_route_list()) routes.push_back({verb, path});
  routes.push_back({"GET", "/api/v1/imaging/segmentation"});
  routes.push_back({"PUT", "/api/v1/imaging/segmentation/{plane}"});
  routes.push_back({"POST", "/api/v1/imaging/roadmap/{plane}"});
  routes.push_back({"GET", "/api/v1/replay"});
  routes.push_back({"PUT", "/api/v1/replay"});
  return routes;
}

}  // namespace tendril::server
