// Private parts of the HTTP/WebSocket front end shared by its source files (one idea each):
//   http_server.cpp      the public HttpServer: start/stop, listener, I/O threads, publisher thread
//   byte_stream.hpp      one connection's byte stream, whatever the transport (stream_transport.hpp:
//                        plain TCP in byte_stream_tcp.cpp, TLS in byte_stream_tls.cpp)
//   http_session.hpp     one HTTP connection (read with limits, write, upgrade) over a ByteStream,
//                        instantiated once in http_session.cpp
//   request_reader.cpp   the bounded request parser every connection reads with
//   rest_routes.cpp      REST routing: a request and a caller in, a response out (no sockets)
//   auth.cpp             token, cookie sessions, roles and client names -> Identity
//   commands.cpp         command preamble (role, robot, lease), lease actions, parameters
//   ws_connection.cpp    Foxglove protocol per WebSocket connection (no sockets)
//   ws_session.hpp       the WebSocket transport over a ByteStream, instantiated once in ws_session.cpp
//   publisher.cpp        channels, topic publishing, status broadcasts, front-end metrics
//   services.cpp         the Foxglove services that mirror the REST commands
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl/context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <nlohmann/json.hpp>

#include "connection_limits.hpp"
#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/server/http/http_server.hpp"
#include "tendril/server/http/lease.hpp"
#include "tendril/server/http/request_codec.hpp"
#include "work_lane.hpp"

namespace tendril::server {

namespace net = boost::asio;
namespace bhttp = boost::beast::http;
namespace fg = tendril::server::http::foxglove;
using tcp = net::ip::tcp;
using SteadyClock = std::chrono::steady_clock;
using Request = bhttp::request<bhttp::string_body>;

inline constexpr std::string_view kCookieName = "tendril_session";

enum class Role { kViewer, kOperator };

// Who is calling: resolved once per request or per WebSocket connection (auth.cpp).
struct Identity {
  Role role = Role::kOperator;
  // Private: what a lease this caller takes is bound to, and how it is recognised as the holder
  // (LeaseManager lists the kinds): the cookie session, the lease token it presents, the bearer
  // token, or its own WebSocket connection. Embeds secrets; never shown.
  std::string lease_key;
  std::string label;  // public name shown as lease holder (X-Tendril-Client is only ever a label)
  // lease_key is this WebSocket connection: a lease bound to it ends when the connection closes.
  bool connection_bound = false;
  // Private: the cookie session the caller came with (empty without one), so that a session with an
  // open WebSocket is never forgotten to make room for a new one.
  std::string cookie_session;
};

// Robot commands as the front end dispatches them. kAuthorizeOnly: the role and lease checks of a
// robot command, for routes dispatched elsewhere (planning_routes.cpp); answers 200 {} when they pass.
// kRobotCommand: one of a robot type's own commands, named in CommandRef::name.
enum class Command {
  kStateCommand,
  kMode,
  kMoveJp,
  kServoJv,
  kMoveCp,
  kServoCp,
  kServoCv,
  kRobotCommand,
  kEstop,
  kEstopReset,
  kAuthorizeOnly
};
struct CommandRef {
  Command kind = Command::kAuthorizeOnly;
  std::string name;                   // the robot type's command (kRobotCommand)
  CommandRef(Command k) : kind(k) {}  // NOLINT(google-explicit-constructor)
  CommandRef(Command k, std::string n) : kind(k), name(std::move(n)) {}
};
// The CRTK commands every robot is addressed with (REST POST /robots/{robot}/<name>).
const std::map<std::string, Command>& core_robot_commands();

// Services mirror the REST commands (services.cpp): the core ones, then one per robot-type command
// name. Request: {"robot":..., ...REST body}; response: {"status":..,"body"|"error"}.
struct ServiceDef {
  std::uint32_t id;
  std::string name;
  std::optional<CommandRef> command;  // nullopt = lease
  bool needs_robot;
  nlohmann::json request_schema;
};
std::vector<ServiceDef> service_definitions(const ControlApi& api);
std::vector<fg::Service> service_list(const std::vector<ServiceDef>& definitions);

std::string random_hex(std::size_t bytes);
std::string dump(const nlohmann::json& value);
std::uint64_t wall_time_ns();
ApiResult unknown_robot_result(const std::string& robot);

// What a WebSocket connection offers the rest of the front end (ws_connection.hpp implements it).
class WsConnectionBase {
 public:
  virtual ~WsConnectionBase() = default;
  virtual std::uint64_t id() const = 0;
  virtual const Identity& identity() const = 0;
  virtual void send_text(const nlohmann::json& message) = 0;
  virtual void offer(std::uint32_t channel_id, const std::shared_ptr<const std::string>& payload,
                     std::uint64_t time_ns,
                     std::optional<std::uint32_t> only_subscription = std::nullopt) = 0;
  virtual void offer_parameter_updates(const nlohmann::json& changed) = 0;
  virtual void subscribed_channels(std::set<std::uint32_t>& out) const = 0;
  virtual void drop_channels(const std::vector<std::uint32_t>& removed) = 0;
  virtual HttpServer::ConnectionStats stats() const = 0;
  virtual void hard_close() = 0;  // from any thread: posts to the connection's strand
};

class HttpServer::Impl {
 public:
  Impl(ControlApi& api_in, HttpOptions options_in);

  ControlApi& api;
  HttpOptions opts;
  http::RobotLeases leases;        // one operator lease per robot
  std::mutex lease_actions_mutex;  // acquire, takeover and release across several robots are atomic
  const std::vector<ServiceDef> service_defs;
  const std::vector<fg::Service> services;
  const std::string server_session_id = random_hex(8);
  const SteadyClock::time_point started_at = SteadyClock::now();
  std::vector<std::string> allowed_origins;
  unsigned short bound_port = 0;
  std::string openapi_document;                    // served at GET /api/v1/openapi.json; read at start()
  std::unique_ptr<net::ssl::context> tls_context;  // set when a certificate and key are configured

  // Cookie sessions: random id -> role and public label. Bounded (opts.max_sessions): a new one
  // replaces the least recently used session that holds no lease, has no open WebSocket and was not
  // used within the lease timeout; with none, the new one is refused (auth.cpp).
  struct CookieSession {
    Role role;
    std::string label;
    SteadyClock::time_point last_used{};
  };
  mutable std::mutex sessions_mutex;
  std::unordered_map<std::string, CookieSession> cookie_sessions;
  bool forget_a_session_locked(const std::unordered_set<std::string>& with_websockets);
  std::uint64_t next_session_label = 1;

  // Channels advertised to WebSocket clients; ids are never reused.
  struct ChannelState {
    fg::Channel channel;
    std::uint64_t version = 0;
    std::shared_ptr<const std::string> last_payload;
    std::uint64_t last_time_ns = 0;
    TopicSource* source = nullptr;  // null: the topic comes from ControlApi
  };
  // Topics of opts.topic_sources (fixed at construction: a source's topics are stable).
  std::map<std::string, std::pair<TopicSource*, TopicInfo>> source_topics;
  bool sources_ready = false;         // a source has a new message; guarded by lifecycle_mutex
  mutable std::mutex channels_mutex;  // lock order: channels_mutex, then ws_mutex
  std::map<std::uint32_t, ChannelState> channels;
  std::map<std::string, std::uint32_t> topic_ids;
  std::vector<std::string> last_topics;
  std::uint32_t next_channel_id = 1;
  std::mutex publish_mutex;
  // Which source topics have subscribers, as last told to their source (guarded by publish_mutex).
  std::map<std::string, bool> source_demand;

  mutable std::mutex ws_mutex;
  std::map<std::uint64_t, std::weak_ptr<WsConnectionBase>> ws_sessions;

  // Metrics.
  std::atomic<std::uint64_t> ws_sent{0}, ws_dropped{0}, ws_bytes{0}, ws_connections_total{0},
      ws_client_messages{0}, ws_violations{0}, ws_closed_for_abuse{0}, ws_closed_for_backlog{0};
  // Exceptions that reached a connection's handler (that connection was closed; the server went on).
  std::atomic<std::uint64_t> connection_exceptions{0};
  // Requests refused while being read (framing, size limits, trailers), by reason.
  mutable std::mutex status_mutex;
  std::map<int, std::uint64_t> http_by_status;
  std::map<std::string, std::uint64_t> refused_requests;
  std::atomic<std::uint64_t> next_connection_id{1};
  // More Prometheus text for GET /metrics (HttpServer::add_metrics_source; fixed once started).
  std::vector<std::function<std::string()>> metrics_sources;

  // Runtime.
  std::unique_ptr<net::io_context> ioc;
  // Where requests' work runs, off the I/O threads (work_lane.hpp): ordinary requests, and large
  // uploads and slow pictures. Made in start(), stopped in stop() before the I/O threads.
  std::unique_ptr<http::WorkLane> request_lane;
  std::unique_ptr<http::WorkLane> upload_lane;
  // Large bodies being read or waiting for their work (at most upload_threads + upload_queue): each
  // may be up to the largest body limit, so their number bounds the memory uploads can take.
  std::atomic<std::size_t> large_bodies_in_flight{0};
  std::unique_ptr<tcp::acceptor> acceptor;
  // Connection limits (connection_limits.hpp), fixed in start().
  ConnectionRegistry connections;
  // The slot of the connection do_accept is starting: its HttpSession::run() takes it, on the same
  // thread, before start_*_http_session returns (the session's constructor has no room for it).
  std::shared_ptr<ConnectionSlot> accepted_slot;
  // Descriptor exhaustion: the back-off before the next accept, and a descriptor held in reserve so
  // that the listener can still take a waiting client and close it (rather than leave it hanging).
  std::unique_ptr<net::steady_timer> accept_timer;
  int spare_descriptor = -1;
  std::atomic<std::uint64_t> accept_backoffs{0}, accepted_and_closed{0};
  std::vector<std::thread> io_threads;
  std::thread publisher;
  std::mutex lifecycle_mutex;
  std::condition_variable publisher_wake;
  bool running = false;
  bool stopping = false;

  void count_status(int status) {
    std::lock_guard lock(status_mutex);
    ++http_by_status[status];
  }
  void count_refused(const std::string& reason) {
    std::lock_guard lock(status_mutex);
    ++refused_requests[reason];
  }
  // A connection's handler threw: count it and log it (the caller closes that connection).
  void connection_failed(std::uint64_t connection_id, const char* where, const char* what) noexcept;
  void log(const std::string& line) const noexcept;

  struct AuthOutcome {
    std::optional<ApiResult> error;
    Identity identity;
    std::optional<std::string> set_cookie;
  };
  AuthOutcome authenticate(const Request& req, const http::RequestTarget& target, std::uint64_t connection_id,
                           bool accept_query_token, bool create_cookie_session, bool websocket);

  // Runs a robot command after the preamble (role, robot, lease), and hands it with its outcome to
  // the publish tap when there is one (a recording).
  ApiResult execute(const CommandRef& command, const std::string& robot, const nlohmann::json& body,
                    const Identity& who);
  ApiResult execute_checked(const CommandRef& command, const std::string& robot, const nlohmann::json& body,
                            const Identity& who);
  // action: "acquire" (with an optional takeover token), "release" or "status"; of one robot's lease,
  // or of every robot's when `robot` is empty (POST /api/v1/lease).
  ApiResult lease_action(const std::string& action, const Identity& who,
                         const std::string& takeover_token = {}, const std::string& robot = {});
  // The leases of `robots` as `who` sees them. lease_token: set in the answer that grants the lease (its
  // holder's secret), empty otherwise.
  nlohmann::json lease_description(const Identity& who, SteadyClock::time_point now,
                                   const std::vector<std::string>& robots,
                                   const std::string& lease_token = {}) const;
  // 409 lease_held for a caller that does not hold `robot`'s lease, saying who does and what to do.
  ApiResult lease_refusal(const Identity& who, SteadyClock::time_point now, const std::string& robot,
                          const std::string& what) const;
  // Renews the leases of `robots` for `who`, or the refusal for the first one it does not hold.
  std::optional<ApiResult> use_leases(const Identity& who, SteadyClock::time_point now,
                                      const std::vector<std::string>& robots, const std::string& what);
  // "the operator lease", or "the operator lease of ur5" / "of srmc and ur5" on a server of several robots.
  std::string lease_phrase(const std::vector<std::string>& robots) const;
  // Where to take a lease: the robot's own route, or /api/v1/lease for every robot.
  static std::string lease_route(const std::string& robot);
  // Sets parameters for `who` (operator with the lease) and pushes the new values to subscribers.
  ApiResult set_parameters(const nlohmann::json& parameters, const Identity& who);
  void publish_parameter_updates(const nlohmann::json& changed);

  // Servo streaming, for the takeover rule: a holder who sent a servo command within the longest
  // command timeout of any robot is streaming and cannot be displaced. Recorded per robot and lease
  // generation, since one lease may be used under several keys (its token and its owner's key).
  struct ServoSeen {
    std::uint64_t generation = 0;
    SteadyClock::time_point time{};
  };
  std::mutex servo_mutex;
  std::map<std::string, ServoSeen> last_servo;  // robot -> last servo command
  std::chrono::milliseconds servo_window{150};
  void note_servo(const std::string& robot, std::uint64_t generation, SteadyClock::time_point now) {
    std::lock_guard lock(servo_mutex);
    last_servo[robot] = {generation, now};
  }
  bool servo_streaming(const std::string& robot, std::uint64_t generation, SteadyClock::time_point now) {
    std::lock_guard lock(servo_mutex);
    const auto it = last_servo.find(robot);
    return it != last_servo.end() && it->second.generation == generation &&
           now - it->second.time <= servo_window;
  }
  // A WebSocket connection closed: stop the robots whose lease it held, and end the leases bound to it.
  void connection_closed(const Identity& who);

  // Status messages to WebSocket clients: to all, or only to the sockets whose lease key is listed.
  void broadcast_status(const nlohmann::json& status, const std::vector<std::string>& only_lease_keys = {});
  // Faults and e-stops seen in ControlApi::faults() become status messages (newest seen so far).
  std::optional<std::string> newest_event_seen;
  void report_new_safety_events();

  void refresh_channels();
  bool channel_exists(std::uint32_t id) const {
    std::lock_guard lock(channels_mutex);
    return channels.count(id) != 0;
  }
  // Latest payload of a channel, for a new subscriber (null when none yet).
  std::shared_ptr<const std::string> channel_payload(std::uint32_t id, std::uint64_t& time_ns) const;
  void register_ws(std::uint64_t id, const std::weak_ptr<WsConnectionBase>& session,
                   std::vector<fg::Channel>& channels_now);
  void unregister_ws(std::uint64_t id);
  std::vector<std::shared_ptr<WsConnectionBase>> live_sessions() const;
  // only_sources: publish the topic sources' new messages only (a source said one is ready), so that
  // robot topics keep their publish_rate_hz.
  void publish_once(bool only_sources = false);
  // Tells each topic source which of its topics have subscribers now (TopicSource::set_demand).
  void tell_sources_demand(const std::set<std::uint32_t>& wanted);
  void do_accept();
  void accept_connection(tcp::socket socket);
  void on_descriptors_exhausted();
  void run_io() noexcept;  // an I/O thread: io_context::run(), re-entered after a stray exception
  std::string metrics() const;
  // The largest body any route takes (vessel files may exceed max_body_bytes).
  std::size_t largest_body_limit() const;
};

// Start serving one accepted TCP connection (byte_stream_tcp.cpp, byte_stream_tls.cpp).
void start_plain_http_session(tcp::socket&& socket, HttpServer::Impl& server);
void start_tls_http_session(tcp::socket&& socket, HttpServer::Impl& server);
// Start serving one connection over its byte stream, whatever the transport (http_session.cpp).
class ByteStream;
void start_http_session(ByteStream&& stream, HttpServer::Impl& server);

}  // namespace tendril::server
