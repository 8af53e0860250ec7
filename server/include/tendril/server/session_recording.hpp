// SessionRecording: everything the server publishes and receives, recorded to rotating MCAP files
// (tendril::record::Recorder) — every channel the WebSocket publisher advertises (joint states,
// operating states, scenes, diagnostics, the safety events, images and maps), each message as it is
// sent to clients (JSON, with the channel's JSON schema), and every robot command on /commands with
// who sent it and how it ended. It is the publisher's PublishTap: the publisher thread hands it the
// payload it serialised once for its clients (no copy); the recorder's own thread writes. Nothing here
// runs on the control thread, and a full queue drops (counted) rather than waits.
//
// What is recorded is what is published: robot topics at the publish rate (50 Hz by default, the
// newest state each cycle; the 1 kHz loop itself is not recorded), images at the imaging rate.
// Images are recorded while someone watches them ("images": "watched", the default: a simulated plane
// renders only then) or always ("images": "always": the planes then render for the recording).
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "tendril/record/recorder.hpp"
#include "tendril/server/http/publish_tap.hpp"

namespace tendril::server {

struct RecordingConfig {
  bool enabled = false;
  std::filesystem::path directory;  // relative paths resolve against the server file's folder
  record::Compression compression = record::Compression::kZstd;
  std::uint64_t max_file_bytes = std::uint64_t{1} << 30;         // rotate at 1 GiB
  std::uint64_t max_file_duration_ns = 3600ULL * 1000000000ULL;  // and every hour
  bool images_always = false;
  // Retention (record::RecorderOptions::keep_total_bytes, keep_age); 0 = no limit.
  std::uint64_t keep_total_bytes = 0;
  std::chrono::seconds keep_age{0};
};

// The server file's "recording": {"enabled", "directory", "compression": "zstd"|"lz4"|"none",
// "max_file_mb", "max_file_minutes", "images": "watched"|"always", "keep_total_mb", "keep_days", "note"};
// null = off. Throws
// ConfigError naming the file and key.
RecordingConfig parse_recording_config(const nlohmann::json& recording,
                                       const std::filesystem::path& server_file);

class SessionRecording final : public http::PublishTap {
 public:
  // Creates the directory; throws ConfigError when it cannot be made.
  SessionRecording(const RecordingConfig& config, std::function<void(std::string_view)> log);
  ~SessionRecording() override;
  SessionRecording(const SessionRecording&) = delete;
  SessionRecording& operator=(const SessionRecording&) = delete;

  void start();
  void stop();  // writes what is queued and finalises the file; idempotent

  bool wants(const std::string& topic, bool from_source) const override;
  void channel(std::uint32_t id, const std::string& topic, const std::string& schema_name,
               const std::string& schema, const std::string& encoding,
               const std::string& schema_encoding) override;
  void message(std::uint32_t id, std::uint64_t log_time_ns,
               std::shared_ptr<const std::string> payload) override;
  void command(std::uint64_t time_ns, const std::string& robot, const std::string& command,
               const std::string& who, const nlohmann::json& body, int status,
               const std::string& error) override;

  record::RecorderStats stats() const { return recorder_.stats(); }
  std::vector<std::filesystem::path> files() const { return recorder_.files(); }

 private:
  RecordingConfig config_;
  record::Recorder recorder_;
  record::Recorder::ChannelId commands_ = 0;
  mutable std::mutex ids_mutex_;
  std::map<std::uint32_t, record::Recorder::ChannelId> ids_;  // publisher channel id -> recorder channel
};

}  // namespace tendril::server
