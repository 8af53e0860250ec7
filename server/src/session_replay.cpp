#include "tendril/server/session_replay.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace tendril::server {

namespace {

std::uint64_t wall_time_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

std::string status_schema() {
  const nlohmann::json time = {{"type", "integer"}, {"description", "log time, ns since the Unix epoch"}};
  return nlohmann::json{
      {"title", "tendril.ReplayStatus"},
      {"description", "Where tendrild --replay is in its recording"},
      {"type", "object"},
      {"properties",
       {{"start_ns", time},
        {"end_ns", time},
        {"position_ns", time},
        {"rate", {{"type", "number"}, {"description", "playback speed (1 = recorded pace)"}}},
        {"playing", {{"type", "boolean"}}},
        {"ended", {{"type", "boolean"}, {"description", "the last message has been replayed"}}},
        {"messages_sent", {{"type", "integer"}}},
        {"error", {{"type", "string"}, {"description", "a damaged chunk stopped the replay"}}}}}}
      .dump();
}

ApiResult bad_control(const std::string& message) {
  return ApiResult::error(400, "bad_replay_control", message);
}

}  // namespace

SessionReplay::SessionReplay(const std::filesystem::path& file_or_folder, ReplayOptions options)
    : options_(std::move(options)), files_(record::mcap_files(file_or_folder)) {
  if (!(options_.status_rate_hz > 0 && options_.status_rate_hz <= 1000))
    throw std::invalid_argument("replay status_rate_hz must be in (0, 1000]");
  bool any = false;
  std::uint64_t messages = 0;
  for (const auto& file : files_) {
    auto reader = std::make_unique<record::McapReader>(file, options_.reader);
    if (!reader->finalised()) {
      log(file.filename().string() + " was not finalised (the recording was cut): replaying its " +
          std::to_string(reader->message_count()) + " messages up to its last whole chunk");
    }
    if (reader->message_count() > 0) {
      start_ns_ = any ? std::min(start_ns_, reader->start_time()) : reader->start_time();
      end_ns_ = any ? std::max(end_ns_, reader->end_time()) : reader->end_time();
      any = true;
    }
    messages += reader->message_count();
    for (const auto& entry : reader->channels()) {
      const record::McapChannel& channel = entry.second;
      if (channel.topic == kStatusTopic) continue;  // a recorded replay's status: this replay's own wins
      if (std::any_of(topics_.begin(), topics_.end(),
                      [&](const TopicInfo& t) { return t.topic == channel.topic; })) {
        continue;
      }
      TopicInfo info;
      info.topic = channel.topic;
      info.encoding = channel.message_encoding;
      if (const auto* schema = reader->schema_of(channel)) {
        info.schema_name = schema->name;
        info.schema_encoding = schema->encoding;
        info.schema.assign(schema->data.begin(), schema->data.end());
      } else {
        info.schema_encoding.clear();
      }
      topics_.push_back(std::move(info));
    }
    readers_.push_back(std::move(reader));
  }
  if (!any) throw record::McapError("no messages to replay in " + file_or_folder.string());
  topics_.push_back(TopicInfo{kStatusTopic, "tendril.ReplayStatus", status_schema(), "json", "jsonschema"});
  anchor_position_ = start_ns_;
  log("replaying " + std::to_string(messages) + " messages on " + std::to_string(topics_.size() - 1) +
      " topics from " + std::to_string(files_.size()) + " file(s), " +
      std::to_string(static_cast<double>(end_ns_ - start_ns_) / 1e9) + " s of log time");
}

SessionReplay::~SessionReplay() { stop(); }

void SessionReplay::log(const std::string& line) const {
  if (options_.log) options_.log(line);
}

void SessionReplay::start() {
  std::lock_guard lock(mutex_);
  if (thread_.joinable() || stopping_) return;
  playing_ = options_.start_playing;
  anchor_wall_ = SteadyClock::now();
  thread_ = std::thread([this] { run(); });
}

void SessionReplay::stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

std::uint64_t SessionReplay::position_at(SteadyClock::time_point now) const {
  if (!playing_) return anchor_position_;
  const double elapsed_ns =
      std::chrono::duration<double, std::nano>(std::max(now - anchor_wall_, SteadyClock::duration::zero()))
          .count();
  // The offset in double (ns over seconds: exact enough), the sum in integers: a log time near 1.8e18 ns
  // has no sub-microsecond precision as a double.
  const double offset = elapsed_ns * rate_;
  if (offset >= static_cast<double>(end_ns_ - std::min(anchor_position_, end_ns_))) return end_ns_;
  return anchor_position_ + static_cast<std::uint64_t>(offset);
}

void SessionReplay::reanchor(SteadyClock::time_point now) {
  anchor_position_ = position_at(now);
  anchor_wall_ = now;
}

void SessionReplay::publish(const std::string& topic, std::shared_ptr<const std::string> payload) {
  Slot& slot = slots_[topic];
  slot.payload = std::move(payload);
  ++slot.version;
  slot.log_time_ns = wall_time_ns();
}

nlohmann::json SessionReplay::status_json() const {
  nlohmann::json j = {{"start_ns", start_ns_},
                      {"end_ns", end_ns_},
                      {"position_ns", position_at(SteadyClock::now())},
                      {"rate", rate_},
                      {"playing", playing_},
                      {"ended", ended_},
                      {"messages_sent", messages_sent_}};
  if (!error_.empty()) j["error"] = error_;
  return j;
}

std::shared_ptr<const std::string> SessionReplay::status_payload() const {
  return std::make_shared<const std::string>(status_json().dump());
}

void SessionReplay::run() {
  std::vector<const record::McapReader*> readers;
  for (const auto& r : readers_) readers.push_back(r.get());
  std::map<std::string, const TopicInfo*> advertised;
  for (const auto& t : topics_) advertised[t.topic] = &t;
  std::map<std::string, bool> warned;  // topics whose later files changed encoding or schema
  // A message is replayed on its advertised channel only if it has that channel's encoding and schema.
  const auto publishable = [&](const record::McapMessageCursor::Item& item) {
    const std::string& topic = item.channel->topic;
    const auto info = advertised.find(topic);
    if (info != advertised.end() && info->second->encoding == item.channel->message_encoding &&
        info->second->schema_name == (item.schema ? item.schema->name : "")) {
      return true;
    }
    if (topic != kStatusTopic && !warned[topic]) {
      warned[topic] = true;
      log("topic " + topic + " changes encoding or schema in " + files_[item.reader].filename().string() +
          "; its messages there are not replayed");
    }
    return false;
  };

  std::unique_lock lock(mutex_);
  record::McapMessageCursor cursor(readers, anchor_position_);
  std::optional<record::McapMessageCursor::Item> pending;
  const auto status_period = std::chrono::duration_cast<SteadyClock::duration>(
      std::chrono::duration<double>(1.0 / options_.status_rate_hz));
  auto next_status = SteadyClock::now();
  std::uint64_t status_changes = ~std::uint64_t{0};
  while (!stopping_) {
    bool ready = false;
    if (seek_pending_) {
      seek_pending_ = false;
      pending.reset();
      // The state at the new position: each topic's last message in the lookback before it, published at
      // once, so that a client paused after a seek shows where the recording is (on-change topics older
      // than the lookback are not found).
      const std::uint64_t target = anchor_position_;
      const std::uint64_t from = target - std::min(target - start_ns_, options_.seek_lookback_ns);
      std::map<std::string, std::shared_ptr<const std::string>> state;
      try {
        cursor.seek(from);
        record::McapMessageCursor::Item item;
        while (cursor.next(item)) {
          if (item.message.log_time >= target) {
            pending = std::move(item);
            break;
          }
          if (publishable(item)) {
            state[item.channel->topic] =
                std::make_shared<const std::string>(item.message.data.begin(), item.message.data.end());
          }
        }
      } catch (const std::exception& e) {
        error_ = e.what();
        playing_ = false;
        ++changes_;
        log("stopped: " + error_);
      }
      for (auto& [topic, payload] : state) publish(topic, std::move(payload));
      messages_sent_ += state.size();
      ready = !state.empty();
    }
    if (!pending && !ended_ && error_.empty()) {
      record::McapMessageCursor::Item item;
      try {
        if (cursor.next(item)) {
          pending = std::move(item);
        } else {
          ended_ = true;
          playing_ = false;
          anchor_position_ = end_ns_;
          ++changes_;
          log("the end of the recording was reached after " + std::to_string(messages_sent_) + " messages");
        }
      } catch (const std::exception& e) {
        error_ = e.what();
        reanchor(SteadyClock::now());
        playing_ = false;
        ++changes_;
        log("stopped: " + error_);
      }
    }
    const auto now = SteadyClock::now();
    if (pending && playing_ && pending->message.log_time <= position_at(now)) {
      if (publishable(*pending)) {
        const auto& data = pending->message.data;
        publish(pending->channel->topic, std::make_shared<const std::string>(data.begin(), data.end()));
        ++messages_sent_;
        ready = true;
      }
      pending.reset();
    }
    if ((playing_ && now >= next_status) || status_changes != changes_) {
      publish(kStatusTopic, status_payload());
      next_status = now + status_period;
      status_changes = changes_;
      ready = true;
    }
    if (ready) {
      const auto callback = ready_;
      lock.unlock();
      if (callback) callback();
      lock.lock();
      continue;
    }
    if (pending && playing_ && pending->message.log_time <= position_at(SteadyClock::now())) continue;
    // Sleep until the next message is due, the next status, or a control changes the plan.
    auto until = now + std::chrono::seconds(1);
    if (playing_) until = std::min(until, next_status);
    if (pending && playing_) {
      const double ahead_ns = static_cast<double>(pending->message.log_time -
                                                  std::min(pending->message.log_time, anchor_position_)) /
                              rate_;
      until =
          std::min(until, anchor_wall_ + std::chrono::duration_cast<SteadyClock::duration>(
                                             std::chrono::duration<double, std::nano>(std::ceil(ahead_ns))));
    }
    const std::uint64_t seen = changes_;
    wake_.wait_until(lock, until, [&] { return stopping_ || changes_ != seen || seek_pending_; });
  }
}

SessionReplay::Status SessionReplay::status() const {
  std::lock_guard lock(mutex_);
  Status s;
  s.start_ns = start_ns_;
  s.end_ns = end_ns_;
  s.position_ns = position_at(SteadyClock::now());
  s.rate = rate_;
  s.playing = playing_;
  s.ended = ended_;
  s.messages_sent = messages_sent_;
  s.error = error_;
  return s;
}

void SessionReplay::set_playing(bool playing) {
  {
    std::lock_guard lock(mutex_);
    const auto now = SteadyClock::now();
    reanchor(now);
    if (playing && (ended_ || !error_.empty())) {
      // Play after the end starts over; after a damaged chunk, tries again from where it stopped.
      if (ended_) anchor_position_ = start_ns_;
      seek_pending_ = true;
      ended_ = false;
      error_.clear();
    }
    playing_ = playing;
    ++changes_;
  }
  wake_.notify_all();
}

void SessionReplay::set_rate(double rate) {
  if (!std::isfinite(rate) || rate < kMinRate || rate > kMaxRate) {
    std::ostringstream message;
    message << "replay rate must be from " << kMinRate << " to " << kMaxRate << " (1 = recorded pace), got "
            << rate;
    throw std::invalid_argument(message.str());
  }
  {
    std::lock_guard lock(mutex_);
    reanchor(SteadyClock::now());
    rate_ = rate;
    ++changes_;
  }
  wake_.notify_all();
}

void SessionReplay::seek(std::uint64_t position_ns) {
  if (position_ns < start_ns_ || position_ns > end_ns_) {
    throw std::invalid_argument("position_ns " + std::to_string(position_ns) +
                                " is outside the recording, which spans " + std::to_string(start_ns_) +
                                " to " + std::to_string(end_ns_) + " ns");
  }
  {
    std::lock_guard lock(mutex_);
    anchor_position_ = position_ns;
    anchor_wall_ = SteadyClock::now();
    seek_pending_ = true;
    ended_ = false;
    error_.clear();
    ++changes_;
  }
  wake_.notify_all();
}

std::vector<TopicInfo> SessionReplay::topics() const { return topics_; }

std::optional<TopicPayload> SessionReplay::latest(const std::string& topic,
                                                  std::uint64_t since_version) const {
  std::lock_guard lock(mutex_);
  const auto it = slots_.find(topic);
  if (it == slots_.end() || it->second.version <= since_version || !it->second.payload) return std::nullopt;
  return TopicPayload{it->second.payload, it->second.version, it->second.log_time_ns};
}

void SessionReplay::set_ready_callback(std::function<void()> ready) {
  std::lock_guard lock(mutex_);
  ready_ = std::move(ready);
}

std::string SessionReplay::metrics() const {
  const Status s = status();
  std::ostringstream out;
  out << "# HELP tendril_replay_messages_sent_total Recorded messages replayed.\n"
         "# TYPE tendril_replay_messages_sent_total counter\n"
      << "tendril_replay_messages_sent_total " << s.messages_sent << '\n'
      << "# HELP tendril_replay_position_seconds Log time reached since the recording's first message.\n"
         "# TYPE tendril_replay_position_seconds gauge\n"
      << "tendril_replay_position_seconds " << static_cast<double>(s.position_ns - s.start_ns) / 1e9 << '\n';
  return out.str();
}

ApiResult SessionReplay::replay_status() const {
  nlohmann::json files = nlohmann::json::array();
  for (std::size_t i = 0; i < files_.size(); ++i) {
    const auto& r = *readers_[i];
    files.push_back({{"name", files_[i].filename().string()},
                     {"messages", r.message_count()},
                     {"finalised", r.finalised()},
                     {"start_ns", r.start_time()},
                     {"end_ns", r.end_time()}});
  }
  nlohmann::json topics = nlohmann::json::array();
  for (const auto& t : topics_) topics.push_back(t.topic);
  std::lock_guard lock(mutex_);
  nlohmann::json body = status_json();
  body["files"] = std::move(files);
  body["topics"] = std::move(topics);
  return ApiResult::success(std::move(body));
}

ApiResult SessionReplay::control_replay(const nlohmann::json& body) {
  if (!body.is_object())
    return bad_control("expected a JSON object such as {\"playing\": true, \"rate\": 2}");
  if (body.empty()) return bad_control("nothing to change: give playing, rate or position_ns");
  for (const auto& item : body.items()) {
    if (item.key() != "playing" && item.key() != "rate" && item.key() != "position_ns") {
      return bad_control("unknown key \"" + item.key() +
                         "\"; the replay takes playing, rate and position_ns");
    }
  }
  std::optional<bool> playing;
  std::optional<double> rate;
  std::optional<std::uint64_t> position;
  if (body.contains("playing")) {
    if (!body.at("playing").is_boolean()) return bad_control("playing must be true or false");
    playing = body.at("playing").get<bool>();
  }
  if (body.contains("rate")) {
    const auto& v = body.at("rate");
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < kMinRate ||
        v.get<double>() > kMaxRate) {
      return bad_control("rate must be a number from 0.1 to 10 (1 = recorded pace), got " + v.dump());
    }
    rate = v.get<double>();
  }
  if (body.contains("position_ns")) {
    const auto& v = body.at("position_ns");
    if (v.is_number_unsigned()) {
      position = v.get<std::uint64_t>();
    } else if (v.is_number_integer()) {
      return bad_control("position_ns must not be negative, got " + v.dump());
    } else {
      return bad_control(
          "position_ns must be an integer number of nanoseconds (a log time from start_ns to "
          "end_ns), got " +
          v.dump());
    }
    // JavaScript numbers (the console's) hold a log time in ns only to ±256 ns: a position within 1 ms
    // of the span is its edge; further out is a mistake.
    constexpr std::uint64_t kSlack = 1'000'000;
    if (*position < start_ns_ && start_ns_ - *position <= kSlack) position = start_ns_;
    if (*position > end_ns_ && *position - end_ns_ <= kSlack) position = end_ns_;
    if (*position < start_ns_ || *position > end_ns_) {
      return bad_control("position_ns " + v.dump() + " is outside the recording, which spans start_ns " +
                         std::to_string(start_ns_) + " to end_ns " + std::to_string(end_ns_));
    }
  }
  // Validated whole before anything changes: all or nothing. A pause goes first, so that time spent
  // waiting for the replay thread (it holds the lock while it reads the lookback after a seek) does not
  // move a paused position away from the one asked for; a play goes last, from the new position.
  if (playing && !*playing) set_playing(false);
  if (rate) set_rate(*rate);
  if (position) seek(*position);
  if (playing && *playing) set_playing(true);
  return replay_status();
}

}  // namespace tendril::server
