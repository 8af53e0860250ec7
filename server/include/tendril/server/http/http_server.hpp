// HttpServer: the REST + WebSocket front end of tendrild (Boost.Beast), on one port.
//
// - REST under /api/v1 mapped onto ControlApi; GET /metrics at the root; static console files.
// - WebSocket /ws speaking Foxglove WebSocket protocol v1 (subprotocol "foxglove.websocket.v1").
//
// Access:
// - Every call but GET /api/v1/health and static files needs the token: `Authorization: Bearer <token>`,
//   the session cookie `tendril_session` (set when a page is requested with `?token=`; it holds a random
//   session id, never the token), or `?token=` on the WebSocket URL.
// - Roles: a token holder is an operator. `?role=viewer` (page or WS URL; sticks to the cookie session) or
//   the header `X-Tendril-Role: viewer` makes the session read-only: viewers get 403 `forbidden_role` on
//   commands and on the lease, but may still trigger the e-stop (safety first).
// - Lease: one operator commands a robot at a time (each robot has its own lease, RobotLeases), and
//   holding it takes a secret (lease.hpp): the cookie
//   session; the lease token POST /api/v1/lease answers (`X-Tendril-Lease`, or `?lease=` on the WS
//   URL); for REST callers with the bearer token alone, the bearer token (so plain curl keeps its
//   lease across connections); for a WebSocket with neither, the connection (its lease ends with it).
//   `X-Tendril-Client` is a label only. A WebSocket shares its cookie session's identity, so a console
//   that took the lease over REST also holds it on its socket. The lease expires `lease_timeout` after
//   it was taken or last used by a command. When a WebSocket holding the lease closes,
//   ControlApi::operator_lost(robot) is called for each robot whose lease it held (servo stops).
// - Browsers: WebSocket handshakes and REST calls that carry an Origin header must come from an allowed
//   origin (403 otherwise); a missing Origin (non-browser client) is allowed.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "tendril/server/control_api.hpp"
#include "tendril/server/http/publish_tap.hpp"
#include "tendril/server/imaging_control.hpp"
#include "tendril/server/replay_control.hpp"
#include "tendril/server/topic_source.hpp"

namespace tendril::server {

class PlanningApi;

struct HttpOptions {
  std::string host = "127.0.0.1";
  unsigned short port = 8080;  // 0 = any free port; see HttpServer::port()
  std::string token;           // required, never empty
  // Origins allowed for browsers. Empty = the server's own origin http://host:port (plus
  // http://localhost:port and http://127.0.0.1:port when bound to loopback, the same machine).
  std::vector<std::string> allowed_origins;
  std::string web_root;      // static console files; empty = none
  std::string openapi_file;  // served at GET /api/v1/openapi.json; empty = not served (404)
  // HTTPS and WSS on the same port when both are set (PEM files); plain HTTP otherwise.
  std::string tls_certificate_file;
  std::string tls_private_key_file;
  std::map<std::string, std::string> static_mounts;     // URL prefix -> directory, e.g. "/vendor/three/"
  std::size_t max_body_bytes = std::size_t{64} * 1024;  // REST request bodies (413 above)
  std::size_t max_ws_message_bytes =
      std::size_t{64} * 1024;  // client WebSocket messages (connection closed above)
  int io_threads = 2;
  // Requests' work runs off the I/O threads, which only read and write (and answer the e-stop the
  // moment its header is read): ordinary requests on request_threads, large uploads (vessels, plans,
  // calibration pictures) and slow pictures on upload_threads. A full queue answers 503 server_busy.
  int request_threads = 2;
  std::size_t request_queue = 256;
  int upload_threads = 1;
  std::size_t upload_queue = 4;
  double publish_rate_hz = 50;  // topic publishing; <= 0 = no publisher thread (call publish_once())
  std::chrono::milliseconds lease_timeout{30000};
  // Client WebSocket message rate limit (token bucket) and how many protocol violations
  // (malformed messages, rate excess) a connection may commit before it is closed.
  double ws_client_rate_hz = 200;
  double ws_client_burst = 400;
  int ws_max_violations = 20;
  std::size_t ws_max_control_queue = 256;  // queued JSON messages per connection before it is closed
  // A connection whose write has waited this long has stopped reading (its backlog is full): it is
  // closed and counted rather than later flushing seconds of stale frames from the kernel buffer.
  std::chrono::milliseconds ws_stalled_write_timeout{5000};
  std::size_t ws_max_subscriptions = 256;
  // Cookie sessions kept. When full, a new one replaces the least recently used session that holds no
  // lease, has no open WebSocket and was not used within lease_timeout; with none, it is refused (503).
  std::size_t max_sessions = 1024;
  // Connection limits (server/src/http/README.md, "Limits"). 0 = derived from the process's descriptor
  // limit (RLIMIT_NOFILE, whose soft limit start() raises toward the hard limit, at most 65536): total
  // = min(4096, limit - descriptor_reserve), unauthenticated = 3/4 of the total. A new connection beyond
  // a limit closes the oldest idle unauthenticated one (of its own address at the per-address limit),
  // or is closed at once when there is none; authenticated connections are never closed for room.
  std::size_t max_connections = 0;
  std::size_t max_unauthenticated_connections = 0;
  std::size_t max_unauthenticated_per_address = 64;
  // Descriptors kept for the rest of the process: files, the CAN bus, DDS, recordings.
  std::size_t descriptor_reserve = 256;
  // Until authenticated, a connection must send each request header (the first one, TLS handshake
  // included, counted from the accept) within handshake_timeout; an authenticated connection may idle
  // idle_timeout between requests (a WebSocket: no frame for idle_timeout, a ping at half of it).
  std::chrono::seconds handshake_timeout{10};
  std::chrono::seconds idle_timeout{60};
  // After the process ran out of descriptors (EMFILE, ENFILE, ENOBUFS, ENOMEM) with no idle
  // unauthenticated connection to close, the listener waits this long before it accepts again,
  // instead of spinning on the error (after closing one it retries 1 ms later).
  std::chrono::milliseconds accept_backoff{50};
  // Planning, jobs and vessel uploads (planning_routes.hpp); null = those routes answer 503. Vessel
  // files may be up to PlanningApi::max_vessel_bytes() (413 above).
  PlanningApi* planning = nullptr;
  // Topics from outside ControlApi (imaging, maps), advertised and published next to the robots'
  // with the same newest-only backpressure; a source's ready callback publishes its topics at once.
  std::vector<std::shared_ptr<TopicSource>> topic_sources;
  // The segmentation editor and roadmaps (/api/v1/imaging/…); null = those routes answer 503.
  std::shared_ptr<ImagingControl> imaging;
  // Replay mode (tendrild --replay): GET/PUT /api/v1/replay, and every robot command (the e-stop and
  // its reset too: no robot is driven) is refused with 409 replay_mode. Null = a live server; the
  // /replay routes answer 404 not_replaying.
  std::shared_ptr<ReplayControl> replay;
  // A second reader of every channel, message and command (e.g. the session recording); null = none.
  std::shared_ptr<http::PublishTap> tap;
  // More fields of GET /api/v1/health, fixed at start-up (the control thread's real-time priority).
  nlohmann::json health_details = nlohmann::json::object();
  // Where the front end logs (refused connections, contained exceptions); null = standard error.
  std::function<void(const std::string&)> log;
};

// Set-up failure (port taken, bad address, missing token). The message is written for a person.
class HttpServerError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class HttpServer {
 public:
  // Per-connection view for tests and metrics.
  struct ConnectionStats {
    std::uint64_t id = 0;
    std::size_t queued_messages = 0;  // control messages + newest-only data slots waiting to be written
    std::size_t subscriptions = 0;
    bool write_in_flight = false;
    std::uint64_t dropped = 0;
  };

  HttpServer(ControlApi& api, HttpOptions options);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  // Binds and starts the I/O threads and the publisher. Throws HttpServerError.
  void start();
  // Closes the listener and every connection, joins all threads. Safe to call twice.
  void stop();
  // Bound port (useful with port 0). Valid after start().
  unsigned short port() const;
  // True when serving HTTPS/WSS (a certificate and key were configured).
  bool tls() const;
  // Prometheus text of the front end: clients, WS messages sent/dropped, HTTP responses by status.
  std::string metrics() const;
  // Asks ControlApi for every subscribed topic's message once and queues it to subscribers. The
  // publisher thread calls this at publish_rate_hz; tests call it directly to step time.
  void publish_once();
  std::vector<ConnectionStats> connection_stats() const;

  // A robot command from another front end of this server (the DDS bridge), checked exactly like
  // POST /api/v1/robots/{robot}/{command} from an operator who sends `lease_token` as X-Tendril-Lease:
  // the robot, the lease, then ControlApi's checks of shape, sizes, finiteness and limits; recorded
  // by the tap like a REST command. `command` is a core CRTK command (state_command, mode, move_jp,
  // servo_jv, ...) or one of the robot type's own; `client` is the caller's public label (lease
  // holder, event log). Thread-safe; never called from the control thread.
  ApiResult command(const std::string& robot, const std::string& command, const nlohmann::json& body,
                    const std::string& lease_token, const std::string& client);
  // Prometheus text that another part of the server appends to GET /metrics (e.g. the DDS bridge's
  // counters). Call before start(); throws HttpServerError after.
  void add_metrics_source(std::function<std::string()> source);

  // The REST routes this front end dispatches (method, path template with {robot}), for the test
  // that holds the OpenAPI document to what is served.
  struct Route {
    std::string method;
    std::string path;
  };
  static std::vector<Route> api_routes();

  class Impl;  // implementation detail (declared public so the connection classes can name it)

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::server
