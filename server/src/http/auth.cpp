// Who is calling: the bearer token, the console's cookie session or the ?token= of a WebSocket URL,
// the requested role, the lease token and the script's client name, resolved into an Identity.
#include <algorithm>
#include <cctype>
#include <unordered_set>
#include <utility>
#include <vector>

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

// The cookie sessions that have an open WebSocket now.
std::unordered_set<std::string> sessions_with_websockets(
    const std::vector<std::shared_ptr<WsConnectionBase>>& sockets) {
  std::unordered_set<std::string> out;
  for (const auto& socket : sockets) {
    if (!socket->identity().cookie_session.empty()) out.insert(socket->identity().cookie_session);
  }
  return out;
}

}  // namespace

// Makes room for a new cookie session: forgets the least recently used one that nobody can be relying
// on. A session that holds a lease, has an open WebSocket (`with_websockets`) or was used within the
// lease timeout is kept, so that opening pages with ?token= never logs the console out. False when
// every session is kept.
bool HttpServer::Impl::forget_a_session_locked(const std::unordered_set<std::string>& with_websockets) {
  const auto now = SteadyClock::now();
  std::vector<std::pair<SteadyClock::time_point, const std::string*>> idle;
  for (const auto& [id, session] : cookie_sessions) {
    if (now - session.last_used >= opts.lease_timeout && !with_websockets.count(id))
      idle.emplace_back(session.last_used, &id);
  }
  std::sort(idle.begin(), idle.end());
  for (const auto& [last_used, id] : idle) {
    if (leases.token_held_by("session:" + *id, now)) continue;
    const std::string forgotten = *id;  // a copy: the key must outlive its own erase
    cookie_sessions.erase(forgotten);
    return true;
  }
  return false;
}

HttpServer::Impl::AuthOutcome HttpServer::Impl::authenticate(const Request& req, const RequestTarget& target,
                                                             std::uint64_t connection_id,
                                                             bool accept_query_token,
                                                             bool create_cookie_session, bool websocket) {
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

  // X-Tendril-Client names a script in lease messages; it is a label, never a credential.
  std::string client_label;
  if (const auto it = req.find("X-Tendril-Client"); it != req.end()) {
    const std::string name(it->value());
    if (!valid_client_name(name)) {
      out.error =
          ApiResult::error(400, "bad_client_name",
                           "X-Tendril-Client must be 1-64 characters of letters, digits, '-', '_' or '.'");
      return out;
    }
    client_label = "client:" + name;
  }
  // The lease token from POST /api/v1/lease: a header, or ?lease= on a WebSocket URL (browsers and
  // Foxglove Studio cannot set headers there; REST ignores secrets in URLs, as it does ?token=). Any
  // value is a claim: one that is not the current lease's token holds nothing. It is never refused
  // here, so a stale or garbled token cannot stand between a caller and the e-stop.
  std::string lease_token;
  if (const auto it = req.find("X-Tendril-Lease"); it != req.end()) lease_token = std::string(it->value());
  if (const auto it = target.query.find("lease"); websocket && it != target.query.end())
    lease_token = it->second;
  // The lease key: a presented lease token wins; else the caller's own credential.
  auto set_identity = [&](Role role, std::string key, std::string label, bool connection_bound) {
    out.identity.role = role;
    if (!lease_token.empty()) {
      out.identity.lease_key = std::string(http::LeaseManager::kTokenKeyPrefix) + lease_token;
      out.identity.label = client_label.empty() ? "api-client" : client_label;
      return;
    }
    out.identity.lease_key = std::move(key);
    out.identity.label = client_label.empty() ? std::move(label) : client_label;
    out.identity.connection_bound = connection_bound;
  };
  // The bearer token alone: every such REST caller is one identity (they share the only credential
  // there is, so nothing else could tell them apart); a WebSocket connection is its own identity.
  auto token_identity = [&]() {
    if (websocket) {
      const std::string connection = "ws:" + std::to_string(connection_id);
      set_identity(asked, connection, connection, true);
    } else {
      set_identity(asked, "bearer", "api-client", false);
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
    connections.authenticated(connection_id);
    return out;
  }
  if (const auto it = req.find(bhttp::field::cookie); it != req.end()) {
    if (const auto session_id = cookie_value(it->value(), kCookieName)) {
      std::unique_lock lock(sessions_mutex);
      const auto session = cookie_sessions.find(*session_id);
      // Session ids are random and looked up by hash; an unknown one is simply not a credential.
      if (session != cookie_sessions.end()) {
        session->second.last_used = SteadyClock::now();
        set_identity(session->second.role == Role::kViewer ? Role::kViewer : asked, "session:" + *session_id,
                     session->second.label, false);
        out.identity.label = session->second.label;
        out.identity.cookie_session = *session_id;
        lock.unlock();
        connections.authenticated(connection_id);
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
      connections.authenticated(connection_id);
      if (!create_cookie_session) {
        token_identity();
        return out;
      }
      const std::string session_id = random_hex(16);
      const auto with_websockets = sessions_with_websockets(live_sessions());
      std::lock_guard lock(sessions_mutex);
      if (cookie_sessions.size() >= opts.max_sessions && !forget_a_session_locked(with_websockets)) {
        out.error = ApiResult::error(
            503, "too_many_sessions",
            "all " + std::to_string(opts.max_sessions) +
                " console sessions are in use (each holds a lease, has an open WebSocket or was used in "
                "the last " +
                std::to_string(opts.lease_timeout.count() / 1000) +
                " s); close a console tab, or open the console again in a moment");
        return out;
      }
      const std::string label = "session:" + std::to_string(next_session_label++);
      cookie_sessions[session_id] = {asked, label, SteadyClock::now()};
      set_identity(asked, "session:" + session_id, label, false);
      out.identity.label = label;
      out.identity.cookie_session = session_id;
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
