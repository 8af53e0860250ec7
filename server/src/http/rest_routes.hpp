// REST routing: from a complete request and the connection it came on to the response message. No
// sockets here, so the routes compile once for plain and TLS connections and are tested without I/O.
#pragma once

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

// Whether the request's route may carry a large body (vessel file, plan) and the caller is
// authenticated: only then is the body limit raised above HttpOptions::max_body_bytes.
bool admits_large_body(HttpServer::Impl& server, const Request& header, std::uint64_t connection_id);

// The checks of a WebSocket upgrade on /ws: path, origin, token, subprotocol.
struct UpgradeDecision {
  std::optional<StringResponse> refusal;
  Identity identity;
};
UpgradeDecision decide_upgrade(HttpServer::Impl& server, const Request& req, std::uint64_t connection_id);

}  // namespace tendril::server
