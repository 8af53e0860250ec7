// Publishing: channels advertised from ControlApi's topics and the topic sources, the newest message
// of each subscribed channel offered to every connection, status broadcasts (lease, parameters, safety
// events) and the front end's Prometheus metrics.
#include <algorithm>
#include <sstream>

#include "front_end.hpp"

namespace tendril::server {

using nlohmann::json;
using namespace tendril::server::http;

std::vector<std::shared_ptr<WsConnectionBase>> HttpServer::Impl::live_sessions() const {
  std::vector<std::shared_ptr<WsConnectionBase>> result;
  std::lock_guard lock(ws_mutex);
  for (const auto& [id, weak] : ws_sessions) {
    if (auto session = weak.lock()) result.push_back(std::move(session));
  }
  return result;
}

std::shared_ptr<const std::string> HttpServer::Impl::channel_payload(std::uint32_t id,
                                                                     std::uint64_t& time_ns) const {
  std::lock_guard lock(channels_mutex);
  const auto it = channels.find(id);
  if (it == channels.end()) return nullptr;
  time_ns = it->second.last_time_ns;
  return it->second.last_payload;
}

void HttpServer::Impl::register_ws(std::uint64_t id, const std::weak_ptr<WsConnectionBase>& session,
                                   std::vector<fg::Channel>& channels_now) {
  // Register and snapshot the channels under one lock, so an advertise diff is never missed.
  std::lock_guard channels_lock(channels_mutex);
  {
    std::lock_guard ws_lock(ws_mutex);
    ws_sessions[id] = session;
  }
  for (const auto& [channel_id, state] : channels) channels_now.push_back(state.channel);
}

void HttpServer::Impl::unregister_ws(std::uint64_t id) {
  std::lock_guard lock(ws_mutex);
  ws_sessions.erase(id);
}

void HttpServer::Impl::broadcast_status(const json& status, const std::vector<std::string>& only_lease_keys) {
  for (const auto& session : live_sessions()) {
    if (only_lease_keys.empty() || std::find(only_lease_keys.begin(), only_lease_keys.end(),
                                             session->identity().lease_key) != only_lease_keys.end()) {
      session->send_text(status);
    }
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

namespace {
std::optional<TopicInfo> schema_of(const ControlApi& api, const std::string& topic) {
  try {
    return api.topic_schema(topic);
  } catch (const std::exception&) {
    return std::nullopt;
  }
}
}  // namespace

void HttpServer::Impl::refresh_channels() {
  const auto api_topic_schema = [this](const std::string& topic) { return schema_of(api, topic); };
  std::vector<std::string> topics;
  try {
    topics = api.topics();
  } catch (const std::exception&) {
    return;  // keep the current channels; the next cycle asks again
  }
  for (const auto& [topic, source] : source_topics) topics.push_back(topic);
  std::vector<fg::Channel> added;
  std::vector<std::uint32_t> removed;
  std::vector<std::shared_ptr<WsConnectionBase>> sessions;
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
        channel.encoding = source->second.second.encoding;
        channel.schema_name = source->second.second.schema_name;
        channel.schema_encoding = source->second.second.schema_encoding;
        channel.schema = source->second.second.schema;
        channels[id].source = source->second.first;
      } else if (auto info = api_topic_schema(topic)) {
        // A robot type's own topic: it brings its schema.
        auto& channel = channels[id].channel;
        channel.id = id;
        channel.topic = topic;
        channel.encoding = info->encoding;
        channel.schema_name = info->schema_name;
        channel.schema_encoding = info->schema_encoding;
        channel.schema = info->schema;
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
  if (opts.tap) {
    for (const auto& channel : added) {
      try {
        opts.tap->channel(channel.id, channel.topic, channel.schema_name, channel.schema, channel.encoding,
                          channel.schema_encoding);
      } catch (const std::exception& e) {
        log(std::string("recording: channel ") + channel.topic + " not recorded: " + e.what());
      }
    }
  }
  for (auto& session : sessions) {
    if (!removed.empty()) {
      session->drop_channels(removed);
      session->send_text(fg::unadvertise(removed));
    }
    if (!added.empty()) session->send_text(fg::advertise(added));
  }
}

void HttpServer::Impl::tell_sources_demand(const std::set<std::uint32_t>& wanted) {
  // Caller holds publish_mutex. Sources hear only changes; a topic that loses its last subscriber
  // also loses its cached message, so a later subscriber is not sent an old one as current.
  for (const auto& [topic, entry] : source_topics) {
    bool now_wanted = false;
    {
      std::lock_guard lock(channels_mutex);
      const auto id = topic_ids.find(topic);
      now_wanted = id != topic_ids.end() && wanted.count(id->second) > 0;
      if (!now_wanted && id != topic_ids.end()) {
        const auto channel = channels.find(id->second);
        if (channel != channels.end()) channel->second.last_payload.reset();
      }
    }
    auto& told = source_demand[topic];
    if (told == now_wanted) continue;
    told = now_wanted;
    try {
      entry.first->set_demand(topic, now_wanted);
    } catch (const std::exception&) {
      told = !now_wanted;  // tell it again next cycle
    }
  }
}

void HttpServer::Impl::publish_once(bool only_sources) {
  std::lock_guard publish_lock(publish_mutex);
  refresh_channels();
  const auto sessions = live_sessions();
  report_new_safety_events();
  std::set<std::uint32_t> wanted;
  for (const auto& session : sessions) session->subscribed_channels(wanted);
  if (opts.tap) {
    // What the recording wants is fetched (and, from a source, produced) even with no subscriber.
    std::lock_guard lock(channels_mutex);
    for (const auto& [id, state] : channels) {
      if (wanted.count(id)) continue;
      // A source's topic the recording may keep only while watched, unless the source marks it cheap.
      const auto info = source_topics.find(state.channel.topic);
      const bool costly =
          state.source != nullptr && (info == source_topics.end() || !info->second.second.recorded_always);
      if (opts.tap->wants(state.channel.topic, costly)) wanted.insert(id);
    }
  }
  tell_sources_demand(wanted);
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
      if (opts.tap) opts.tap->message(channel_id, latest->log_time_ns, latest->payload);
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
    if (opts.tap) opts.tap->message(channel_id, time_ns, std::move(payload));
  }
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
  metric("tendril_ws_closed_for_backlog_total", "counter",
         "Connections closed because their outgoing backlog stayed full (a client that stopped reading).",
         ws_closed_for_backlog.load());
  metric("tendril_ws_queue_max", "gauge", "Largest outgoing queue of any connection (messages).", max_queue);
  metric("tendril_http_connection_exceptions_total", "counter",
         "Exceptions caught in a connection's handler (that connection was closed, the server went on).",
         connection_exceptions.load());
  {
    std::lock_guard lock(sessions_mutex);
    metric("tendril_http_sessions", "gauge", "Console cookie sessions remembered.", cookie_sessions.size());
  }
  // Connection limits (connection_limits.hpp, README "Limits").
  const auto connection_counts = connections.counts();
  const auto connection_limits = connections.limits();
  out << "# HELP tendril_http_connections Open connections (HTTP and WebSocket), by whether they have "
         "presented a valid token or cookie.\n# TYPE tendril_http_connections gauge\n"
      << "tendril_http_connections{state=\"authenticated\"} " << connection_counts.authenticated << '\n'
      << "tendril_http_connections{state=\"unauthenticated\"} " << connection_counts.unauthenticated << '\n';
  out << "# HELP tendril_http_connection_limit The connection limits in force.\n"
         "# TYPE tendril_http_connection_limit gauge\n"
      << "tendril_http_connection_limit{kind=\"total\"} " << connection_limits.total << '\n'
      << "tendril_http_connection_limit{kind=\"unauthenticated\"} " << connection_limits.unauthenticated
      << '\n'
      << "tendril_http_connection_limit{kind=\"unauthenticated_per_address\"} "
      << connection_limits.per_address << '\n';
  metric("tendril_http_connections_evicted_total", "counter",
         "Idle unauthenticated connections closed to make room for a new connection.",
         connection_counts.evicted);
  out << "# HELP tendril_http_connections_refused_total Connections closed at once at a limit, with no idle "
         "unauthenticated connection to make room.\n# TYPE tendril_http_connections_refused_total counter\n"
      << "tendril_http_connections_refused_total{limit=\"total\"} " << connection_counts.refused_full << '\n'
      << "tendril_http_connections_refused_total{limit=\"per_address\"} "
      << connection_counts.refused_per_address << '\n'
      << "tendril_http_connections_refused_total{limit=\"descriptors\"} " << accepted_and_closed.load()
      << '\n';
  metric("tendril_http_accept_backoffs_total", "counter",
         "Times the listener ran out of file descriptors (or memory) and waited before accepting again.",
         accept_backoffs.load());
  out << "# HELP tendril_http_requests_total HTTP responses sent, by status code.\n"
         "# TYPE tendril_http_requests_total counter\n";
  {
    std::lock_guard lock(status_mutex);
    for (const auto& [status, count] : http_by_status) {
      out << "tendril_http_requests_total{status=\"" << status << "\"} " << count << '\n';
    }
  }
  out << "# HELP tendril_http_requests_refused_total Requests refused while being read, by reason.\n"
         "# TYPE tendril_http_requests_refused_total counter\n";
  {
    std::lock_guard lock(status_mutex);
    for (const auto& [reason, count] : refused_requests) {
      out << "tendril_http_requests_refused_total{reason=\"" << reason << "\"} " << count << '\n';
    }
  }
  out << "# HELP tendril_lease_held 1 when an operator holds the robot's command lease.\n"
         "# TYPE tendril_lease_held gauge\n";
  const auto now = SteadyClock::now();
  for (const auto& robot : leases.robots()) {
    out << "tendril_lease_held{robot=\"" << robot << "\"} "
        << (leases.find(robot)->status({}, now).held ? 1 : 0) << '\n';
  }
  for (const auto& source : opts.topic_sources)
    if (source) out << source->metrics();
  for (const auto& source : metrics_sources) out << source();
  return out.str();
}

}  // namespace tendril::server
