// REST routing: from a complete request and the connection it came on to the response message. No
// sockets here, so the routes compile once for plain and TLS connections and are tested without I/O.
#pragma once

#include <memory>
#include <optional>
#include <variant>

#include <boost/beast/http/empty_body.hpp>
#include <boost/beast/http/file_body.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>

#include "front_end.hpp"

namespace tendril::server {

using StringResponse = bhttp::response<bhttp::string_body>;
using RouteResult =
    std::variant<StringResponse, bhttp::response<bhttp::file_body>, bhttp::response<bhttp::empty_body>>;

StringResponse json_response(const Request& req, int status, const nlohmann::json& body);
StringResponse error_response(const Request& req, const ApiResult& result);

// Answers one request (REST, /metrics, static files). Never throws for a caller's mistake; an
// exception from ControlApi becomes 500.
RouteResult route_request(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id);

// What the front end decides once a request's header is read, before its body (http_session.hpp).
enum class RequestLane {
  kInline,    // on the I/O thread: the e-stop, /health, static files, the WebSocket upgrade
  kRequests,  // HttpServer::Impl::request_lane
  kUploads,   // HttpServer::Impl::upload_lane: large bodies and slow pictures
};
struct HeaderDecision {
  // The body limit of this route for this caller: large bodies (vessel files, plans, calibration
  // pictures) only for an authenticated operator on a route that takes them.
  std::size_t body_limit = 0;
  // Answer at once and close the connection without reading the body: a caller who may not send it
  // (no or a wrong token, a foreign origin, a viewer, a robot command without the robot's lease).
  std::optional<ApiResult> refusal;
  // The e-stop, latched the moment its header was read; answered once its body (ignored) is read.
  std::optional<ApiResult> estop;
  RequestLane lane = RequestLane::kRequests;
  // Held while a large body is read and worked on (HttpServer::Impl::large_bodies_in_flight).
  std::shared_ptr<void> large_body_slot;
};
// has_body: the header declares a body (a Content-Length above 0, or chunked).
HeaderDecision decide_header(HttpServer::Impl& server, const Request& header, bool has_body,
                             std::uint64_t connection_id);

// The checks of a WebSocket upgrade on /ws: path, origin, token, subprotocol.
struct UpgradeDecision {
  std::optional<StringResponse> refusal;
  Identity identity;
};
UpgradeDecision decide_upgrade(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id);

}  // namespace tendril::server
