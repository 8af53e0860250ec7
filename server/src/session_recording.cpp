#include "tendril/server/session_recording.hpp"

#include <cmath>

#include "tendril/server/config.hpp"

namespace tendril::server {

namespace {

std::vector<std::uint8_t> bytes_of(const std::string& text) { return {text.begin(), text.end()}; }

std::string commands_schema() {
  return nlohmann::json{
      {"title", "tendril.Command"},
      {"description", "A robot command as the server received and executed it"},
      {"type", "object"},
      {"properties",
       {{"robot", {{"type", "string"}, {"description", "empty for the e-stop and its reset"}}},
        {"command",
         {{"type", "string"}, {"description", "CRTK name (move_jp, servo_jv, …) or the robot type's"}}},
        {"who", {{"type", "string"}, {"description", "the client's label"}}},
        {"status", {{"type", "integer"}, {"description", "HTTP status of the outcome"}}},
        {"error", {{"type", "string"}, {"description", "code: message when refused; empty when executed"}}},
        {"body", {{"type", "object"}, {"description", "the request as sent"}}}}}}
      .dump();
}

}  // namespace

RecordingConfig parse_recording_config(const nlohmann::json& recording,
                                       const std::filesystem::path& server_file) {
  RecordingConfig c;
  if (recording.is_null()) return c;
  const std::string file = server_file.string();
  const auto fail = [&](const std::string& key, const std::string& expected) {
    std::string got = recording.contains(key) ? recording.at(key).dump() : "nothing";
    if (got.size() > 60) got = got.substr(0, 57) + "...";
    throw ConfigError(file + ": recording." + key + ": expected " + expected + ", got " + got);
  };
  if (!recording.is_object())
    throw ConfigError(file + ": recording: expected an object, got " + recording.dump());
  for (const auto& item : recording.items()) {
    static const std::vector<std::string> kKeys = {"enabled",       "directory",        "compression",
                                                   "max_file_mb",   "max_file_minutes", "images",
                                                   "keep_total_mb", "keep_days",        "note"};
    if (std::find(kKeys.begin(), kKeys.end(), item.key()) == kKeys.end()) {
      std::string message = file;
      message += ": recording.";
      message += item.key();
      message +=
          ": unknown key; expected enabled, directory, compression, max_file_mb, max_file_minutes, images, "
          "keep_total_mb, keep_days or note";
      throw ConfigError(message);
    }
  }
  c.enabled = true;
  if (recording.contains("enabled")) {
    if (!recording.at("enabled").is_boolean()) fail("enabled", "true or false");
    c.enabled = recording.at("enabled").get<bool>();
  }
  std::filesystem::path dir = "recordings";
  if (recording.contains("directory")) {
    if (!recording.at("directory").is_string() || recording.at("directory").get<std::string>().empty())
      fail("directory", "a folder");
    dir = recording.at("directory").get<std::string>();
  }
  c.directory = dir.is_relative() ? (server_file.parent_path() / dir).lexically_normal() : dir;
  if (recording.contains("compression")) {
    const auto& v = recording.at("compression");
    const std::string name = v.is_string() ? v.get<std::string>() : "";
    if (name == "zstd") {
      c.compression = record::Compression::kZstd;
    } else if (name == "lz4") {
      c.compression = record::Compression::kLz4;
    } else if (name == "none") {
      c.compression = record::Compression::kNone;
    } else {
      fail("compression", "\"zstd\", \"lz4\" or \"none\"");
    }
  }
  const auto number = [&](const std::string& key, double lo, double hi, double fallback) {
    if (!recording.contains(key)) return fallback;
    const auto& v = recording.at(key);
    if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < lo || v.get<double>() > hi)
      fail(key, "a number from " + std::to_string(lo) + " to " + std::to_string(hi));
    return v.get<double>();
  };
  c.max_file_bytes = static_cast<std::uint64_t>(number("max_file_mb", 1.0, 1e6, 1024.0) * 1024.0 * 1024.0);
  c.max_file_duration_ns = static_cast<std::uint64_t>(number("max_file_minutes", 0.05, 1e5, 60.0) * 60e9);
  if (recording.contains("keep_total_mb"))
    c.keep_total_bytes = static_cast<std::uint64_t>(number("keep_total_mb", 1.0, 1e9, 0.0) * 1024.0 * 1024.0);
  if (recording.contains("keep_days")) {
    const double days = number("keep_days", 0.0, 36500.0, 0.0);
    if (!(days > 0)) fail("keep_days", "a number of days greater than 0");
    c.keep_age = std::chrono::seconds(static_cast<std::int64_t>(std::ceil(days * 86400.0)));
  }
  if (recording.contains("images")) {
    const auto& v = recording.at("images");
    if (v == "always") {
      c.images_always = true;
    } else if (v == "watched") {
      c.images_always = false;
    } else {
      fail("images", "\"watched\" or \"always\"");
    }
  }
  return c;
}

namespace {
record::RecorderOptions recorder_options(const RecordingConfig& config,
                                         std::function<void(std::string_view)> log) {
  std::error_code ec;
  std::filesystem::create_directories(config.directory, ec);
  if (ec || !std::filesystem::is_directory(config.directory))
    throw ConfigError("recording.directory: cannot make " + config.directory.string() + ": " +
                      (ec ? ec.message() : std::string("not a folder")));
  record::RecorderOptions o;
  o.directory = config.directory;
  o.file_prefix = "tendril";
  o.writer.compression = config.compression;
  o.max_file_bytes = config.max_file_bytes;
  o.max_file_duration_ns = config.max_file_duration_ns;
  o.keep_total_bytes = config.keep_total_bytes;
  o.keep_age = config.keep_age;
  o.log = std::move(log);
  return o;
}
}  // namespace

SessionRecording::SessionRecording(const RecordingConfig& config, std::function<void(std::string_view)> log)
    : config_(config), recorder_(recorder_options(config, std::move(log))) {
  record::ChannelSpec spec;
  spec.topic = "/commands";
  spec.message_encoding = "json";
  spec.schema_name = "tendril.Command";
  spec.schema_encoding = "jsonschema";
  spec.schema_data = bytes_of(commands_schema());
  commands_ = recorder_.add_channel(std::move(spec));
}

SessionRecording::~SessionRecording() { stop(); }

void SessionRecording::start() { recorder_.start(); }
void SessionRecording::stop() { recorder_.stop(); }

bool SessionRecording::wants(const std::string& topic, bool from_source) const {
  // The segmentation's parameters and roadmaps are a few hundred bytes per change and produced at no
  // cost when nobody watches: always kept, so a recorded session says how its images were segmented.
  return !from_source || config_.images_always || topic == "/imaging/segmentation";
}

void SessionRecording::channel(std::uint32_t id, const std::string& topic, const std::string& schema_name,
                               const std::string& schema, const std::string& encoding,
                               const std::string& schema_encoding) {
  record::ChannelSpec spec;
  spec.topic = topic;
  spec.message_encoding = encoding;  // MCAP's names: "json", "protobuf"
  spec.schema_name = schema_name;
  spec.schema_encoding = schema.empty() ? "" : schema_encoding;
  if (schema.empty()) spec.schema_name.clear();
  spec.schema_data = bytes_of(schema);
  const auto recorded = recorder_.add_channel(std::move(spec));
  std::lock_guard lock(ids_mutex_);
  ids_[id] = recorded;
}

void SessionRecording::message(std::uint32_t id, std::uint64_t log_time_ns,
                               std::shared_ptr<const std::string> payload) {
  record::Recorder::ChannelId recorded = 0;
  {
    std::lock_guard lock(ids_mutex_);
    const auto it = ids_.find(id);
    if (it == ids_.end()) return;  // advertised before the recording began: not ours
    recorded = it->second;
  }
  recorder_.record(recorded, log_time_ns, std::move(payload));
}

void SessionRecording::command(std::uint64_t time_ns, const std::string& robot, const std::string& command,
                               const std::string& who, const nlohmann::json& body, int status,
                               const std::string& error) {
  const nlohmann::json entry = {{"robot", robot},   {"command", command}, {"who", who},
                                {"status", status}, {"error", error},     {"body", body}};
  recorder_.record(commands_, time_ns,
                   std::make_shared<const std::string>(
                       entry.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace)));
}

}  // namespace tendril::server
