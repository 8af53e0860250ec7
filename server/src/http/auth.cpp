// Who is calling: the bearer token, the console's cookie session or the ?token= of a WebSocket URL,
// the requested role and the script's client name, resolved into an Identity.
#include <algorithm>
#include <cctype>

#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;
using namespace tendril::server::http;

namespace {

bool valid_client_name(std::string_view name) {
  if (name.empty() || name.size() > 64) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == '.';
  });
}

}  // namespace

HttpServer::Impl::AuthOutcome HttpServer::Impl::authenticate(const Request& req, const RequestTarget& target,
                                                             std::uint64_t connection_id,
                                                             bool accept_query_token,
                                                             bool create_cookie_session,
                                                             const char* connection_kind) {
  AuthOutcome out;
  // Requested role: the header or ?role=; a session can only ever narrow to viewer, never widen.
  std::string requested_role;
  if (const auto it = req.find("X-Tendril-Role"); it != req.end()) requested_role = std::string(it->value());
  if (const auto it = target.query.find("role"); it != target.query.end()) requested_role = it->second;
  if (!requested_role.empty() && requested_role != "viewer" && requested_role != "operator") {
    out.error = ApiResult::error(400, "bad_role", "role must be \"viewer\" or \"operator\"");
    return out;
  }
  const Role asked = requested_role == "viewer" ? Role::kViewer : Role::kOperator;

  std::string client_name;
  if (const auto it = req.find("X-Tendril-Client"); it != req.end()) {
    client_name = std::string(it->value());
    if (!valid_client_name(client_name)) {
      out.error =
          ApiResult::error(400, "bad_client_name",
                           "X-Tendril-Client must be 1-64 characters of letters, digits, '-', '_' or '.'");
      return out;
    }
  }
  auto token_identity = [&]() {
    out.identity.role = asked;
    if (!client_name.empty()) {
      out.identity.lease_key = "client:" + client_name;
      out.identity.label = "client:" + client_name;
    } else {
      out.identity.lease_key = std::string(connection_kind) + ":" + std::to_string(connection_id);
      out.identity.label = out.identity.lease_key;
    }
  };

  if (const auto it = req.find(bhttp::field::authorization); it != req.end()) {
    const auto token = bearer_token(it->value());
    if (!token || !constant_time_equal(*token, opts.token)) {
      out.error = ApiResult::error(
          401, "bad_token",
          "the Authorization header must be \"Bearer <token>\" with the token tendrild printed "
          "at start-up");
      return out;
    }
    token_identity();
    return out;
  }
  if (const auto it = req.find(bhttp::field::cookie); it != req.end()) {
    if (const auto session_id = cookie_value(it->value(), kCookieName)) {
      std::lock_guard lock(sessions_mutex);
      const auto session = cookie_sessions.find(*session_id);
      // Session ids are random and looked up by hash; an unknown one is simply not a credential.
      if (session != cookie_sessions.end()) {
        out.identity.role = session->second.role == Role::kViewer ? Role::kViewer : asked;
        out.identity.lease_key = "session:" + *session_id;
        out.identity.label = session->second.label;
        if (!create_cookie_session || !target.query.count("token")) return out;
      }
    }
  }
  if (accept_query_token) {
    if (const auto it = target.query.find("token"); it != target.query.end()) {
      if (!constant_time_equal(it->second, opts.token)) {
        out.error = ApiResult::error(401, "bad_token", "the token in the URL is not this server's token");
        return out;
      }
      if (!create_cookie_session) {
        token_identity();
        return out;
      }
      const std::string session_id = random_hex(16);
      std::lock_guard lock(sessions_mutex);
      const std::string label = "session:" + std::to_string(next_session_label++);
      cookie_sessions[session_id] = {asked, label};
      cookie_order.push_back(session_id);
      while (cookie_order.size() > opts.max_sessions) {
        cookie_sessions.erase(cookie_order.front());
        cookie_order.pop_front();
      }
      out.identity.role = asked;
      out.identity.lease_key = "session:" + session_id;
      out.identity.label = label;
      out.set_cookie = std::string(kCookieName) + "=" + session_id + "; Path=/; HttpOnly; SameSite=Strict";
      return out;
    }
  }
  out.error =
      ApiResult::error(401, "missing_token",
                       "this call needs the access token: send \"Authorization: Bearer <token>\" or open the "
                       "console URL that tendrild printed");
  return out;
}

}  // namespace tendril::server
