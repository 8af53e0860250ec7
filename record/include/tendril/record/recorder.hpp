// Recorder: records messages from any number of producer threads into rotating MCAP files.
//
// Producers call record(), which copies the bytes into a bounded lock-free queue and returns at once:
// it never waits for the writer or the disk. When the queue is full (by message count or by bytes),
// the message is dropped and counted, per channel and in total; the sequence number it would have had
// is skipped, so a reader of the file sees the gap too, and the counts go into each file's
// "tendril.recorder" Metadata record and to the log callback. One writer thread drains the queue into
// an McapWriter.
//
// Rotation: a new file is started before a message that would take the current file past
// max_file_bytes, or whose log time is max_file_duration past the file's first message. Durations are
// measured in the messages' log time, not the wall clock, so a recording rotates the same way whatever
// the machine's load. A chunk is also written once it has waited max_chunk_delay (wall clock), which
// bounds what a SIGKILL can take from a slow stream.
//
// Files are named <prefix>_<UTC time the file was opened, YYYYMMDDTHHMMSSZ>_<index, 0000…>.mcap.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "tendril/record/mcap_writer.hpp"

namespace tendril::record {

// What a channel is: the MCAP Channel and Schema records written for it in every file it appears in.
struct ChannelSpec {
  std::string topic;
  std::string message_encoding;  // e.g. "json", "cdr", "protobuf" (MCAP's well-known encodings)
  std::string schema_name;       // "" together with schema_encoding "": no schema
  std::string schema_encoding;   // e.g. "jsonschema", "ros2msg"; "" = none
  std::vector<std::uint8_t> schema_data;
  std::map<std::string, std::string> metadata;
};

struct RecorderOptions {
  std::filesystem::path directory;  // created if missing
  std::string file_prefix = "tendril";
  McapWriterOptions writer;
  std::uint64_t max_file_bytes = std::uint64_t{1} << 30;  // 0: no rotation by size
  std::uint64_t max_file_duration_ns = 0;                 // log-time span; 0: no rotation by time
  std::chrono::milliseconds max_chunk_delay{500};
  std::size_t queue_capacity = 4096;                     // messages waiting (rounded up to a power of 2)
  std::size_t queue_max_bytes = std::size_t{256} << 20;  // payload bytes waiting
  std::size_t max_channels = 1024;
  // Retention, applied each time a file is started (the first and every rotation): among the finished
  // files named <file_prefix>_<UTC>_<index>.mcap in `directory` (this session's and earlier ones' with
  // the same prefix; other files are never touched), those last written more than keep_age ago are
  // deleted, and the oldest are deleted while all of them, the open file included, take more than
  // keep_total_bytes. The open file is never deleted. 0 = no limit. Each deletion is logged.
  std::uint64_t keep_total_bytes = 0;
  std::chrono::seconds keep_age{0};
  // Files finished, drops and errors, one line each, from the writer thread. May be empty.
  std::function<void(std::string_view)> log;
};

struct RecorderStats {
  std::uint64_t accepted = 0;        // taken into the queue
  std::uint64_t dropped = 0;         // refused: queue full, not running, or the writer failed
  std::uint64_t written = 0;         // handed to the MCAP writer
  std::uint64_t flushed = 0;         // in complete chunks on disk (safe from SIGKILL)
  std::uint64_t bytes = 0;           // MCAP bytes written, all files
  std::uint64_t files = 0;           // files started
  std::uint64_t files_deleted = 0;   // deleted by retention (keep_total_bytes, keep_age)
  std::size_t queue_high_water = 0;  // most messages waiting at once
  std::string error;                 // the writer's first I/O error; recording stopped there
};

class Recorder {
 public:
  using ChannelId = std::uint32_t;

  explicit Recorder(RecorderOptions options);
  ~Recorder();  // stop()
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  // Any thread, any time (set-up: allocates and locks). Throws std::invalid_argument for an empty
  // topic or past max_channels.
  ChannelId add_channel(ChannelSpec spec);

  // Any thread; never blocks. Copies the bytes (an allocation on the caller's thread: the control
  // thread hands its data to a publisher thread, which records). Returns false when the message was
  // dropped. Before start() messages wait in the queue.
  bool record(ChannelId channel, std::uint64_t log_time_ns, std::span<const std::uint8_t> bytes);
  // The same without a copy: the recorder holds the payload (e.g. a JSON message the WebSocket
  // publisher already serialised once for all its clients) until it is written. Null counts as empty.
  bool record(ChannelId channel, std::uint64_t log_time_ns, std::shared_ptr<const std::string> payload);

  void start();  // starts the writer thread
  void stop();   // writes what is queued, finalises the current file, joins. Idempotent.

  RecorderStats stats() const;
  std::uint64_t dropped(ChannelId channel) const;
  std::vector<std::filesystem::path> files() const;  // every file started, oldest first

 private:
  struct Entry {
    ChannelId channel = 0;
    std::uint32_t sequence = 0;
    std::uint64_t log_time = 0;
    std::vector<std::uint8_t> owned;            // record(span): the recorder's copy
    std::shared_ptr<const std::string> shared;  // record(shared_ptr): the publisher's payload, held
    std::span<const std::uint8_t> data() const {
      if (shared) return {reinterpret_cast<const std::uint8_t*>(shared->data()), shared->size()};
      return {owned.data(), owned.size()};
    }
  };
  // Vyukov's bounded multi-producer queue cell: seq says whose turn the cell is.
  struct Cell {
    std::atomic<std::size_t> seq{0};
    Entry entry;
  };
  struct ChannelCounters {
    std::atomic<std::uint32_t> next_sequence{0};
    std::atomic<std::uint64_t> dropped{0};
  };

  bool enqueue(ChannelId channel, std::uint64_t log_time_ns, std::size_t size,
               std::span<const std::uint8_t> copy, std::shared_ptr<const std::string> shared);
  bool push(Entry&& entry);
  bool pop(Entry& out);
  void drop(ChannelId channel);
  void run();
  void write(Entry& entry);
  void open_file();
  void apply_retention();
  void close_file();
  void maybe_flush_by_age();
  void report_drops(bool force);
  void fail(const std::exception& e);
  void log(const std::string& line) const;

  RecorderOptions options_;
  std::size_t mask_;
  std::unique_ptr<Cell[]> cells_;
  alignas(64) std::atomic<std::size_t> enqueue_pos_{0};
  alignas(64) std::atomic<std::size_t> dequeue_pos_{0};
  std::atomic<std::size_t> queued_bytes_{0};
  std::atomic<std::size_t> queued_messages_{0};
  std::atomic<std::size_t> high_water_{0};
  std::unique_ptr<ChannelCounters[]> counters_;

  mutable std::mutex channels_mutex_;
  std::vector<ChannelSpec> channels_;
  std::atomic<std::uint32_t> channel_count_{0};

  std::atomic<bool> running_{false};
  std::atomic<bool> stopping_{false};
  std::atomic<bool> stopped_{false};
  std::atomic<bool> failed_{false};
  std::thread thread_;

  std::atomic<std::uint64_t> accepted_{0}, dropped_{0}, written_{0}, flushed_{0}, bytes_{0}, file_count_{0},
      files_deleted_{0};
  mutable std::mutex status_mutex_;  // files_ and error_
  std::vector<std::filesystem::path> files_;
  std::string error_;

  // Writer thread only.
  std::unique_ptr<McapWriter> writer_;
  std::vector<std::uint16_t> file_channel_;  // recorder channel -> MCAP channel id in this file (0: none)
  std::vector<std::uint16_t> file_schema_;   // recorder channel -> MCAP schema id in this file (0: none)
  std::uint64_t file_first_log_time_ = 0;
  std::uint64_t flushed_before_file_ = 0, bytes_before_file_ = 0;
  std::chrono::steady_clock::time_point chunk_opened_{};
  std::chrono::steady_clock::time_point last_drop_report_{};
  std::uint64_t dropped_reported_ = 0;
  std::uint64_t written_in_file_ = 0;
};

}  // namespace tendril::record
