// HTTP + WebSocket front end (Boost.Beast advanced-server pattern: one port, upgrade on /ws).
// Threads: `io_threads` run the io_context (one strand per connection); one publisher thread asks
// ControlApi for topic messages and hands them to the connections. No code here runs in the RT path.
#include "tendril/server/http/http_server.hpp"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <thread>
#include <unordered_map>
#include <variant>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket.hpp>
#include <boost/beast/websocket/ssl.hpp>

#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/server/http/lease.hpp"
#include "tendril/server/http/planning_routes.hpp"
#include "tendril/server/http/request_codec.hpp"
#include "tendril/server/version.hpp"

namespace tendril::server {

namespace beast = boost::beast;
namespace bhttp = boost::beast::http;
namespace websocket = boost::beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using nlohmann::json;
using namespace tendril::server::http;
namespace fg = tendril::server::http::foxglove;

namespace {

using Request = bhttp::request<bhttp::string_body>;
// A connection is plain TCP, or TLS when the server has a certificate (same code for both).
using TlsStream = beast::ssl_stream<beast::tcp_stream>;
using ByteStream = std::variant<beast::tcp_stream, TlsStream>;
using PlainWs = websocket::stream<beast::tcp_stream>;
using TlsWs = websocket::stream<TlsStream>;
using SteadyClock = std::chrono::steady_clock;

constexpr std::string_view kCookieName = "tendril_session";

enum class Role { kViewer, kOperator };

// Who is calling: resolved once per request or per WebSocket connection.
struct Identity {
  Role role = Role::kOperator;
  std::string lease_key;  // private: may embed the session id
  std::string label;      // public name shown as lease holder
};

// kAuthorizeOnly: the role and lease checks of a robot command, for routes dispatched elsewhere
// (planning_routes.cpp); answers 200 {} when they pass.
enum class Command {
  kStateCommand,
  kMode,
  kMoveJp,
  kServoJv,
  kMoveConfiguration,
  kJoystick,
  kEstop,
  kEstopReset,
  kAuthorizeOnly
};

std::string random_hex(std::size_t bytes) {
  static thread_local std::random_device device;
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < bytes; ++i) {
    const auto b = static_cast<unsigned>(device()) & 0xFF;
    out.push_back(kDigits[b >> 4]);
    out.push_back(kDigits[b & 0xF]);
  }
  return out;
}

std::string dump(const json& value) { return value.dump(-1, ' ', false, json::error_handler_t::replace); }

std::uint64_t wall_time_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

bool valid_client_name(std::string_view name) {
  if (name.empty() || name.size() > 64) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == '.';
  });
}

json service_schema(const json& properties, const std::vector<std::string>& required) {
  return {{"type", "object"}, {"properties", properties}, {"required", required}};
}

// Services mirror the REST commands. Request: {"robot":..., ...REST body}; response:
// {"status":..,"body"|"error"}.
struct ServiceDef {
  std::uint32_t id;
  const char* name;
  std::optional<Command> command;  // nullopt = lease
  bool needs_robot;
};
constexpr ServiceDef kServices[] = {
    {1, "state_command", Command::kStateCommand, true},
    {2, "mode", Command::kMode, true},
    {3, "move_jp", Command::kMoveJp, true},
    {4, "servo_jv", Command::kServoJv, true},
    {5, "estop", Command::kEstop, false},
    {6, "estop_reset", Command::kEstopReset, false},
    {7, "lease", std::nullopt, false},
    {8, "move_configuration", Command::kMoveConfiguration, true},
    {9, "joystick", Command::kJoystick, true},
};

// REST commands and getters under /api/v1/robots/{robot}/...
using Getter = ApiResult (ControlApi::*)(const std::string&) const;
const std::map<std::string, Getter>& robot_getters() {
  static const std::map<std::string, Getter> getters = {{"measured_js", &ControlApi::measured_js},
                                                        {"setpoint_js", &ControlApi::setpoint_js},
                                                        {"measured_cp", &ControlApi::measured_cp},
                                                        {"shape", &ControlApi::shape},
                                                        {"operating_state", &ControlApi::operating_state}};
  return getters;
}
const std::map<std::string, Command>& robot_commands() {
  static const std::map<std::string, Command> commands = {{"state_command", Command::kStateCommand},
                                                          {"mode", Command::kMode},
                                                          {"move_jp", Command::kMoveJp},
                                                          {"servo_jv", Command::kServoJv},
                                                          {"move_configuration", Command::kMoveConfiguration},
                                                          {"joystick", Command::kJoystick}};
  return commands;
}

std::vector<fg::Service> service_list() {
  const json robot = {{"type", "string"}};
  const json numbers = {{"type", "array"}, {"items", {{"type", "number"}}}};
  const json response = {
      {"type", "object"},
      {"properties",
       {{"status", {{"type", "integer"}}},
        {"body", json::object()},
        {"error",
         {{"type", "object"},
          {"properties", {{"code", {{"type", "string"}}}, {"message", {{"type", "string"}}}}}}}}}};
  std::vector<fg::Service> services;
  for (const auto& def : kServices) {
    json request;
    const std::string name = def.name;
    if (name == "state_command") {
      request = service_schema({{"robot", robot}, {"command", {{"type", "string"}}}}, {"robot", "command"});
    } else if (name == "mode") {
      request = service_schema({{"robot", robot}, {"mode", {{"type", "string"}}}}, {"robot", "mode"});
    } else if (name == "move_jp") {
      request = service_schema({{"robot", robot}, {"goal", numbers}}, {"robot", "goal"});
    } else if (name == "servo_jv") {
      request = service_schema({{"robot", robot}, {"velocity", numbers}}, {"robot", "velocity"});
    } else if (name == "move_configuration") {
      request = service_schema({{"robot", robot},
                                {"goal",
                                 {{"type", "object"},
                                  {"properties",
                                   {{"insertion", {{"type", "number"}}},
                                    {"roll", {{"type", "number"}}},
                                    {"theta_proximal", {{"type", "number"}}},
                                    {"theta_distal", {{"type", "number"}}}}}}}},
                               {"robot", "goal"});
    } else if (name == "joystick") {
      request = service_schema({{"robot", robot}, {"axes", numbers}, {"deadman", {{"type", "boolean"}}}},
                               {"robot", "axes", "deadman"});
    } else if (name == "lease") {
      request =
          service_schema({{"action", {{"type", "string"}, {"enum", {"acquire", "release", "status"}}}}}, {});
    } else {
      request = service_schema(json::object(), {});
    }
    services.push_back({def.id, name, "tendril/" + name, dump(request), dump(response)});
  }
  return services;
}

}  // namespace

class FrontEndWsSession;

class HttpServer::Impl {
 public:
  Impl(ControlApi& api_in, HttpOptions options_in)
      : api(api_in), opts(std::move(options_in)), lease(opts.lease_timeout), services(service_list()) {
    for (const auto& source : opts.topic_sources) {
      if (!source) continue;
      for (auto& info : source->topics()) {
        const std::string topic = info.topic;
        source_topics[topic] = {source.get(), std::move(info)};
      }
    }
  }

  ControlApi& api;
  HttpOptions opts;
  LeaseManager lease;
  const std::vector<fg::Service> services;
  const std::string server_session_id = random_hex(8);
  const SteadyClock::time_point started_at = SteadyClock::now();
  std::vector<std::string> allowed_origins;
  unsigned short bound_port = 0;
  std::string openapi_document;                    // served at GET /api/v1/openapi.json; read at start()
  std::unique_ptr<net::ssl::context> tls_context;  // set when a certificate and key are configured

  // Cookie sessions: random id -> role and public label. Bounded; the oldest is forgotten first.
  struct CookieSession {
    Role role;
    std::string label;
  };
  mutable std::mutex sessions_mutex;
  std::unordered_map<std::string, CookieSession> cookie_sessions;
  std::deque<std::string> cookie_order;
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

  mutable std::mutex ws_mutex;
  std::map<std::uint64_t, std::weak_ptr<FrontEndWsSession>> ws_sessions;

  // Metrics.
  std::atomic<std::uint64_t> ws_sent{0}, ws_dropped{0}, ws_bytes{0}, ws_connections_total{0},
      ws_client_messages{0}, ws_violations{0}, ws_closed_for_abuse{0};
  mutable std::mutex status_mutex;
  std::map<int, std::uint64_t> http_by_status;
  std::atomic<std::uint64_t> next_connection_id{1};

  // Runtime.
  std::unique_ptr<net::io_context> ioc;
  std::unique_ptr<tcp::acceptor> acceptor;
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

  struct AuthOutcome {
    std::optional<ApiResult> error;
    Identity identity;
    std::optional<std::string> set_cookie;
  };
  AuthOutcome authenticate(const Request& req, const RequestTarget& target, std::uint64_t connection_id,
                           bool accept_query_token, bool create_cookie_session, const char* connection_kind);

  ApiResult execute(Command command, const std::string& robot, const json& body, const Identity& who);
  // action: "acquire" (with an optional takeover token), "release" or "status".
  ApiResult lease_action(const std::string& action, const Identity& who,
                         const std::string& takeover_token = {});
  json lease_description(const Identity& who, SteadyClock::time_point now) const;
  // Sets parameters for `who` (operator with the lease) and pushes the new values to subscribers.
  ApiResult set_parameters(const json& parameters, const Identity& who);
  void publish_parameter_updates(const json& changed);

  // Servo streaming, for the takeover rule: a holder who sent a servo command within the longest
  // command timeout of any robot is streaming and cannot be displaced.
  std::mutex servo_mutex;
  std::string last_servo_key;
  SteadyClock::time_point last_servo_time{};
  std::chrono::milliseconds servo_window{150};
  void note_servo(const std::string& key, SteadyClock::time_point now) {
    std::lock_guard lock(servo_mutex);
    last_servo_key = key;
    last_servo_time = now;
  }
  bool servo_streaming(const std::string& key, SteadyClock::time_point now) {
    std::lock_guard lock(servo_mutex);
    return !last_servo_key.empty() && last_servo_key == key && now - last_servo_time <= servo_window;
  }

  // Status messages to WebSocket clients: to all, or only to the sockets of one lease identity.
  void broadcast_status(const json& status, const std::string& only_lease_key = {});
  // Faults and e-stops seen in ControlApi::faults() become status messages (newest seen so far).
  std::optional<std::string> newest_event_seen;
  void report_new_safety_events();

  void refresh_channels();
  bool channel_exists(std::uint32_t id) const {
    std::lock_guard lock(channels_mutex);
    return channels.count(id) != 0;
  }
  std::vector<std::shared_ptr<FrontEndWsSession>> live_sessions() const;
  // only_sources: publish the topic sources' new messages only (a source said one is ready), so that
  // robot topics keep their publish_rate_hz.
  void publish_once(bool only_sources = false);
  void do_accept();
  std::string metrics() const;
};

// ------------------------------------------------------------------------------------------------
// WebSocket session: Foxglove protocol, bounded outgoing queue with newest-only data slots.

class FrontEndWsSession : public std::enable_shared_from_this<FrontEndWsSession> {
 public:
  FrontEndWsSession(ByteStream&& stream, HttpServer::Impl& server, Identity identity, std::uint64_t id)
      : ws_(make_ws(std::move(stream))),
        executor_(std::visit([](auto& ws) { return net::any_io_executor(ws.get_executor()); }, ws_)),
        server_(server),
        identity_(std::move(identity)),
        id_(id),
        tokens_(server.opts.ws_client_burst),
        last_refill_(SteadyClock::now()) {}

  std::uint64_t id() const { return id_; }
  const Identity& identity() const { return identity_; }

  // Sends the subset of `changed` parameters this connection subscribed to (parametersSubscribe).
  void offer_parameter_updates(const json& changed) {
    json mine = json::array();
    {
      std::lock_guard lock(out_mutex_);
      for (const auto& p : changed) {
        if (p.contains("name") && parameter_subscriptions_.count(p["name"].get<std::string>()))
          mine.push_back(p);
      }
    }
    if (!mine.empty()) send_text(fg::parameter_values(mine, std::nullopt));
  }

  void run(Request request) {
    request_ = std::move(request);
    net::dispatch(executor_, beast::bind_front_handler(&FrontEndWsSession::do_accept, shared_from_this()));
  }

  // Queues a JSON message. Called from any thread. A client whose control queue overflows is not
  // reading: it is closed rather than allowed to grow memory.
  void send_text(const json& message) {
    std::string text = dump(message);
    bool overflow = false;
    bool kick = false;
    {
      std::lock_guard lock(out_mutex_);
      if (closed_) return;
      if (control_queue_.size() >= server_.opts.ws_max_control_queue) {
        overflow = true;
      } else {
        control_queue_.push_back(std::move(text));
        kick = !writing_;
        if (kick) writing_ = true;
      }
    }
    if (overflow) {
      ++server_.ws_closed_for_abuse;
      net::post(executor_, beast::bind_front_handler(&FrontEndWsSession::hard_close, shared_from_this()));
    } else if (kick) {
      net::post(executor_, beast::bind_front_handler(&FrontEndWsSession::do_write, shared_from_this()));
    }
  }

  // Offers a topic message to this connection's subscriptions of `channel_id`. Only the newest waits
  // per subscription: an unsent older one is replaced and counted as dropped.
  void offer(std::uint32_t channel_id, const std::shared_ptr<const std::string>& payload,
             std::uint64_t time_ns, std::optional<std::uint32_t> only_subscription = std::nullopt) {
    bool kick = false;
    {
      std::lock_guard lock(out_mutex_);
      if (closed_) return;
      for (const auto& [subscription, channel] : subscriptions_) {
        if (channel != channel_id || (only_subscription && *only_subscription != subscription)) continue;
        PendingData data{fg::message_data_header(subscription, time_ns), payload};
        auto [it, inserted] = latest_.try_emplace(subscription, data);
        if (inserted) {
          latest_order_.push_back(subscription);
        } else {
          it->second = std::move(data);
          ++dropped_;
          ++server_.ws_dropped;
        }
      }
      if (!latest_.empty() && !writing_) kick = writing_ = true;
    }
    if (kick)
      net::post(executor_, beast::bind_front_handler(&FrontEndWsSession::do_write, shared_from_this()));
  }

  void subscribed_channels(std::set<std::uint32_t>& out) const {
    std::lock_guard lock(out_mutex_);
    for (const auto& [subscription, channel] : subscriptions_) out.insert(channel);
  }

  void drop_channels(const std::vector<std::uint32_t>& removed) {
    std::lock_guard lock(out_mutex_);
    for (auto it = subscriptions_.begin(); it != subscriptions_.end();) {
      if (std::find(removed.begin(), removed.end(), it->second) != removed.end()) {
        latest_.erase(it->first);
        it = subscriptions_.erase(it);
      } else {
        ++it;
      }
    }
  }

  HttpServer::ConnectionStats stats() const {
    std::lock_guard lock(out_mutex_);
    return {id_, control_queue_.size() + latest_.size(), subscriptions_.size(), writing_, dropped_};
  }

  // Ends the connection at once (used by stop() and for clients that do not read).
  void hard_close() {
    {
      std::lock_guard lock(out_mutex_);
      closed_ = true;
      control_queue_.clear();
      latest_.clear();
      latest_order_.clear();
    }
    beast::error_code ignored;
    auto& socket =
        std::visit([](auto& ws) -> tcp::socket& { return beast::get_lowest_layer(ws).socket(); }, ws_);
    socket.shutdown(tcp::socket::shutdown_both, ignored);
    socket.close(ignored);
  }

 private:
  struct PendingData {
    std::array<std::uint8_t, fg::kMessageDataHeaderBytes> header{};
    std::shared_ptr<const std::string> payload;
  };

  void do_accept() {
    std::visit(
        [this](auto& ws) {
          ws.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
          ws.set_option(websocket::stream_base::decorator([](websocket::response_type& res) {
            res.set(bhttp::field::server, "tendril");
            res.set(bhttp::field::sec_websocket_protocol, std::string(fg::kSubprotocol));
          }));
          ws.read_message_max(server_.opts.max_ws_message_bytes);
          ws.async_accept(request_,
                          beast::bind_front_handler(&FrontEndWsSession::on_accept, shared_from_this()));
        },
        ws_);
  }

  void on_accept(beast::error_code ec) {
    if (ec) return;
    ++server_.ws_connections_total;
    std::vector<fg::Channel> channels;
    {
      // Register and snapshot the channels under one lock, so an advertise diff is never missed.
      std::lock_guard channels_lock(server_.channels_mutex);
      {
        std::lock_guard ws_lock(server_.ws_mutex);
        server_.ws_sessions[id_] = weak_from_this();
      }
      for (const auto& [id, state] : server_.channels) channels.push_back(state.channel);
    }
    // Parameters are readable by everyone; setting them needs the operator role and the lease.
    std::vector<std::string> capabilities = {"services", "parameters", "parametersSubscribe"};
    // Client publishing (joystick streams) is a command path: operators only.
    if (identity_.role == Role::kOperator) capabilities.insert(capabilities.begin(), "clientPublish");
    const json metadata = {{"tendril_version", version()},
                           {"role", identity_.role == Role::kOperator ? "operator" : "viewer"},
                           {"client", identity_.label}};
    send_text(fg::server_info("tendril", capabilities, metadata, server_.server_session_id));
    send_text(fg::advertise(channels));
    send_text(fg::advertise_services(server_.services));
    do_read();
  }

  void do_read() {
    std::visit(
        [this](auto& ws) {
          ws.async_read(buffer_, beast::bind_front_handler(&FrontEndWsSession::on_read, shared_from_this()));
        },
        ws_);
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec) {
      on_closed();
      return;
    }
    const bool is_text = std::visit([](auto& ws) { return ws.got_text(); }, ws_);
    const std::string message = beast::buffers_to_string(buffer_.data());
    buffer_.consume(buffer_.size());
    ++server_.ws_client_messages;
    if (take_rate_token()) {
      try {
        if (is_text) {
          handle_text(message);
        } else {
          handle_binary(message);
        }
      } catch (const std::exception& e) {
        send_text(fg::status(fg::StatusLevel::kError, std::string("internal error: ") + e.what()));
      }
    } else {
      violation("client message rate limit exceeded (" + std::to_string(server_.opts.ws_client_rate_hz) +
                " messages/s); message ignored");
    }
    if (!closing_) do_read();
  }

  bool take_rate_token() {
    const auto now = SteadyClock::now();
    const double elapsed = std::chrono::duration<double>(now - last_refill_).count();
    last_refill_ = now;
    tokens_ = std::min(server_.opts.ws_client_burst, tokens_ + elapsed * server_.opts.ws_client_rate_hz);
    if (tokens_ < 1.0) return false;
    tokens_ -= 1.0;
    return true;
  }

  void violation(const std::string& message) {
    ++violations_;
    ++server_.ws_violations;
    send_text(fg::status(fg::StatusLevel::kError, message));
    if (violations_ >= server_.opts.ws_max_violations && !closing_) {
      ++server_.ws_closed_for_abuse;
      send_text(fg::status(fg::StatusLevel::kError, "too many protocol violations; closing the connection"));
      begin_close(websocket::close_code::policy_error);
    }
  }

  void handle_text(const std::string& text) {
    auto parsed = fg::parse_client_text(text);
    if (auto* error = std::get_if<fg::ProtocolError>(&parsed)) {
      violation(error->message);
    } else if (auto* unsupported = std::get_if<fg::UnsupportedOp>(&parsed)) {
      send_text(fg::status(fg::StatusLevel::kWarning,
                           "op \"" + unsupported->op + "\" is not supported by tendril"));
    } else if (auto* subscribe = std::get_if<fg::SubscribeOp>(&parsed)) {
      handle_subscribe(*subscribe);
    } else if (auto* unsubscribe = std::get_if<fg::UnsubscribeOp>(&parsed)) {
      std::lock_guard lock(out_mutex_);
      for (const auto id : unsubscribe->subscription_ids) {
        subscriptions_.erase(id);
        latest_.erase(id);
      }
    } else if (auto* advertise = std::get_if<fg::ClientAdvertiseOp>(&parsed)) {
      handle_client_advertise(*advertise);
    } else if (auto* unadvertise = std::get_if<fg::ClientUnadvertiseOp>(&parsed)) {
      for (const auto id : unadvertise->channel_ids) client_channels_.erase(id);
    } else if (auto* get = std::get_if<fg::GetParametersOp>(&parsed)) {
      send_text(fg::parameter_values(select_parameters(get->names), get->id));
    } else if (auto* set = std::get_if<fg::SetParametersOp>(&parsed)) {
      handle_set_parameters(*set);
    } else if (auto* sub = std::get_if<fg::SubscribeParameterUpdatesOp>(&parsed)) {
      // Empty = every parameter known now (spec); subscribing twice to one name is a no-op.
      std::vector<std::string> names = sub->names;
      if (names.empty()) {
        for (const auto& p : server_.api.parameters()) names.push_back(p.value("name", std::string()));
      }
      std::lock_guard lock(out_mutex_);
      for (auto& name : names) {
        if (parameter_subscriptions_.size() >= 4096) break;
        parameter_subscriptions_.insert(std::move(name));
      }
    } else if (auto* unsub = std::get_if<fg::UnsubscribeParameterUpdatesOp>(&parsed)) {
      std::lock_guard lock(out_mutex_);
      if (unsub->names.empty()) parameter_subscriptions_.clear();
      for (const auto& name : unsub->names) parameter_subscriptions_.erase(name);
    }
  }

  // Current values of `names` (all when empty); unknown names are left out, as the spec allows.
  json select_parameters(const std::vector<std::string>& names) const {
    json all = server_.api.parameters();
    if (names.empty()) return all;
    json selected = json::array();
    for (const auto& p : all) {
      if (std::find(names.begin(), names.end(), p.value("name", std::string())) != names.end())
        selected.push_back(p);
    }
    return selected;
  }

  void handle_set_parameters(const fg::SetParametersOp& set) {
    const ApiResult result = server_.set_parameters(set.parameters, identity_);
    if (!result.ok()) {
      send_text(fg::status(fg::StatusLevel::kError, "setParameters: " + result.code + ": " + result.message,
                           "setParameters"));
    }
    // With an id the client expects an answer: the values now in force (unchanged after a refusal).
    if (set.id) {
      std::vector<std::string> names;
      for (const auto& p : set.parameters) names.push_back(p["name"].get<std::string>());
      send_text(fg::parameter_values(select_parameters(names), set.id));
    }
  }

  void handle_subscribe(const fg::SubscribeOp& subscribe) {
    for (const auto& sub : subscribe.subscriptions) {
      if (!server_.channel_exists(sub.channel_id)) {
        send_text(
            fg::status(fg::StatusLevel::kError, "subscribe: no channel " + std::to_string(sub.channel_id)));
        continue;
      }
      enum class Outcome { kSubscribed, kDuplicate, kTooMany } outcome;
      {
        std::lock_guard lock(out_mutex_);
        if (subscriptions_.count(sub.id)) {
          outcome = Outcome::kDuplicate;
        } else if (subscriptions_.size() >= server_.opts.ws_max_subscriptions) {
          outcome = Outcome::kTooMany;
        } else {
          subscriptions_[sub.id] = sub.channel_id;
          outcome = Outcome::kSubscribed;
        }
      }
      if (outcome == Outcome::kDuplicate) {
        send_text(fg::status(fg::StatusLevel::kWarning,
                             "subscribe: subscription id " + std::to_string(sub.id) + " is already in use"));
        continue;
      }
      if (outcome == Outcome::kTooMany) {
        send_text(fg::status(fg::StatusLevel::kError, "subscribe: at most " +
                                                          std::to_string(server_.opts.ws_max_subscriptions) +
                                                          " subscriptions per connection"));
        continue;
      }
      // A new subscriber gets the latest message at once instead of waiting for the next change.
      std::shared_ptr<const std::string> payload;
      std::uint64_t time_ns = 0;
      {
        std::lock_guard lock(server_.channels_mutex);
        const auto it = server_.channels.find(sub.channel_id);
        if (it != server_.channels.end()) {
          payload = it->second.last_payload;
          time_ns = it->second.last_time_ns;
        }
      }
      if (payload) offer(sub.channel_id, payload, time_ns, sub.id);
    }
  }

  void handle_client_advertise(const fg::ClientAdvertiseOp& advertise) {
    if (identity_.role != Role::kOperator) {
      send_text(fg::status(fg::StatusLevel::kError, "advertise: viewers may not publish"));
      return;
    }
    for (const auto& channel : advertise.channels) {
      // Operator streams: "/{robot}/servo_jv" with JSON {"velocity":[...]}, and "/{robot}/joystick"
      // with JSON {"axes":[...], "deadman": bool} (console joystick, telemanipulation).
      const auto segments = split_path(channel.topic);
      if (segments.size() != 2 || (segments[1] != "servo_jv" && segments[1] != "joystick") ||
          !server_.api.has_robot(segments[0]) || channel.encoding != "json") {
        send_text(fg::status(fg::StatusLevel::kError,
                             "advertise: tendril accepts client channels \"/{robot}/servo_jv\" and "
                             "\"/{robot}/joystick\" with encoding \"json\" only; refused \"" +
                                 channel.topic + "\""));
        continue;
      }
      if (client_channels_.size() >= 64) {
        send_text(fg::status(fg::StatusLevel::kError, "advertise: at most 64 client channels"));
        return;
      }
      client_channels_[channel.id] = {segments[0],
                                      segments[1] == "joystick" ? Command::kJoystick : Command::kServoJv};
    }
  }

  void handle_binary(const std::string& data) {
    auto parsed = fg::parse_client_binary(data);
    if (auto* error = std::get_if<fg::ProtocolError>(&parsed)) {
      violation(error->message);
    } else if (auto* message = std::get_if<fg::ClientMessageData>(&parsed)) {
      const auto it = client_channels_.find(message->channel_id);
      if (it == client_channels_.end()) {
        violation("message data on channel " + std::to_string(message->channel_id) +
                  " that was not advertised");
        return;
      }
      const ApiResult body = parse_json_body(message->payload, server_.opts.max_ws_message_bytes);
      const auto& [robot, command] = it->second;
      const ApiResult result = body.ok() ? server_.execute(command, robot, body.body, identity_) : body;
      if (!result.ok()) {
        send_text(fg::status(fg::StatusLevel::kWarning,
                             "/" + robot + (command == Command::kJoystick ? "/joystick: " : "/servo_jv: ") +
                                 result.code + ": " + result.message));
      }
    } else if (auto* call = std::get_if<fg::ServiceCallRequest>(&parsed)) {
      handle_service_call(*call);
    }
  }

  void handle_service_call(const fg::ServiceCallRequest& call) {
    const ServiceDef* def = nullptr;
    for (const auto& candidate : kServices) {
      if (candidate.id == call.service_id) def = &candidate;
    }
    if (!def) {
      send_text(fg::service_call_failure(call.service_id, call.call_id,
                                         "no service with id " + std::to_string(call.service_id)));
      return;
    }
    if (call.encoding != "json") {
      send_text(
          fg::service_call_failure(call.service_id, call.call_id, "tendril services take encoding \"json\""));
      return;
    }
    ApiResult result = parse_json_body(call.payload, server_.opts.max_ws_message_bytes);
    if (result.ok()) {
      json body = std::move(result.body);
      std::string robot;
      if (def->needs_robot) {
        const auto it = body.find("robot");
        if (it == body.end() || !it->is_string()) {
          result =
              ApiResult::error(400, "missing_robot", std::string(def->name) + " needs a \"robot\" string");
        } else {
          robot = it->get<std::string>();
          body.erase("robot");
        }
      }
      if (result.ok()) {
        if (def->command) {
          result = server_.execute(*def->command, robot, body, identity_);
        } else {
          const auto action = body.find("action");
          const auto token = body.find("takeover_token");
          result = server_.lease_action(
              action != body.end() && action->is_string() ? action->get<std::string>() : "acquire", identity_,
              token != body.end() && token->is_string() ? token->get<std::string>() : std::string());
        }
      }
    }
    json response = {{"status", result.status}};
    if (result.ok()) {
      response["body"] = result.body;
    } else {
      response["error"] = result.error_json()["error"];
      // The refusal also shows in Foxglove's problems panel, not only in the response payload.
      send_text(fg::status(fg::StatusLevel::kWarning,
                           std::string(def->name) + ": " + result.code + ": " + result.message));
    }
    send_binary(fg::encode_service_call_response(call.service_id, call.call_id, "json", dump(response)));
  }

  // Service responses travel in the control queue (never dropped), tagged binary.
  void send_binary(std::string frame) {
    bool kick = false;
    bool overflow = false;
    {
      std::lock_guard lock(out_mutex_);
      if (closed_) return;
      if (control_queue_.size() >= server_.opts.ws_max_control_queue) {
        overflow = true;
      } else {
        control_queue_.push_back(std::move(frame));
        binary_control_.insert(control_queue_.size() - 1 + control_popped_);
        kick = !writing_;
        if (kick) writing_ = true;
      }
    }
    if (overflow) {
      ++server_.ws_closed_for_abuse;
      hard_close();
    } else if (kick) {
      net::post(executor_, beast::bind_front_handler(&FrontEndWsSession::do_write, shared_from_this()));
    }
  }

  void do_write() {
    std::unique_lock lock(out_mutex_);
    if (closed_) {
      writing_ = false;
      return;
    }
    if (!control_queue_.empty()) {
      current_text_ = std::move(control_queue_.front());
      control_queue_.pop_front();
      const bool binary = binary_control_.erase(control_popped_) != 0;
      ++control_popped_;
      lock.unlock();
      std::visit(
          [this, binary](auto& ws) {
            ws.binary(binary);
            ws.async_write(net::buffer(current_text_),
                           beast::bind_front_handler(&FrontEndWsSession::on_write, shared_from_this()));
          },
          ws_);
      return;
    }
    while (!latest_order_.empty()) {
      const std::uint32_t subscription = latest_order_.front();
      latest_order_.pop_front();
      auto it = latest_.find(subscription);
      if (it == latest_.end()) continue;  // unsubscribed meanwhile
      current_data_ = std::move(it->second);
      latest_.erase(it);
      lock.unlock();
      const std::array<net::const_buffer, 2> buffers = {net::buffer(current_data_.header),
                                                        net::buffer(*current_data_.payload)};
      std::visit(
          [this, &buffers](auto& ws) {
            ws.binary(true);
            ws.async_write(buffers,
                           beast::bind_front_handler(&FrontEndWsSession::on_write, shared_from_this()));
          },
          ws_);
      return;
    }
    writing_ = false;
    const bool close_now = close_pending_;
    lock.unlock();
    if (close_now) finish_close();
  }

  void on_write(beast::error_code ec, std::size_t bytes) {
    if (ec) {
      std::lock_guard lock(out_mutex_);
      writing_ = false;
      closed_ = true;
      return;
    }
    ++server_.ws_sent;
    server_.ws_bytes += bytes;
    current_data_.payload.reset();
    do_write();
  }

  void begin_close(websocket::close_code code) {
    closing_ = true;
    close_code_ = code;
    std::unique_lock lock(out_mutex_);
    close_pending_ = true;
    if (!writing_) {
      lock.unlock();
      finish_close();
    }
  }

  void finish_close() {
    {
      std::lock_guard lock(out_mutex_);
      if (closed_) return;
      closed_ = true;
    }
    // Reading stopped when the close began, so the close completion is where the connection ends.
    std::visit(
        [this](auto& ws) {
          ws.async_close(close_code_, [self = shared_from_this()](beast::error_code) { self->on_closed(); });
        },
        ws_);
  }

  void on_closed() {
    if (gone_) return;
    gone_ = true;
    {
      std::lock_guard lock(out_mutex_);
      closed_ = true;
      control_queue_.clear();
      latest_.clear();
      latest_order_.clear();
    }
    {
      std::lock_guard lock(server_.ws_mutex);
      server_.ws_sessions.erase(id_);
    }
    // The holder's console went away: the robot holds now, and a reconnect must command afresh.
    if (server_.lease.holder(SteadyClock::now()) == identity_.lease_key) server_.api.operator_lost();
  }

  static std::variant<PlainWs, TlsWs> make_ws(ByteStream&& stream) {
    if (auto* tls = std::get_if<TlsStream>(&stream))
      return std::variant<PlainWs, TlsWs>(std::in_place_type<TlsWs>, std::move(*tls));
    return std::variant<PlainWs, TlsWs>(std::in_place_type<PlainWs>,
                                        std::move(std::get<beast::tcp_stream>(stream)));
  }

  std::variant<PlainWs, TlsWs> ws_;
  net::any_io_executor executor_;
  beast::flat_buffer buffer_;
  HttpServer::Impl& server_;
  const Identity identity_;
  const std::uint64_t id_;
  Request request_;

  // Strand-only state.
  double tokens_;
  SteadyClock::time_point last_refill_;
  int violations_ = 0;
  bool closing_ = false;
  bool gone_ = false;
  websocket::close_code close_code_ = websocket::close_code::normal;
  std::map<std::uint32_t, std::pair<std::string, Command>> client_channels_;  // id -> robot, stream
  std::string current_text_;
  PendingData current_data_;

  // Shared with the publisher thread.
  mutable std::mutex out_mutex_;
  std::deque<std::string> control_queue_;
  std::set<std::uint64_t> binary_control_;  // sequence numbers of binary entries in control_queue_
  std::uint64_t control_popped_ = 0;
  std::unordered_map<std::uint32_t, PendingData> latest_;  // subscription id -> newest unsent message
  std::deque<std::uint32_t> latest_order_;                 // fair order of subscriptions with data
  std::map<std::uint32_t, std::uint32_t> subscriptions_;   // subscription id -> channel id
  std::set<std::string> parameter_subscriptions_;          // parametersSubscribe names
  bool writing_ = false;
  bool closed_ = false;
  bool close_pending_ = false;
  std::uint64_t dropped_ = 0;
};

// ------------------------------------------------------------------------------------------------
// HTTP session: one request at a time (no pipelining), keep-alive, upgrade to FrontEndWsSession on /ws.

class FrontEndHttpSession : public std::enable_shared_from_this<FrontEndHttpSession> {
 public:
  FrontEndHttpSession(tcp::socket&& socket, HttpServer::Impl& server)
      : stream_(make_stream(std::move(socket), server)),
        server_(server),
        connection_id_(server.next_connection_id++) {}

  void run() {
    if (auto* tls = std::get_if<TlsStream>(&stream_)) {
      // TLS first; a client that does not complete the handshake in time is dropped.
      net::dispatch(lowest().get_executor(), [self = shared_from_this(), tls] {
        self->lowest().expires_after(std::chrono::seconds(30));
        tls->async_handshake(net::ssl::stream_base::server, [self](beast::error_code ec) {
          if (!ec) self->do_read();
        });
      });
      return;
    }
    net::dispatch(lowest().get_executor(),
                  beast::bind_front_handler(&FrontEndHttpSession::do_read, shared_from_this()));
  }

 private:
  using StringResponse = bhttp::response<bhttp::string_body>;

  void do_read() {
    parser_.emplace();
    // Beast checks Content-Length against the body limit while it parses the header, before the
    // route is known: admit the largest body any route takes here, and narrow it in on_header.
    std::size_t largest = server_.opts.max_body_bytes;
    if (server_.opts.planning != nullptr)
      largest = std::max(largest, server_.opts.planning->max_vessel_bytes());
    parser_->body_limit(largest);
    parser_->header_limit(16 * 1024);
    lowest().expires_after(std::chrono::seconds(30));
    body_limit_ = largest;
    // Headers first: vessel files and plans may be larger than other bodies (planning_routes.hpp).
    std::visit(
        [this](auto& stream) {
          bhttp::async_read_header(
              stream, buffer_, *parser_,
              beast::bind_front_handler(&FrontEndHttpSession::on_header, shared_from_this()));
        },
        stream_);
  }

  void on_header(beast::error_code ec, std::size_t bytes) {
    if (ec) return on_read(ec, bytes);
    const auto& header = parser_->get();
    if (server_.opts.planning == nullptr ||
        !takes_large_body(header.method_string(), parse_target(header.target()).path)) {
      body_limit_ = server_.opts.max_body_bytes;
    }
    // A declared length over the route's limit is refused before the body is read; a chunked body
    // is held to the limit chunk by chunk.
    if (const auto declared = parser_->content_length(); declared && *declared > body_limit_) {
      return on_read(bhttp::error::body_limit, bytes);
    }
    parser_->body_limit(body_limit_);
    std::visit(
        [this](auto& stream) {
          bhttp::async_read(stream, buffer_, *parser_,
                            beast::bind_front_handler(&FrontEndHttpSession::on_read, shared_from_this()));
        },
        stream_);
  }

  void on_read(beast::error_code ec, std::size_t) {
    if (ec == bhttp::error::end_of_stream) return do_close();
    if (ec == bhttp::error::body_limit) {
      Request partial;
      partial.version(parser_->get().version());
      partial.keep_alive(false);
      return send(error_response(partial, ApiResult::error(413, "body_too_large",
                                                           "request body exceeds the limit of " +
                                                               std::to_string(body_limit_) + " bytes")));
    }
    if (ec == bhttp::error::header_limit) {
      Request partial;
      partial.keep_alive(false);
      return send(
          error_response(partial, ApiResult::error(431, "headers_too_large", "request headers too large")));
    }
    if (ec) {
      if (ec != beast::error::timeout && ec != net::error::operation_aborted && !parser_->is_header_done()) {
        Request partial;
        partial.keep_alive(false);
        return send(error_response(partial, ApiResult::error(400, "bad_request", "malformed HTTP request")));
      }
      return;
    }
    Request request = parser_->release();
    if (websocket::is_upgrade(request)) return handle_upgrade(std::move(request));
    try {
      handle_request(request);
    } catch (const std::exception& e) {
      // A throwing ControlApi must not take an I/O thread down with it.
      send(error_response(request, ApiResult::error(500, "internal_error", e.what())));
    }
  }

  static StringResponse json_response(const Request& req, int status, const json& body) {
    StringResponse res{static_cast<bhttp::status>(status), req.version()};
    res.set(bhttp::field::server, "tendril");
    res.set(bhttp::field::content_type, "application/json");
    res.set(bhttp::field::cache_control, "no-store");
    res.keep_alive(req.keep_alive());
    res.body() = dump(body);
    res.prepare_payload();
    return res;
  }
  static StringResponse error_response(const Request& req, const ApiResult& result) {
    return json_response(req, result.status, result.error_json());
  }
  static StringResponse result_response(const Request& req, const ApiResult& result) {
    return result.ok() ? json_response(req, result.status, result.body) : error_response(req, result);
  }
  static StringResponse method_not_allowed(const Request& req, const char* allow) {
    auto res =
        error_response(req, ApiResult::error(405, "method_not_allowed",
                                             std::string(req.method_string()) + " is not allowed on " +
                                                 std::string(req.target().substr(0, req.target().find('?'))) +
                                                 "; allowed: " + allow));
    res.set(bhttp::field::allow, allow);
    return res;
  }

  template <class Body>
  void send(bhttp::response<Body>&& response) {
    server_.count_status(response.result_int());
    auto shared = std::make_shared<bhttp::response<Body>>(std::move(response));
    std::visit([&](auto& stream) { write_response(stream, shared); }, stream_);
  }

  template <class Stream, class Message>
  void write_response(Stream& stream, const std::shared_ptr<Message>& shared) {
    bhttp::async_write(stream, *shared,
                       [self = shared_from_this(), shared](beast::error_code ec, std::size_t) {
                         self->on_write(ec, shared->need_eof());
                       });
  }

  void on_write(beast::error_code ec, bool close) {
    if (ec) return;
    if (close) return do_close();
    do_read();
  }

  void do_close() {
    beast::error_code ignored;
    if (auto* tls = std::get_if<TlsStream>(&stream_)) {
      // TLS close_notify, then the socket goes with the session.
      tls->async_shutdown([self = shared_from_this()](beast::error_code) {});
      return;
    }
    lowest().socket().shutdown(tcp::socket::shutdown_send, ignored);
  }

  bool origin_refused(const Request& req) const {
    const auto origin = req.find(bhttp::field::origin);
    return origin != req.end() && !origin_allowed(origin->value(), server_.allowed_origins);
  }

  void handle_upgrade(Request req) {
    const RequestTarget target = parse_target(req.target());
    if (!target.valid || target.path != "/ws") {
      return send(error_response(req, ApiResult::error(404, "not_found", "WebSocket endpoint is /ws")));
    }
    if (origin_refused(req)) {
      return send(error_response(
          req, ApiResult::error(403, "origin_not_allowed",
                                "WebSocket Origin \"" + std::string(req[bhttp::field::origin]) +
                                    "\" is not in the allowlist")));
    }
    auto auth = server_.authenticate(req, target, connection_id_, /*accept_query_token=*/true,
                                     /*create_cookie_session=*/false, "ws");
    if (auth.error) return send(error_response(req, *auth.error));
    const auto offered = split_header_list(req[bhttp::field::sec_websocket_protocol]);
    if (std::find(offered.begin(), offered.end(), fg::kSubprotocol) == offered.end()) {
      return send(
          error_response(req, ApiResult::error(400, "subprotocol_required",
                                               "offer WebSocket subprotocol \"foxglove.websocket.v1\"")));
    }
    lowest().expires_never();
    std::make_shared<FrontEndWsSession>(std::move(stream_), server_, std::move(auth.identity), connection_id_)
        ->run(std::move(req));
  }

  void handle_request(const Request& req) {
    const RequestTarget target = parse_target(req.target());
    if (!target.valid) {
      return send(error_response(req, ApiResult::error(400, "bad_request", "malformed request target")));
    }
    const std::string& path = target.path;
    if (path == "/api" || path.rfind("/api/", 0) == 0) return handle_api(req, target);
    if (path == "/metrics") return handle_metrics(req, target);
    if (path == "/ws") {
      return send(error_response(
          req,
          ApiResult::error(426, "upgrade_required", "/ws is a WebSocket endpoint (foxglove.websocket.v1)")));
    }
    handle_static(req, target);
  }

  void handle_metrics(const Request& req, const RequestTarget& target) {
    if (req.method() != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
    if (origin_refused(req)) {
      return send(
          error_response(req, ApiResult::error(403, "origin_not_allowed", "Origin is not in the allowlist")));
    }
    auto auth = server_.authenticate(req, target, connection_id_, false, false, "connection");
    if (auth.error) return send(error_response(req, *auth.error));
    StringResponse res{bhttp::status::ok, req.version()};
    res.set(bhttp::field::content_type, "text/plain; version=0.0.4");
    res.set(bhttp::field::cache_control, "no-store");
    res.keep_alive(req.keep_alive());
    std::string control = server_.api.metrics();
    if (!control.empty() && control.back() != '\n') control.push_back('\n');
    res.body() = control + server_.metrics();
    res.prepare_payload();
    send(std::move(res));
  }

  void handle_api(const Request& req, const RequestTarget& target) {
    const auto segments = split_path(target.path);
    const auto method = req.method();
    if (segments.size() < 2 || segments[1] != "v1") {
      return send(error_response(req, ApiResult::error(404, "not_found", "the API lives under /api/v1")));
    }
    const std::vector<std::string> route(segments.begin() + 2, segments.end());
    if (route == std::vector<std::string>{"health"}) {
      if (method != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
      const double uptime = std::chrono::duration<double>(SteadyClock::now() - server_.started_at).count();
      return send(json_response(req, 200, {{"status", "ok"}, {"version", version()}, {"uptime_s", uptime}}));
    }
    // Public like /health: it documents the interface (the same file is in the repository) and
    // reveals no state, so API tools can read it before they have a token.
    if (route == std::vector<std::string>{"openapi.json"}) {
      if (method != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
      if (server_.openapi_document.empty()) {
        return send(
            error_response(req, ApiResult::error(404, "not_found",
                                                 "the OpenAPI document is not installed with this server "
                                                 "(server/openapi/openapi.json)")));
      }
      StringResponse res{bhttp::status::ok, req.version()};
      res.set(bhttp::field::server, "tendril");
      res.set(bhttp::field::content_type, "application/json");
      res.set(bhttp::field::cache_control, "no-cache");
      res.keep_alive(req.keep_alive());
      res.body() = server_.openapi_document;
      res.prepare_payload();
      return send(std::move(res));
    }
    // A browser page from another origin must not drive the robot with a stolen cookie or token.
    if (origin_refused(req)) {
      return send(error_response(req, ApiResult::error(403, "origin_not_allowed",
                                                       "Origin \"" + std::string(req[bhttp::field::origin]) +
                                                           "\" is not in the allowlist")));
    }
    auto auth = server_.authenticate(req, target, connection_id_, false, false, "connection");
    if (auth.error) return send(error_response(req, *auth.error));
    const Identity& who = auth.identity;
    auto& api = server_.api;

    if (route == std::vector<std::string>{"robots"}) {
      if (method != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
      return send(json_response(req, 200, api.robots()));
    }
    if (route == std::vector<std::string>{"faults"}) {
      if (method != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
      std::size_t max_events = 200;
      if (const auto it = target.query.find("max"); it != target.query.end()) {
        char* end = nullptr;
        const long value = std::strtol(it->second.c_str(), &end, 10);
        if (it->second.empty() || *end != '\0' || value < 1 || value > 10000) {
          return send(
              error_response(req, ApiResult::error(400, "bad_parameter", "max must be an integer 1..10000")));
        }
        max_events = static_cast<std::size_t>(value);
      }
      return send(json_response(req, 200, api.faults(max_events)));
    }
    if (route == std::vector<std::string>{"lease"}) {
      if (method == bhttp::verb::get) return send(result_response(req, server_.lease_action("status", who)));
      if (method == bhttp::verb::post) {
        const ApiResult body = parse_json_body(req.body(), server_.opts.max_body_bytes);
        if (!body.ok()) return send(error_response(req, body));
        std::string takeover_token;
        if (const auto it = body.body.find("takeover_token"); it != body.body.end()) {
          if (!it->is_string()) {
            return send(error_response(
                req, ApiResult::error(400, "bad_request",
                                      "\"takeover_token\" must be the string from the 409 answer")));
          }
          takeover_token = it->get<std::string>();
        }
        return send(result_response(req, server_.lease_action("acquire", who, takeover_token)));
      }
      if (method == bhttp::verb::delete_)
        return send(result_response(req, server_.lease_action("release", who)));
      return send(method_not_allowed(req, "GET, POST, DELETE"));
    }
    if (route == std::vector<std::string>{"estop"} || route == std::vector<std::string>{"estop", "reset"}) {
      if (method != bhttp::verb::post) return send(method_not_allowed(req, "POST"));
      if (route.size() == 1) {
        // Safety first: the e-stop ignores the body and the lease, and works for viewers too.
        return send(result_response(req, server_.execute(Command::kEstop, {}, json::object(), who)));
      }
      const ApiResult body = parse_json_body(req.body(), server_.opts.max_body_bytes);
      if (!body.ok()) return send(error_response(req, body));
      return send(result_response(req, server_.execute(Command::kEstopReset, {}, body.body, who)));
    }
    if (route.size() == 3 && route[0] == "robots") {
      const std::string& robot = route[1];
      const std::string& verb = route[2];
      const auto& kGetters = robot_getters();
      const auto& kCommands = robot_commands();
      if (const auto getter = kGetters.find(verb); getter != kGetters.end()) {
        if (method != bhttp::verb::get) return send(method_not_allowed(req, "GET"));
        if (!api.has_robot(robot)) return send(error_response(req, unknown_robot(robot)));
        return send(result_response(req, (api.*(getter->second))(robot)));
      }
      if (const auto command = kCommands.find(verb); command != kCommands.end()) {
        if (method != bhttp::verb::post) return send(method_not_allowed(req, "POST"));
        if (!api.has_robot(robot)) return send(error_response(req, unknown_robot(robot)));
        const ApiResult body = parse_json_body(req.body(), server_.opts.max_body_bytes);
        if (!body.ok()) return send(error_response(req, body));
        return send(result_response(req, server_.execute(command->second, robot, body.body, who)));
      }
    }
    const PlanningCall planning_call{req.method_string(),
                                     route,
                                     target.query,
                                     req[bhttp::field::content_type],
                                     req.body(),
                                     server_.opts.max_body_bytes,
                                     who.role == Role::kOperator,
                                     [&](const std::string& robot) -> std::optional<ApiResult> {
                                       auto allowed =
                                           server_.execute(Command::kAuthorizeOnly, robot, {}, who);
                                       return allowed.ok() ? std::nullopt : std::optional<ApiResult>(allowed);
                                     }};
    if (auto planned = route_planning(server_.opts.planning, api, planning_call)) {
      auto res = result_response(req, planned->result);
      if (!planned->location.empty()) res.set(bhttp::field::location, planned->location);
      if (!planned->allow.empty()) res.set(bhttp::field::allow, planned->allow);
      return send(std::move(res));
    }
    send(error_response(
        req, ApiResult::error(404, "not_found",
                              "no endpoint " + std::string(req.method_string()) + " " + target.path)));
  }

  static ApiResult unknown_robot(const std::string& robot) {
    return ApiResult::error(404, "unknown_robot",
                            "no robot named \"" + robot + "\"; GET /api/v1/robots lists them");
  }

  void handle_static(const Request& req, const RequestTarget& target) {
    if (req.method() != bhttp::verb::get && req.method() != bhttp::verb::head) {
      return send(method_not_allowed(req, "GET, HEAD"));
    }
    // Opening the console URL with ?token= turns the token into a session cookie.
    std::optional<std::string> set_cookie;
    if (target.query.count("token")) {
      auto auth = server_.authenticate(req, target, connection_id_, true, true, "connection");
      if (auth.error) return send(error_response(req, *auth.error));
      set_cookie = auth.set_cookie;
    }
    // Longest matching mount wins; the web root serves everything else.
    std::string prefix;
    std::string root;
    for (const auto& [mount, dir] : server_.opts.static_mounts) {
      if (target.path.rfind(mount, 0) == 0 && mount.size() > prefix.size()) {
        prefix = mount;
        root = dir;
      }
    }
    if (root.empty() && !server_.opts.web_root.empty()) {
      prefix = "/";
      root = server_.opts.web_root;
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
      return send(error_response(req, ApiResult::error(404, "not_found", "no file at " + target.path)));
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
      return send(std::move(res));
    }
    bhttp::response<bhttp::file_body> res{std::piecewise_construct, std::make_tuple(std::move(body)),
                                          std::make_tuple(bhttp::status::ok, req.version())};
    decorate(res);
    send(std::move(res));
  }

  static ByteStream make_stream(tcp::socket&& socket, HttpServer::Impl& server) {
    if (server.tls_context)
      return ByteStream(std::in_place_type<TlsStream>, std::move(socket), *server.tls_context);
    return ByteStream(std::in_place_type<beast::tcp_stream>, std::move(socket));
  }
  beast::tcp_stream& lowest() {
    return std::visit([](auto& stream) -> beast::tcp_stream& { return beast::get_lowest_layer(stream); },
                      stream_);
  }

  ByteStream stream_;
  beast::flat_buffer buffer_;
  std::optional<bhttp::request_parser<bhttp::string_body>> parser_;
  std::size_t body_limit_ = 0;  // of the request being read
  HttpServer::Impl& server_;
  const std::uint64_t connection_id_;
};

// ------------------------------------------------------------------------------------------------
// Impl

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

ApiResult HttpServer::Impl::execute(Command command, const std::string& robot, const json& body,
                                    const Identity& who) {
  if (command == Command::kEstop) {
    try {
      return api.estop_from(who.label + (who.role == Role::kViewer ? " (viewer)" : " (operator)"));
    } catch (const std::exception& e) {
      return ApiResult::error(500, "internal_error", e.what());
    }
  }
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators command");
  }
  const bool needs_robot = command != Command::kEstopReset;
  if (needs_robot && !api.has_robot(robot)) {
    return ApiResult::error(404, "unknown_robot", "no robot named \"" + robot + "\"");
  }
  const auto now = SteadyClock::now();
  if (!lease.use(who.lease_key, now)) {
    const auto status = lease.status(who.lease_key, now);
    return ApiResult::error(409, "lease_held",
                            status.held ? "the operator lease is held by " + status.holder_label +
                                              "; commands need the lease (POST /api/v1/lease)"
                                        : "take the operator lease first (POST /api/v1/lease)");
  }
  try {
    switch (command) {
      case Command::kStateCommand:
        return api.state_command(robot, body);
      case Command::kMode:
        return api.mode(robot, body);
      case Command::kMoveJp:
        return api.move_jp(robot, body);
      case Command::kServoJv: {
        ApiResult result = api.servo_jv(robot, body);
        if (result.ok()) note_servo(who.lease_key, SteadyClock::now());
        return result;
      }
      case Command::kEstopReset:
        return api.estop_reset();
      case Command::kMoveConfiguration:
        return api.move_configuration(robot, body);
      case Command::kJoystick: {
        ApiResult result = api.joystick(robot, body);
        // A held deadman counts as streaming commands (a takeover must not cut it off silently).
        if (result.ok() && body.value("deadman", false)) note_servo(who.lease_key, SteadyClock::now());
        return result;
      }
      case Command::kAuthorizeOnly:
        return ApiResult::success(json::object());
      case Command::kEstop:
        break;
    }
  } catch (const std::exception& e) {
    return ApiResult::error(500, "internal_error", e.what());
  }
  return ApiResult::error(500, "internal_error", "unhandled command");
}

json HttpServer::Impl::lease_description(const Identity& who, SteadyClock::time_point now) const {
  const auto status = lease.status(who.lease_key, now);
  const double remaining = static_cast<double>(status.remaining.count()) / 1000.0;
  // "held/holder/mine/expires_s" is the contract; "yours/expires_in_s/you" stay for older clients.
  return {{"held", status.held},   {"holder", status.held ? json(status.holder_label) : json(nullptr)},
          {"mine", status.yours},  {"expires_s", remaining},
          {"yours", status.yours}, {"expires_in_s", remaining},
          {"you", who.label}};
}

ApiResult HttpServer::Impl::lease_action(const std::string& action, const Identity& who,
                                         const std::string& takeover_token) {
  const auto now = SteadyClock::now();
  if (action == "status") return ApiResult::success(lease_description(who, now));
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role", "viewers cannot take or release the operator lease");
  }
  if (action == "acquire") {
    const bool had_it = lease.status(who.lease_key, now).yours;
    if (lease.acquire(who.lease_key, who.label, now)) {
      if (!had_it) {
        broadcast_status(
            fg::status(fg::StatusLevel::kInfo, who.label + " holds the operator lease", "lease"));
      }
      return ApiResult::success(lease_description(who, now));
    }
    const auto held = lease.status(who.lease_key, now);
    const auto holder_key = lease.holder(now);
    if (!takeover_token.empty()) {
      // Confirmation of a takeover. Never while the holder streams servo commands: the stream would
      // stop in mid-motion under someone else's control.
      if (holder_key && servo_streaming(*holder_key, now)) {
        ApiResult refused = ApiResult::error(
            409, "servo_active",
            held.holder_label +
                " is streaming servo commands; the lease cannot be taken over while the robot is servoing. "
                "Ask them to stop, or retry when the stream has ended (the takeover token stays valid for "
                "15 s)");
        refused.error_details = {{"holder", held.holder_label}};
        return refused;
      }
      std::string previous_key;
      if (lease.take_over(who.lease_key, who.label, takeover_token, now, previous_key) ==
          LeaseManager::TakeoverResult::kBadToken) {
        return ApiResult::error(409, "bad_takeover_token",
                                "the takeover token is unknown, expired (it lasts 15 s) or was issued to "
                                "another client; POST /api/v1/lease without it to get a new one");
      }
      if (!previous_key.empty()) {
        broadcast_status(fg::status(fg::StatusLevel::kWarning,
                                    "the operator lease was taken over by " + who.label +
                                        "; your commands are refused until you take it back",
                                    "lease"),
                         previous_key);
      }
      broadcast_status(fg::status(fg::StatusLevel::kInfo,
                                  who.label + " took over the operator lease from " + held.holder_label,
                                  "lease"));
      return ApiResult::success(lease_description(who, now));
    }
    // Refused: offer a takeover, to be confirmed by POSTing the token back within 15 s.
    const std::string token = random_hex(16);
    lease.issue_takeover_token(who.lease_key, token, now);
    ApiResult refused =
        ApiResult::error(409, "lease_held",
                         "the operator lease is held by " + held.holder_label +
                             "; to take it over, confirm with POST /api/v1/lease {\"takeover_token\": \"" +
                             token + "\"} within 15 s");
    refused.error_details = {{"holder", held.holder_label}, {"takeover_token", token}};
    return refused;
  }
  if (action == "release") {
    const auto status = lease.status(who.lease_key, now);
    if (status.held && !status.yours) {
      return ApiResult::error(409, "lease_held",
                              "the operator lease is held by " + status.holder_label + ", not you");
    }
    if (lease.release(who.lease_key, now)) {
      broadcast_status(
          fg::status(fg::StatusLevel::kInfo, who.label + " released the operator lease", "lease"));
    }
    return ApiResult::success(lease_description(who, now));
  }
  return ApiResult::error(400, "bad_action", "lease action must be \"acquire\", \"release\" or \"status\"");
}

ApiResult HttpServer::Impl::set_parameters(const json& parameters, const Identity& who) {
  if (who.role != Role::kOperator) {
    return ApiResult::error(403, "forbidden_role",
                            "this session is a viewer (read-only); only operators set parameters");
  }
  const auto now = SteadyClock::now();
  if (!lease.use(who.lease_key, now)) {
    const auto status = lease.status(who.lease_key, now);
    return ApiResult::error(409, "lease_held",
                            status.held ? "the operator lease is held by " + status.holder_label +
                                              "; setting parameters needs the lease"
                                        : "take the operator lease first (POST /api/v1/lease)");
  }
  ApiResult result;
  try {
    result = api.set_parameters(parameters);
  } catch (const std::exception& e) {
    return ApiResult::error(500, "internal_error", e.what());
  }
  if (result.ok()) {
    publish_parameter_updates(result.body);
    std::string names;
    for (const auto& p : result.body) {
      names += (names.empty() ? "" : ", ") + p.value("name", std::string()) + " = " +
               dump(p.value("value", json()));
    }
    broadcast_status(fg::status(fg::StatusLevel::kInfo, who.label + " set " + names, "parameters"));
  }
  return result;
}

std::vector<std::shared_ptr<FrontEndWsSession>> HttpServer::Impl::live_sessions() const {
  std::vector<std::shared_ptr<FrontEndWsSession>> result;
  std::lock_guard lock(ws_mutex);
  for (const auto& [id, weak] : ws_sessions) {
    if (auto session = weak.lock()) result.push_back(std::move(session));
  }
  return result;
}

void HttpServer::Impl::broadcast_status(const json& status, const std::string& only_lease_key) {
  for (const auto& session : live_sessions()) {
    if (only_lease_key.empty() || session->identity().lease_key == only_lease_key) session->send_text(status);
  }
}

void HttpServer::Impl::publish_parameter_updates(const json& changed) {
  for (const auto& session : live_sessions()) session->offer_parameter_updates(changed);
}

void HttpServer::Impl::report_new_safety_events() {
  json events;
  try {
    events = api.faults(16);
  } catch (const std::exception&) {
    return;
  }
  if (!events.is_array() || events.empty()) {
    if (!newest_event_seen) newest_event_seen = std::string();  // an empty log: every later event is new
    return;
  }
  const std::string newest = dump(events.front());
  const bool first_look = !newest_event_seen.has_value();
  if (newest_event_seen == newest) return;
  // Walk from the newest back to the last one already reported (events arrive newest first).
  std::vector<const json*> fresh;
  for (const auto& event : events) {
    if (first_look || dump(event) == *newest_event_seen) break;
    fresh.push_back(&event);
  }
  newest_event_seen = newest;
  for (auto it = fresh.rbegin(); it != fresh.rend(); ++it) {
    const json& event = **it;
    const std::string kind = event.value("kind", std::string());
    if (kind != "fault" && kind != "estop" && kind != "estop_reset") continue;
    const std::string robot = event.value("robot", std::string());
    const auto level = kind == "estop_reset" ? fg::StatusLevel::kInfo : fg::StatusLevel::kError;
    const std::string what = kind == "estop" ? "e-stop" : kind == "estop_reset" ? "e-stop reset" : "fault";
    std::string text = robot;
    text += ' ';
    text += what;
    text += ": ";
    text += event.value("message", std::string());
    broadcast_status(fg::status(level, text, "safety/" + robot));
  }
}

void HttpServer::Impl::refresh_channels() {
  std::vector<std::string> topics;
  try {
    topics = api.topics();
  } catch (const std::exception&) {
    return;  // keep the current channels; the next cycle asks again
  }
  for (const auto& [topic, source] : source_topics) topics.push_back(topic);
  std::vector<fg::Channel> added;
  std::vector<std::uint32_t> removed;
  std::vector<std::shared_ptr<FrontEndWsSession>> sessions;
  {
    std::lock_guard lock(channels_mutex);
    if (topics == last_topics) return;
    for (const auto& topic : topics) {
      if (topic_ids.count(topic)) continue;
      const std::uint32_t id = next_channel_id++;
      topic_ids[topic] = id;
      if (const auto source = source_topics.find(topic); source != source_topics.end()) {
        auto& channel = channels[id].channel;
        channel.id = id;
        channel.topic = topic;
        channel.schema_name = source->second.second.schema_name;
        channel.schema = source->second.second.schema;
        channels[id].source = source->second.first;
      } else {
        channels[id].channel = fg::channel_for_topic(id, topic);
      }
      added.push_back(channels[id].channel);
    }
    for (auto it = topic_ids.begin(); it != topic_ids.end();) {
      if (std::find(topics.begin(), topics.end(), it->first) == topics.end()) {
        removed.push_back(it->second);
        channels.erase(it->second);
        it = topic_ids.erase(it);
      } else {
        ++it;
      }
    }
    last_topics = topics;
    sessions = live_sessions();
  }
  for (auto& session : sessions) {
    if (!removed.empty()) {
      session->drop_channels(removed);
      session->send_text(fg::unadvertise(removed));
    }
    if (!added.empty()) session->send_text(fg::advertise(added));
  }
}

void HttpServer::Impl::publish_once(bool only_sources) {
  std::lock_guard publish_lock(publish_mutex);
  refresh_channels();
  const auto sessions = live_sessions();
  report_new_safety_events();
  std::set<std::uint32_t> wanted;
  for (const auto& session : sessions) session->subscribed_channels(wanted);
  for (const std::uint32_t channel_id : wanted) {
    std::string topic;
    std::uint64_t since = 0;
    TopicSource* source = nullptr;
    {
      std::lock_guard lock(channels_mutex);
      const auto it = channels.find(channel_id);
      if (it == channels.end()) continue;
      topic = it->second.channel.topic;
      since = it->second.version;
      source = it->second.source;
    }
    if (source) {
      // Serialised once by the source; every connection shares the same payload.
      std::optional<TopicPayload> latest;
      try {
        latest = source->latest(topic, since);
      } catch (const std::exception&) {
        continue;
      }
      if (!latest || !latest->payload) continue;
      {
        std::lock_guard lock(channels_mutex);
        const auto it = channels.find(channel_id);
        if (it == channels.end()) continue;
        it->second.version = latest->version;
        it->second.last_payload = latest->payload;
        it->second.last_time_ns = latest->log_time_ns;
      }
      for (const auto& session : sessions) session->offer(channel_id, latest->payload, latest->log_time_ns);
      continue;
    }
    if (only_sources) continue;
    std::uint64_t version = since;
    std::optional<json> message;
    try {
      message = api.topic_message(topic, since, version);
    } catch (const std::exception&) {
      continue;
    }
    if (!message) continue;
    auto payload = std::make_shared<const std::string>(dump(*message));
    const std::uint64_t time_ns = wall_time_ns();
    {
      std::lock_guard lock(channels_mutex);
      const auto it = channels.find(channel_id);
      if (it == channels.end()) continue;
      it->second.version = version;
      it->second.last_payload = payload;
      it->second.last_time_ns = time_ns;
    }
    for (const auto& session : sessions) session->offer(channel_id, payload, time_ns);
  }
}

void HttpServer::Impl::do_accept() {
  acceptor->async_accept(net::make_strand(*ioc), [this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor->is_open()) return;
    if (!ec) {
      beast::error_code ignored;
      socket.set_option(tcp::no_delay(true), ignored);  // small state messages should not wait for Nagle
      std::make_shared<FrontEndHttpSession>(std::move(socket), *this)->run();
    }
    do_accept();
  });
}

std::string HttpServer::Impl::metrics() const {
  std::ostringstream out;
  auto metric = [&](const char* name, const char* type, const char* help, auto value) {
    out << "# HELP " << name << ' ' << help << "\n# TYPE " << name << ' ' << type << '\n'
        << name << ' ' << value << '\n';
  };
  std::size_t clients = 0;
  std::size_t max_queue = 0;
  for (const auto& session : live_sessions()) {
    ++clients;
    max_queue = std::max(max_queue, session->stats().queued_messages);
  }
  metric("tendril_ws_clients", "gauge", "Open WebSocket connections.", clients);
  metric("tendril_ws_connections_total", "counter", "WebSocket connections accepted.",
         ws_connections_total.load());
  metric("tendril_ws_messages_sent_total", "counter", "WebSocket messages written to clients.",
         ws_sent.load());
  metric("tendril_ws_messages_dropped_total", "counter",
         "Topic messages replaced by a newer one before a slow client could receive them.",
         ws_dropped.load());
  metric("tendril_ws_bytes_sent_total", "counter", "WebSocket bytes written to clients.", ws_bytes.load());
  metric("tendril_ws_client_messages_total", "counter", "WebSocket messages received from clients.",
         ws_client_messages.load());
  metric("tendril_ws_client_violations_total", "counter", "Malformed or rate-limited client messages.",
         ws_violations.load());
  metric("tendril_ws_closed_for_abuse_total", "counter", "Connections closed for violations or not reading.",
         ws_closed_for_abuse.load());
  metric("tendril_ws_queue_max", "gauge", "Largest outgoing queue of any connection (messages).", max_queue);
  {
    std::lock_guard lock(sessions_mutex);
    metric("tendril_http_sessions", "gauge", "Console cookie sessions remembered.", cookie_sessions.size());
  }
  out << "# HELP tendril_http_requests_total HTTP responses sent, by status code.\n"
         "# TYPE tendril_http_requests_total counter\n";
  {
    std::lock_guard lock(status_mutex);
    for (const auto& [status, count] : http_by_status) {
      out << "tendril_http_requests_total{status=\"" << status << "\"} " << count << '\n';
    }
  }
  const auto lease_status = lease.status({}, SteadyClock::now());
  metric("tendril_lease_held", "gauge", "1 when an operator holds the command lease.",
         lease_status.held ? 1 : 0);
  for (const auto& source : opts.topic_sources)
    if (source) out << source->metrics();
  return out.str();
}

// ------------------------------------------------------------------------------------------------
// HttpServer

HttpServer::HttpServer(ControlApi& api, HttpOptions options)
    : impl_(std::make_unique<Impl>(api, std::move(options))) {
  if (impl_->opts.token.empty()) {
    throw HttpServerError(
        "HttpServer needs an access token (HttpOptions::token); refusing to serve without one");
  }
  if (impl_->opts.io_threads < 1) throw HttpServerError("HttpOptions::io_threads must be at least 1");
}

HttpServer::~HttpServer() { stop(); }

void HttpServer::start() {
  Impl& s = *impl_;
  std::lock_guard lifecycle(s.lifecycle_mutex);
  if (s.running) return;
  beast::error_code ec;
  const std::string host = s.opts.host == "localhost" ? "127.0.0.1" : s.opts.host;
  const auto address = net::ip::make_address(host, ec);
  if (ec) throw HttpServerError("HTTP host \"" + s.opts.host + "\" is not an IP address (e.g. 127.0.0.1)");
  s.ioc = std::make_unique<net::io_context>(s.opts.io_threads);
  s.acceptor = std::make_unique<tcp::acceptor>(net::make_strand(*s.ioc));
  const tcp::endpoint endpoint{address, s.opts.port};
  const std::string where = s.opts.host + ":" + std::to_string(s.opts.port);
  s.acceptor->open(endpoint.protocol(), ec);
  if (!ec) s.acceptor->set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) s.acceptor->bind(endpoint, ec);
  if (ec == net::error::address_in_use) {
    s.acceptor.reset();
    s.ioc.reset();
    throw HttpServerError("cannot listen on " + where +
                          ": the port is already in use (is another tendrild running?); choose another port");
  }
  if (!ec) s.acceptor->listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    s.acceptor.reset();
    s.ioc.reset();
    throw HttpServerError("cannot listen on " + where + ": " + ec.message());
  }
  s.bound_port = s.acceptor->local_endpoint().port();
  s.allowed_origins = s.opts.allowed_origins;
  if (s.allowed_origins.empty()) {
    const std::string port = std::to_string(s.bound_port);
    const std::string scheme = s.opts.tls_certificate_file.empty() ? "http://" : "https://";
    s.allowed_origins.push_back(scheme + s.opts.host + ":" + port);
    // Same machine: a browser may say localhost or 127.0.0.1 (also when bound to all interfaces).
    if (address.is_loopback() || address.is_unspecified()) {
      s.allowed_origins.push_back(scheme + "localhost:" + port);
      s.allowed_origins.push_back(scheme + "127.0.0.1:" + port);
    }
  }
  if (!s.opts.openapi_file.empty()) {
    std::ifstream file(s.opts.openapi_file, std::ios::binary);
    std::ostringstream text;
    text << file.rdbuf();
    if (!file || json::parse(text.str(), nullptr, false).is_discarded()) {
      s.acceptor.reset();
      s.ioc.reset();
      throw HttpServerError("cannot read the OpenAPI document " + s.opts.openapi_file +
                            " (missing or not JSON); it is server/openapi/openapi.json in the source tree");
    }
    s.openapi_document = text.str();
  }
  if (!s.opts.tls_certificate_file.empty() || !s.opts.tls_private_key_file.empty()) {
    if (s.opts.tls_certificate_file.empty() || s.opts.tls_private_key_file.empty()) {
      s.acceptor.reset();
      s.ioc.reset();
      throw HttpServerError("TLS needs both a certificate and a private key (server.json \"tls\")");
    }
    auto context = std::make_unique<net::ssl::context>(net::ssl::context::tls_server);
    context->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                         net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 |
                         net::ssl::context::no_tlsv1_1);
    const auto load = [&](const std::string& what, const std::string& file, auto&& use) {
      beast::error_code tls_ec;
      use(file, tls_ec);
      if (tls_ec) {
        s.acceptor.reset();
        s.ioc.reset();
        throw HttpServerError("cannot use the TLS " + what + " " + file + ": " + tls_ec.message() +
                              " (expected a PEM file)");
      }
    };
    load("certificate", s.opts.tls_certificate_file, [&](const std::string& file, beast::error_code& e) {
      context->use_certificate_chain_file(file, e);
    });
    load("private key", s.opts.tls_private_key_file, [&](const std::string& file, beast::error_code& e) {
      context->use_private_key_file(file, net::ssl::context::pem, e);
    });
    s.tls_context = std::move(context);
  }
  // The takeover rule needs the longest servo command timeout of any robot.
  try {
    for (const auto& robot : s.api.robots()) {
      const auto timeout = robot.find("command_timeout_ms");
      if (timeout != robot.end() && timeout->is_number() && timeout->get<double>() > 0) {
        s.servo_window = std::max(s.servo_window, std::chrono::milliseconds(timeout->get<std::int64_t>()));
      }
    }
  } catch (const std::exception&) {
    // Keep the default window; robots() failing here shows up again on GET /robots.
  }
  s.refresh_channels();
  s.do_accept();
  s.stopping = false;
  // Registered under lifecycle_mutex; no source holds a callback yet (stop() clears them), so the
  // source's lock (taken around its callback, which then takes lifecycle_mutex) cannot be waiting here.
  for (const auto& source : s.opts.topic_sources) {
    if (!source) continue;
    source->set_ready_callback([&s] {
      {
        std::lock_guard lock(s.lifecycle_mutex);
        s.sources_ready = true;
      }
      s.publisher_wake.notify_all();
    });
  }
  for (int i = 0; i < s.opts.io_threads; ++i) s.io_threads.emplace_back([&s] { s.ioc->run(); });
  if (s.opts.publish_rate_hz > 0) {
    s.publisher = std::thread([&s] {
      const auto period = std::chrono::duration_cast<SteadyClock::duration>(
          std::chrono::duration<double>(1.0 / s.opts.publish_rate_hz));
      auto next = SteadyClock::now();
      while (true) {
        bool only_sources = false;
        {
          std::unique_lock lock(s.lifecycle_mutex);
          s.publisher_wake.wait_until(lock, next, [&s] { return s.stopping || s.sources_ready; });
          if (s.stopping) return;
          // A source's new message (an image) goes out now; robot topics wait for their tick.
          only_sources = s.sources_ready && SteadyClock::now() < next;
          s.sources_ready = false;
        }
        s.publish_once(only_sources);
        if (only_sources) continue;
        next += period;
        const auto now = SteadyClock::now();
        if (next < now) next = now;  // after a stall, do not burst to catch up
      }
    });
  }
  s.running = true;
}

void HttpServer::stop() {
  Impl& s = *impl_;
  {
    std::lock_guard lifecycle(s.lifecycle_mutex);
    if (!s.running) return;
    s.running = false;
    s.stopping = true;
  }
  for (const auto& source : s.opts.topic_sources)
    if (source) source->set_ready_callback(nullptr);
  s.publisher_wake.notify_all();
  if (s.publisher.joinable()) s.publisher.join();
  net::post(s.acceptor->get_executor(), [&s] {
    beast::error_code ignored;
    s.acceptor->close(ignored);
  });
  for (auto& session : s.live_sessions()) {
    net::post(s.ioc->get_executor(), [session] { session->hard_close(); });
  }
  s.ioc->stop();
  for (auto& thread : s.io_threads) thread.join();
  s.io_threads.clear();
  {
    std::lock_guard lock(s.ws_mutex);
    s.ws_sessions.clear();
  }
  s.acceptor.reset();
  s.ioc.reset();  // destroys pending handlers and with them the sessions
}

unsigned short HttpServer::port() const { return impl_->bound_port; }
bool HttpServer::tls() const { return !impl_->opts.tls_certificate_file.empty(); }

std::vector<HttpServer::Route> HttpServer::api_routes() {
  // What handle_api dispatches itself (the planning routes are added by planning_routes.cpp).
  std::vector<Route> routes = {
      {"GET", "/api/v1/health"},   {"GET", "/api/v1/openapi.json"}, {"GET", "/api/v1/robots"},
      {"GET", "/api/v1/faults"},   {"GET", "/api/v1/lease"},        {"POST", "/api/v1/lease"},
      {"DELETE", "/api/v1/lease"}, {"POST", "/api/v1/estop"},       {"POST", "/api/v1/estop/reset"},
  };
  for (const auto& [verb, getter] : robot_getters())
    routes.push_back({"GET", "/api/v1/robots/{robot}/" + verb});
  for (const auto& [verb, command] : robot_commands())
    routes.push_back({"POST", "/api/v1/robots/{robot}/" + verb});
  for (const auto& [verb, path] : planning_route_list()) routes.push_back({verb, path});
  return routes;
}
std::string HttpServer::metrics() const { return impl_->metrics(); }
void HttpServer::publish_once() { impl_->publish_once(); }

std::vector<HttpServer::ConnectionStats> HttpServer::connection_stats() const {
  std::vector<ConnectionStats> result;
  for (const auto& session : impl_->live_sessions()) result.push_back(session->stats());
  return result;
}

}  // namespace tendril::server
