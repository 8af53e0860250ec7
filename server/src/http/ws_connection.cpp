#include "ws_connection.hpp"

#include <algorithm>

#include <boost/asio/post.hpp>

#include "tendril/server/version.hpp"

namespace tendril::server {

using nlohmann::json;
using namespace tendril::server::http;

WsConnection::WsConnection(net::any_io_executor executor, HttpServer::Impl& server, Identity identity,
                           std::uint64_t id)
    : server_(server),
      executor_(std::move(executor)),
      identity_(std::move(identity)),
      id_(id),
      tokens_(server.opts.ws_client_burst),
      last_refill_(SteadyClock::now()) {}

void WsConnection::offer_parameter_updates(const json& changed) {
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

// Queues a JSON message. Called from any thread. A client whose control queue overflows is not
// reading: it is closed rather than allowed to grow memory.
void WsConnection::send_text(const json& message) {
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
    hard_close();
  } else if (kick) {
    post_write();
  }
}

// Service responses travel in the control queue (never dropped), tagged binary.
void WsConnection::send_binary(std::string frame) {
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
    post_write();
  }
}

bool WsConnection::write_stalled_locked(SteadyClock::time_point now) const {
  return writing_ && write_started_ != SteadyClock::time_point{} &&
         now - write_started_ > server_.opts.ws_stalled_write_timeout;
}

void WsConnection::close_for_backlog() {
  ++server_.ws_closed_for_backlog;
  server_.log("WebSocket connection " + std::to_string(id_) + " (" + identity_.label +
              ") closed: it stopped reading (a write waited longer than " +
              std::to_string(server_.opts.ws_stalled_write_timeout.count()) + " ms)");
  hard_close();
}

// Offers a topic message to this connection's subscriptions of `channel_id`. Only the newest waits
// per subscription: an unsent older one is replaced and counted as dropped.
void WsConnection::offer(std::uint32_t channel_id, const std::shared_ptr<const std::string>& payload,
                         std::uint64_t time_ns, std::optional<std::uint32_t> only_subscription) {
  bool kick = false;
  bool stalled = false;
  {
    std::lock_guard lock(out_mutex_);
    if (closed_) return;
    if (write_stalled_locked(SteadyClock::now())) {
      stalled = !backlog_close_posted_;
      backlog_close_posted_ = true;
    }
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
    if (!stalled && !latest_.empty() && !writing_) kick = writing_ = true;
  }
  if (stalled) {
    close_for_backlog();
  } else if (kick) {
    post_write();
  }
}

void WsConnection::subscribed_channels(std::set<std::uint32_t>& out) const {
  std::lock_guard lock(out_mutex_);
  for (const auto& [subscription, channel] : subscriptions_) out.insert(channel);
}

void WsConnection::drop_channels(const std::vector<std::uint32_t>& removed) {
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

HttpServer::ConnectionStats WsConnection::stats() const {
  std::lock_guard lock(out_mutex_);
  return {id_, control_queue_.size() + latest_.size(), subscriptions_.size(), writing_, dropped_};
}

void WsConnection::hard_close() {
  {
    std::lock_guard lock(out_mutex_);
    closed_ = true;
    control_queue_.clear();
    latest_.clear();
    latest_order_.clear();
  }
  net::post(executor_, [self = shared_from_this()] { self->shutdown_socket(); });
}

void WsConnection::post_write() {
  net::post(executor_, [self = shared_from_this()] { self->do_write(); });
}

void WsConnection::on_open() {
  ++server_.ws_connections_total;
  std::vector<fg::Channel> channels;
  server_.register_ws(id_, weak_from_this(), channels);
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
}

bool WsConnection::on_message(bool is_text, const std::string& message) {
  ++server_.ws_client_messages;
  if (!take_rate_token()) {
    violation("client message rate limit exceeded (" + std::to_string(server_.opts.ws_client_rate_hz) +
              " messages/s); message ignored");
    return true;
  }
  try {
    if (is_text) {
      handle_text(message);
    } else {
      return handle_binary(message);
    }
  } catch (const std::exception& e) {
    send_text(fg::status(fg::StatusLevel::kError, std::string("internal error: ") + e.what()));
  }
  return true;
}

bool WsConnection::take_rate_token() {
  const auto now = SteadyClock::now();
  const double elapsed = std::chrono::duration<double>(now - last_refill_).count();
  last_refill_ = now;
  tokens_ = std::min(server_.opts.ws_client_burst, tokens_ + elapsed * server_.opts.ws_client_rate_hz);
  if (tokens_ < 1.0) return false;
  tokens_ -= 1.0;
  return true;
}

void WsConnection::violation(const std::string& message) {
  ++violations_;
  ++server_.ws_violations;
  send_text(fg::status(fg::StatusLevel::kError, message));
  if (violations_ >= server_.opts.ws_max_violations && !closing_) {
    ++server_.ws_closed_for_abuse;
    send_text(fg::status(fg::StatusLevel::kError, "too many protocol violations; closing the connection"));
    begin_close(kClosePolicy);
  }
}

void WsConnection::do_write() {
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
    write_started_ = SteadyClock::now();
    lock.unlock();
    write_message(current_text_, binary);
    return;
  }
  while (!latest_order_.empty()) {
    const std::uint32_t subscription = latest_order_.front();
    latest_order_.pop_front();
    auto it = latest_.find(subscription);
    if (it == latest_.end()) continue;  // unsubscribed meanwhile
    current_data_ = std::move(it->second);
    latest_.erase(it);
    write_started_ = SteadyClock::now();
    lock.unlock();
    write_data(current_data_);
    return;
  }
  writing_ = false;
  write_started_ = {};
  const bool close_now = close_pending_;
  lock.unlock();
  if (close_now) finish_close();
}

void WsConnection::on_write_done(bool ok, std::size_t bytes) {
  if (!ok) {
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

void WsConnection::begin_close(int code) {
  closing_ = true;
  close_code_ = code;
  std::unique_lock lock(out_mutex_);
  close_pending_ = true;
  if (!writing_) {
    lock.unlock();
    finish_close();
  }
}

void WsConnection::finish_close() {
  {
    std::lock_guard lock(out_mutex_);
    if (closed_) return;
    closed_ = true;
  }
  // Reading stopped when the close began, so the close completion is where the connection ends.
  close_with(close_code_);
}

void WsConnection::on_closed() {
  if (gone_) return;
  gone_ = true;
  {
    std::lock_guard lock(out_mutex_);
    closed_ = true;
    control_queue_.clear();
    latest_.clear();
    latest_order_.clear();
  }
  server_.unregister_ws(id_);
  server_.connection_closed(identity_);
}

void WsConnection::handle_text(const std::string& text) {
  auto parsed = fg::parse_client_text(text);
  if (auto* error = std::get_if<fg::ProtocolError>(&parsed)) {
    violation(error->message);
  } else if (auto* unsupported = std::get_if<fg::UnsupportedOp>(&parsed)) {
    send_text(
        fg::status(fg::StatusLevel::kWarning, "op \"" + unsupported->op + "\" is not supported by tendril"));
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
json WsConnection::select_parameters(const std::vector<std::string>& names) const {
  json all = server_.api.parameters();
  if (names.empty()) return all;
  json selected = json::array();
  for (const auto& p : all) {
    if (std::find(names.begin(), names.end(), p.value("name", std::string())) != names.end())
      selected.push_back(p);
  }
  return selected;
}

void WsConnection::handle_set_parameters(const fg::SetParametersOp& set) {
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

void WsConnection::handle_subscribe(const fg::SubscribeOp& subscribe) {
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
    std::uint64_t time_ns = 0;
    if (auto payload = server_.channel_payload(sub.channel_id, time_ns))
      offer(sub.channel_id, payload, time_ns, sub.id);
  }
}

void WsConnection::handle_client_advertise(const fg::ClientAdvertiseOp& advertise) {
  if (identity_.role != Role::kOperator) {
    send_text(fg::status(fg::StatusLevel::kError, "advertise: viewers may not publish"));
    return;
  }
  for (const auto& channel : advertise.channels) {
    // Operator streams: "/{robot}/servo_jv" ({"velocity":[...]}), "/{robot}/servo_cv" ({"linear",
    // "angular"}) and the robot type's streamable commands (e.g. a console joystick).
    const auto segments = split_path(channel.topic);
    std::optional<CommandRef> command;
    if (segments.size() == 2 && channel.encoding == "json" && server_.api.has_robot(segments[0])) {
      if (segments[1] == "servo_jv") command = CommandRef(Command::kServoJv);
      if (segments[1] == "servo_cv") command = CommandRef(Command::kServoCv);
      for (const auto& info : server_.api.robot_commands(segments[0]))
        if (info.streamable && info.name == segments[1])
          command = CommandRef(Command::kRobotCommand, info.name);
    }
    if (!command) {
      send_text(fg::status(
          fg::StatusLevel::kError,
          "advertise: tendril accepts client channels \"/{robot}/servo_jv\", \"/{robot}/servo_cv\" "
          "and a robot type's streamable commands, with encoding \"json\" only; refused \"" +
              channel.topic + "\""));
      continue;
    }
    if (client_channels_.size() >= 64) {
      send_text(fg::status(fg::StatusLevel::kError, "advertise: at most 64 client channels"));
      return;
    }
    client_channels_.insert_or_assign(channel.id, std::pair{segments[0], *command});
  }
}

bool WsConnection::handle_binary(const std::string& data) {
  auto parsed = fg::parse_client_binary(data);
  if (auto* error = std::get_if<fg::ProtocolError>(&parsed)) {
    violation(error->message);
  } else if (auto* message = std::get_if<fg::ClientMessageData>(&parsed)) {
    const auto it = client_channels_.find(message->channel_id);
    if (it == client_channels_.end()) {
      violation("message data on channel " + std::to_string(message->channel_id) +
                " that was not advertised");
      return true;
    }
    const ApiResult body = parse_json_body(message->payload, server_.opts.max_ws_message_bytes);
    const auto& [robot, command] = it->second;
    const ApiResult result = body.ok() ? server_.execute(command, robot, body.body, identity_) : body;
    if (!result.ok()) {
      const std::string leaf = command.kind == Command::kRobotCommand ? command.name
                               : command.kind == Command::kServoCv    ? "servo_cv"
                                                                      : "servo_jv";
      send_text(fg::status(fg::StatusLevel::kWarning,
                           "/" + robot + "/" + leaf + ": " + result.code + ": " + result.message));
    }
  } else if (auto* call = std::get_if<fg::ServiceCallRequest>(&parsed)) {
    return run_service_call(*call);
  }
  return true;
}

// The e-stop is answered here, on the I/O thread; every other service call's work runs on the request
// lane (as a REST request's does), and this connection reads its next message once it is done.
bool WsConnection::run_service_call(const fg::ServiceCallRequest& call) {
  const auto estop =
      std::find_if(server_.service_defs.begin(), server_.service_defs.end(), [&](const auto& d) {
        return d.id == call.service_id && d.command && d.command->kind == Command::kEstop;
      });
  if (estop != server_.service_defs.end() || !server_.request_lane) {
    handle_service_call(call);
    return true;
  }
  // The call's views point into this connection's read buffer: the lane gets its own copies.
  auto owned = std::make_shared<std::pair<std::string, std::string>>(call.encoding, call.payload);
  const bool queued = server_.request_lane->try_submit(
      [self = shared_from_this(), owned, service_id = call.service_id, call_id = call.call_id] {
        self->handle_service_call(fg::ServiceCallRequest{service_id, call_id, owned->first, owned->second});
        self->resume_reading();
      });
  if (queued) return false;
  send_text(fg::service_call_failure(call.service_id, call.call_id,
                                     "the server has " + std::to_string(server_.request_lane->max_queued()) +
                                         " requests waiting; call again in a moment"));
  return true;
}

void WsConnection::handle_service_call(const fg::ServiceCallRequest& call) {
  const ServiceDef* def = nullptr;
  for (const auto& candidate : server_.service_defs) {
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
        result = ApiResult::error(400, "missing_robot", std::string(def->name) + " needs a \"robot\" string");
      } else {
        robot = it->get<std::string>();
        body.erase("robot");
      }
    }
    if (result.ok()) {
      if (def->command) {
        result = server_.execute(*def->command, robot, body, identity_);
      } else {
        // Without "robot": every robot's lease, as POST /api/v1/lease.
        const auto action = body.find("action");
        const auto token = body.find("takeover_token");
        const auto lease_robot = body.find("robot");
        if (lease_robot != body.end() && !lease_robot->is_string()) {
          result = ApiResult::error(400, "bad_request", "lease: \"robot\" must be a robot's name");
        } else {
          result = server_.lease_action(
              action != body.end() && action->is_string() ? action->get<std::string>() : "acquire", identity_,
              token != body.end() && token->is_string() ? token->get<std::string>() : std::string(),
              lease_robot != body.end() ? lease_robot->get<std::string>() : std::string());
        }
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

}  // namespace tendril::server
