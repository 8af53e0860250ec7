#include "tendril/record/recorder.hpp"

#include <algorithm>
#include <bit>
#include <cstdio>
#include <ctime>
#include <stdexcept>
#include <string_view>

namespace tendril::record {
namespace {

std::string utc_stamp() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y%m%dT%H%M%SZ", &tm);
  return buffer;
}

// When the writer thread finds the queue empty it sleeps this long: producers never signal (a futex
// wake per message would cost them a system call); at 1 kHz the queue holds a couple of messages then.
constexpr std::chrono::milliseconds kIdleSleep{2};
constexpr std::chrono::seconds kDropReportInterval{1};

}  // namespace

Recorder::Recorder(RecorderOptions options) : options_(std::move(options)) {
  if (options_.directory.empty())
    throw std::invalid_argument("recorder: no directory to write recordings to");
  if (options_.queue_capacity < 2) throw std::invalid_argument("recorder: queue_capacity must be at least 2");
  if (options_.max_channels == 0 || options_.max_channels > 65535) {
    throw std::invalid_argument("recorder: max_channels must be 1..65535 (MCAP channel ids are 16-bit)");
  }
  std::filesystem::create_directories(options_.directory);
  const std::size_t capacity = std::bit_ceil(options_.queue_capacity);
  mask_ = capacity - 1;
  cells_ = std::make_unique<Cell[]>(capacity);
  for (std::size_t i = 0; i < capacity; ++i) cells_[i].seq.store(i, std::memory_order_relaxed);
  counters_ = std::make_unique<ChannelCounters[]>(options_.max_channels);
  file_channel_.assign(options_.max_channels, 0);
  file_schema_.assign(options_.max_channels, 0);
}

Recorder::~Recorder() { stop(); }

Recorder::ChannelId Recorder::add_channel(ChannelSpec spec) {
  if (spec.topic.empty()) throw std::invalid_argument("recorder: a channel needs a topic");
  const std::lock_guard lock(channels_mutex_);
  if (channels_.size() >= options_.max_channels) {
    throw std::invalid_argument("recorder: channel '" + spec.topic + "' is one more than max_channels (" +
                                std::to_string(options_.max_channels) + ")");
  }
  channels_.push_back(std::move(spec));
  const auto id = static_cast<ChannelId>(channels_.size() - 1);
  channel_count_.store(id + 1, std::memory_order_release);
  return id;
}

void Recorder::drop(ChannelId channel) {
  counters_[channel].dropped.fetch_add(1, std::memory_order_relaxed);
  dropped_.fetch_add(1, std::memory_order_relaxed);
}

bool Recorder::record(ChannelId channel, std::uint64_t log_time_ns, std::span<const std::uint8_t> bytes) {
  return enqueue(channel, log_time_ns, bytes.size(), bytes, nullptr);
}

bool Recorder::record(ChannelId channel, std::uint64_t log_time_ns,
                      std::shared_ptr<const std::string> payload) {
  const std::size_t size = payload ? payload->size() : 0;
  return enqueue(channel, log_time_ns, size, {}, std::move(payload));
}

bool Recorder::enqueue(ChannelId channel, std::uint64_t log_time_ns, std::size_t size,
                       std::span<const std::uint8_t> copy, std::shared_ptr<const std::string> shared) {
  if (channel >= channel_count_.load(std::memory_order_acquire))
    return false;  // not a channel: nothing to count
  // The sequence is taken whether or not the message is kept: a dropped message is a gap in the file.
  const std::uint32_t sequence = counters_[channel].next_sequence.fetch_add(1, std::memory_order_relaxed);
  if (stopping_.load(std::memory_order_acquire) || failed_.load(std::memory_order_acquire)) {
    drop(channel);
    return false;
  }
  const std::size_t queued = queued_bytes_.fetch_add(size, std::memory_order_relaxed) + size;
  if (queued > options_.queue_max_bytes) {
    queued_bytes_.fetch_sub(size, std::memory_order_relaxed);
    drop(channel);
    return false;
  }
  // Counted as waiting before it is pushed, so that the writer's count never runs below zero.
  const std::size_t waiting = queued_messages_.fetch_add(1, std::memory_order_acq_rel) + 1;
  Entry entry{channel, sequence, log_time_ns, std::vector<std::uint8_t>(copy.begin(), copy.end()),
              std::move(shared)};
  if (!push(std::move(entry))) {
    queued_messages_.fetch_sub(1, std::memory_order_acq_rel);
    queued_bytes_.fetch_sub(size, std::memory_order_relaxed);
    drop(channel);
    return false;
  }
  accepted_.fetch_add(1, std::memory_order_relaxed);
  std::size_t seen = high_water_.load(std::memory_order_relaxed);
  while (waiting > seen && !high_water_.compare_exchange_weak(seen, waiting, std::memory_order_relaxed)) {
  }
  return true;
}

// Vyukov's bounded MPMC queue: a producer claims a position with a CAS on enqueue_pos_ and publishes
// the cell with its seq; a full queue is seen as a cell whose previous entry is not yet consumed.
bool Recorder::push(Entry&& entry) {
  std::size_t pos = enqueue_pos_.load(std::memory_order_relaxed);
  for (;;) {
    Cell& cell = cells_[pos & mask_];
    const std::size_t seq = cell.seq.load(std::memory_order_acquire);
    const auto diff = static_cast<std::ptrdiff_t>(seq) - static_cast<std::ptrdiff_t>(pos);
    if (diff == 0) {
      if (enqueue_pos_.compare_exchange_weak(pos, pos + 1, std::memory_order_relaxed)) {
        cell.entry = std::move(entry);
        cell.seq.store(pos + 1, std::memory_order_release);
        return true;
      }
    } else if (diff < 0) {
      return false;  // full
    } else {
      pos = enqueue_pos_.load(std::memory_order_relaxed);
    }
  }
}

bool Recorder::pop(Entry& out) {
  std::size_t pos = dequeue_pos_.load(std::memory_order_relaxed);
  for (;;) {
    Cell& cell = cells_[pos & mask_];
    const std::size_t seq = cell.seq.load(std::memory_order_acquire);
    const auto diff = static_cast<std::ptrdiff_t>(seq) - static_cast<std::ptrdiff_t>(pos + 1);
    if (diff == 0) {
      if (dequeue_pos_.compare_exchange_weak(pos, pos + 1, std::memory_order_relaxed)) {
        out = std::move(cell.entry);
        cell.entry.owned = {};
        cell.entry.shared.reset();
        cell.seq.store(pos + mask_ + 1, std::memory_order_release);
        queued_bytes_.fetch_sub(out.data().size(), std::memory_order_relaxed);
        queued_messages_.fetch_sub(1, std::memory_order_acq_rel);
        return true;
      }
    } else if (diff < 0) {
      return false;  // empty
    } else {
      pos = dequeue_pos_.load(std::memory_order_relaxed);
    }
  }
}

void Recorder::start() {
  if (running_.exchange(true)) return;
  if (stopped_.load()) throw std::logic_error("recorder: start() after stop()");
  last_drop_report_ = std::chrono::steady_clock::now();
  thread_ = std::thread([this] { run(); });
}

void Recorder::stop() {
  if (stopped_.exchange(true)) return;
  stopping_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  // Never started, or a producer that passed the stopping_ check raced the writer's last look: what
  // is still queued is not written, and is counted as dropped.
  Entry entry;
  while (pop(entry)) {
    accepted_.fetch_sub(1, std::memory_order_relaxed);
    drop(entry.channel);
  }
}

void Recorder::log(const std::string& line) const {
  if (options_.log) options_.log(line);
}

void Recorder::run() {
  Entry entry;
  for (;;) {
    if (pop(entry)) {
      if (failed_.load(std::memory_order_relaxed)) {
        drop(entry.channel);
      } else {
        try {
          write(entry);
        } catch (const std::exception& e) {
          fail(e);
          drop(entry.channel);
        }
      }
      continue;
    }
    if (stopping_.load(std::memory_order_acquire)) {
      // A producer that passed the stopping_ check just before it was set may still be pushing.
      if (queued_messages_.load(std::memory_order_acquire) == 0) break;
      std::this_thread::yield();
      continue;
    }
    try {
      maybe_flush_by_age();
    } catch (const std::exception& e) {
      fail(e);
    }
    report_drops(false);
    std::this_thread::sleep_for(kIdleSleep);
  }
  try {
    close_file();
  } catch (const std::exception& e) {
    fail(e);
  }
  report_drops(true);
}

void Recorder::fail(const std::exception& e) {
  if (failed_.exchange(true)) return;
  {
    const std::lock_guard lock(status_mutex_);
    error_ = e.what();
  }
  log(std::string("recorder: stopped recording after an error: ") + e.what());
  writer_.reset();  // its destructor closes the file as well as it still can
}

void Recorder::open_file() {
  const std::uint64_t index = file_count_.load(std::memory_order_relaxed);
  char suffix[16];
  std::snprintf(suffix, sizeof suffix, "_%04llu.mcap", static_cast<unsigned long long>(index));
  const std::filesystem::path path = options_.directory / (options_.file_prefix + "_" + utc_stamp() + suffix);
  writer_ = std::make_unique<McapWriter>(path, options_.writer);
  file_channel_.assign(file_channel_.size(), 0);
  file_schema_.assign(file_schema_.size(), 0);
  written_in_file_ = 0;
  file_count_.fetch_add(1, std::memory_order_relaxed);
  {
    const std::lock_guard lock(status_mutex_);
    files_.push_back(path);
  }
  apply_retention();
}

namespace {
// <prefix>_YYYYMMDDTHHMMSSZ_<digits>.mcap: what a recorder with this prefix names its files, and
// nothing else (retention must not delete a file someone put next to the recordings).
bool recorder_file_name(std::string_view name, std::string_view prefix) {
  const auto digits = [](std::string_view s) {
    return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
  };
  if (name.size() < prefix.size() + 1 || name.substr(0, prefix.size()) != prefix ||
      name[prefix.size()] != '_')
    return false;
  name.remove_prefix(prefix.size() + 1);
  constexpr std::string_view kExtension = ".mcap";
  if (name.size() < 17 + 1 + kExtension.size() || name.substr(name.size() - kExtension.size()) != kExtension)
    return false;
  return digits(name.substr(0, 8)) && name[8] == 'T' && digits(name.substr(9, 6)) && name[15] == 'Z' &&
         name[16] == '_' && digits(name.substr(17, name.size() - 17 - kExtension.size()));
}
}  // namespace

void Recorder::apply_retention() {
  if (options_.keep_total_bytes == 0 && options_.keep_age.count() == 0) return;
  struct Found {
    std::filesystem::path path;
    std::uint64_t size;
    std::filesystem::file_time_type written;
  };
  std::vector<Found> found;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(options_.directory, ec)) {
    std::error_code entry_ec;
    if (!entry.is_regular_file(entry_ec) ||
        !recorder_file_name(entry.path().filename().string(), options_.file_prefix))
      continue;
    const auto size = entry.file_size(entry_ec);
    const auto written = entry.last_write_time(entry_ec);
    if (!entry_ec) found.push_back({entry.path(), size, written});
  }
  if (ec) {
    log("recorder: retention: cannot list " + options_.directory.string() + ": " + ec.message());
    return;
  }
  // Names start with the UTC time the file was opened, then its index: by name is oldest first.
  std::sort(found.begin(), found.end(),
            [](const Found& a, const Found& b) { return a.path.filename() < b.path.filename(); });
  std::uint64_t total = 0;
  for (const auto& f : found) total += f.size;
  const auto open_name = writer_ ? writer_->path().filename() : std::filesystem::path();
  const auto now = std::filesystem::file_time_type::clock::now();
  for (const auto& f : found) {
    if (f.path.filename() == open_name) continue;
    const bool too_old = options_.keep_age.count() > 0 && now - f.written > options_.keep_age;
    const bool over_budget = options_.keep_total_bytes > 0 && total > options_.keep_total_bytes;
    if (!too_old && !over_budget) continue;
    std::error_code remove_ec;
    if (!std::filesystem::remove(f.path, remove_ec)) {
      log("recorder: retention: cannot delete " + f.path.string() + ": " +
          (remove_ec ? remove_ec.message() : std::string("it is gone")));
      continue;
    }
    total -= f.size;
    files_deleted_.fetch_add(1, std::memory_order_relaxed);
    log("recorder: retention: deleted " + f.path.string() + " (" + std::to_string(f.size) + " bytes, " +
        (too_old
             ? "older than the " + std::to_string(options_.keep_age.count()) + " s kept"
             : "the recordings were over the " + std::to_string(options_.keep_total_bytes) + " bytes kept") +
        ")");
  }
}

void Recorder::close_file() {
  if (!writer_) return;
  // What this file holds and what the recording lost so far, for whoever reads the file alone.
  std::map<std::string, std::string> meta{
      {"file_index", std::to_string(file_count_.load() - 1)},
      {"messages", std::to_string(written_in_file_)},
      {"dropped_total", std::to_string(dropped_.load())},
      {"compression", std::string(compression_name(options_.writer.compression))}};
  {
    const std::lock_guard lock(channels_mutex_);
    for (std::size_t c = 0; c < channels_.size(); ++c) {
      const std::uint64_t n = counters_[c].dropped.load(std::memory_order_relaxed);
      if (n > 0) meta["dropped:" + channels_[c].topic] = std::to_string(n);
    }
  }
  writer_->write_metadata("tendril.recorder", meta);
  writer_->close();
  flushed_before_file_ += writer_->stats().flushed_messages;
  bytes_before_file_ += writer_->stats().bytes;
  flushed_.store(flushed_before_file_, std::memory_order_relaxed);
  bytes_.store(bytes_before_file_, std::memory_order_relaxed);
  log("recorder: finished " + writer_->path().string() + " (" + std::to_string(written_in_file_) +
      " messages, " + std::to_string(writer_->stats().chunks) + " chunks, " +
      std::to_string(writer_->stats().bytes) + " bytes)");
  writer_.reset();
}

void Recorder::write(Entry& entry) {
  if (writer_ && written_in_file_ > 0) {
    const std::uint64_t size = writer_->stats().bytes + writer_->open_chunk_bytes() + entry.data().size();
    const bool too_big = options_.max_file_bytes > 0 && size > options_.max_file_bytes;
    const bool too_long = options_.max_file_duration_ns > 0 && entry.log_time >= file_first_log_time_ &&
                          entry.log_time - file_first_log_time_ >= options_.max_file_duration_ns;
    if (too_big || too_long) close_file();
  }
  if (!writer_) open_file();
  if (written_in_file_ == 0) file_first_log_time_ = entry.log_time;

  // The chunk's age counts from its first record, a channel's records included.
  if (writer_->open_chunk_bytes() == 0) chunk_opened_ = std::chrono::steady_clock::now();
  std::uint16_t& channel_id = file_channel_[entry.channel];
  if (channel_id == 0) {
    ChannelSpec spec;
    {
      const std::lock_guard lock(channels_mutex_);
      spec = channels_[entry.channel];
    }
    std::uint16_t schema_id = 0;
    if (!spec.schema_name.empty() || !spec.schema_encoding.empty()) {
      // One Schema record per distinct schema in a file: channels with the same schema share it.
      const std::lock_guard lock(channels_mutex_);
      for (std::size_t c = 0; c < file_schema_.size() && c < channels_.size(); ++c) {
        if (file_schema_[c] != 0 && channels_[c].schema_name == spec.schema_name &&
            channels_[c].schema_encoding == spec.schema_encoding &&
            channels_[c].schema_data == spec.schema_data) {
          schema_id = file_schema_[c];
          break;
        }
      }
    }
    if (schema_id == 0 && (!spec.schema_name.empty() || !spec.schema_encoding.empty())) {
      schema_id = writer_->add_schema(spec.schema_name, spec.schema_encoding, spec.schema_data);
    }
    file_schema_[entry.channel] = schema_id;
    channel_id = writer_->add_channel(schema_id, spec.topic, spec.message_encoding, spec.metadata);
  }
  const std::uint64_t chunks_before = writer_->stats().chunks;
  writer_->write_message(channel_id, entry.sequence, entry.log_time, entry.log_time, entry.data());
  ++written_in_file_;
  written_.fetch_add(1, std::memory_order_relaxed);
  if (writer_->stats().chunks == chunks_before) maybe_flush_by_age();
  flushed_.store(flushed_before_file_ + writer_->stats().flushed_messages, std::memory_order_relaxed);
  bytes_.store(bytes_before_file_ + writer_->stats().bytes, std::memory_order_relaxed);
}

void Recorder::maybe_flush_by_age() {
  if (!writer_ || writer_->open_chunk_bytes() == 0) return;
  if (std::chrono::steady_clock::now() - chunk_opened_ < options_.max_chunk_delay) return;
  writer_->flush_chunk();
  flushed_.store(flushed_before_file_ + writer_->stats().flushed_messages, std::memory_order_relaxed);
  bytes_.store(bytes_before_file_ + writer_->stats().bytes, std::memory_order_relaxed);
}

void Recorder::report_drops(bool force) {
  const auto now = std::chrono::steady_clock::now();
  if (!force && now - last_drop_report_ < kDropReportInterval) return;
  last_drop_report_ = now;
  const std::uint64_t total = dropped_.load(std::memory_order_relaxed);
  if (total == dropped_reported_) return;
  log("recorder: dropped " + std::to_string(total - dropped_reported_) +
      " messages (queue full, stopped or failed); " + std::to_string(total) + " in all");
  dropped_reported_ = total;
}

RecorderStats Recorder::stats() const {
  RecorderStats s;
  s.accepted = accepted_.load(std::memory_order_relaxed);
  s.dropped = dropped_.load(std::memory_order_relaxed);
  s.written = written_.load(std::memory_order_relaxed);
  s.flushed = flushed_.load(std::memory_order_relaxed);
  s.bytes = bytes_.load(std::memory_order_relaxed);
  s.files = file_count_.load(std::memory_order_relaxed);
  s.files_deleted = files_deleted_.load(std::memory_order_relaxed);
  s.queue_high_water = high_water_.load(std::memory_order_relaxed);
  const std::lock_guard lock(status_mutex_);
  s.error = error_;
  return s;
}

std::uint64_t Recorder::dropped(ChannelId channel) const {
  if (channel >= channel_count_.load(std::memory_order_acquire)) return 0;
  return counters_[channel].dropped.load(std::memory_order_relaxed);
}

std::vector<std::filesystem::path> Recorder::files() const {
  const std::lock_guard lock(status_mutex_);
  return files_;
}

}  // namespace tendril::record
