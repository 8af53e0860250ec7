// SessionReplay: a recorded session (MCAP files of tendrild's recording, or any chunked MCAP file)
// published again through the Foxglove WebSocket, at the recorded pace times a rate, for
// tendrild --replay. It is a TopicSource: every recorded channel is advertised with its recorded topic,
// schema name, schema and encodings, so the console and Foxglove Studio/Lichtblick read it as they
// read a live server. /replay/status (tendril.ReplayStatus, JSON) says where the replay is, and the
// ReplayControl side takes play/pause/seek/rate from REST.
//
// Timing: one playback thread maps log time to the steady clock (position = anchor + elapsed × rate)
// and publishes each message when the position reaches its log time, never before; under load it is
// late, not early. Message headers carry the wall-clock time at which the message is replayed (as a
// live server's do, so the console's staleness check works); the recorded time is in the payloads and
// in /replay/status. A topic's messages are offered newest-only, like every topic of the server. After a
// seek the state at the new position (each topic's last message within seek_lookback_ns) is published
// at once, playing or paused.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/record/mcap_reader.hpp"
#include "tendril/server/replay_control.hpp"
#include "tendril/server/topic_source.hpp"

namespace tendril::server {

struct ReplayOptions {
  // Files opened, damaged chunks, the end reached: one line each. May be empty.
  std::function<void(std::string_view)> log;
  double status_rate_hz = 10;  // /replay/status while playing (and at every change)
  bool start_playing = true;   // false: paused at the first message until PUT {"playing": true}
  // After a seek each topic's last message within this much log time before the new position is
  // published at once (the state there); 0: nothing until the replay plays on.
  std::uint64_t seek_lookback_ns = 5'000'000'000;
  // The data-section CRC is not checked at open (about 2 s per 270 MB, record/README.md): every
  // chunk's own CRC is checked as it is played, and the summary's at open.
  record::McapReaderOptions reader{.check_data_crc = false};
};

class SessionReplay final : public TopicSource, public ReplayControl {
 public:
  static constexpr const char* kStatusTopic = "/replay/status";
  static constexpr double kMinRate = 0.1, kMaxRate = 10.0;

  // Opens and indexes every file (record::mcap_files: a file, or a folder's *.mcap sorted by name).
  // Throws record::McapError (record::McapFormatError for a damaged file) naming the file.
  explicit SessionReplay(const std::filesystem::path& file_or_folder, ReplayOptions options = {});
  ~SessionReplay() override;  // stop()
  SessionReplay(const SessionReplay&) = delete;
  SessionReplay& operator=(const SessionReplay&) = delete;

  void start();  // the playback thread
  void stop();   // idempotent

  struct Status {
    std::uint64_t start_ns = 0, end_ns = 0, position_ns = 0;
    double rate = 1.0;
    bool playing = false;
    bool ended = false;
    std::uint64_t messages_sent = 0;
    std::string error;
  };
  Status status() const;
  // Typed controls (REST goes through control_replay). Throw std::invalid_argument naming the value.
  void set_playing(bool playing);
  void set_rate(double rate);
  void seek(std::uint64_t position_ns);

  // TopicSource
  std::vector<TopicInfo> topics() const override;
  std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const override;
  void set_ready_callback(std::function<void()> ready) override;
  std::string metrics() const override;

  // ReplayControl
  ApiResult replay_status() const override;
  ApiResult control_replay(const nlohmann::json& body) override;

 private:
  struct Slot {
    std::shared_ptr<const std::string> payload;
    std::uint64_t version = 0;
    std::uint64_t log_time_ns = 0;
  };
  using SteadyClock = std::chrono::steady_clock;

  void run();
  std::uint64_t position_at(SteadyClock::time_point now) const;                        // caller holds mutex_
  void reanchor(SteadyClock::time_point now);                                          // caller holds mutex_
  void publish(const std::string& topic, std::shared_ptr<const std::string> payload);  // holds mutex_
  std::shared_ptr<const std::string> status_payload() const;                           // holds mutex_
  nlohmann::json status_json() const;                                                  // holds mutex_
  void log(const std::string& line) const;

  ReplayOptions options_;
  std::vector<std::filesystem::path> files_;
  std::vector<std::unique_ptr<record::McapReader>> readers_;
  std::vector<TopicInfo> topics_;  // recorded channels by topic (first file's schema), then the status
  std::uint64_t start_ns_ = 0, end_ns_ = 0;

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::map<std::string, Slot> slots_;
  std::function<void()> ready_;
  bool playing_ = false;
  bool ended_ = false;
  double rate_ = 1.0;
  std::uint64_t anchor_position_ = 0;  // log time at anchor_wall_
  SteadyClock::time_point anchor_wall_{};
  bool seek_pending_ = false;
  std::uint64_t messages_sent_ = 0;
  std::uint64_t changes_ = 0;  // bumped by every control: the thread re-plans its wait
  std::string error_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace tendril::server
