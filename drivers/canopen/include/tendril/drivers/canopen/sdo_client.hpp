// SdoClient: a non-blocking CiA 301 SDO client (expedited and segmented download and upload) for
// one server node. The owner feeds it received frames (handle) and time (poll); it never waits.
// Used at set-up and shutdown only: starting a transfer allocates.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"

namespace tendril::canopen {

class SdoClient {
 public:
  enum class Status : std::uint8_t { idle, busy, done, failed };

  // `timeout` is the wait for each server answer; after `retries` further attempts (each restarts
  // the whole transfer) the transfer fails with an SDO timeout abort.
  SdoClient(can::Bus& bus, std::uint8_t node_id, std::chrono::milliseconds timeout, int retries);

  // Start writing `data` (little-endian object value) to index/sub: expedited up to 4 bytes,
  // segmented above. Any transfer in progress is abandoned.
  void start_download(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                      can::Clock::time_point now);
  // Start reading index/sub; the value is in upload_data() once status() is done.
  void start_upload(std::uint16_t index, std::uint8_t sub, can::Clock::time_point now);

  // Feed a received frame. Returns true if it was this client's SDO answer (0x580 + node id).
  bool handle(const can::Frame& frame, can::Clock::time_point now);
  // Timeouts and retries.
  void poll(can::Clock::time_point now);

  Status status() const noexcept { return status_; }
  bool busy() const noexcept { return status_ == Status::busy; }
  const std::vector<std::uint8_t>& upload_data() const noexcept { return data_; }
  // Abort code that ended the transfer (from the server or sent by us); 0 if none.
  std::uint32_t abort_code() const noexcept { return abort_code_; }
  // Message for a person: node, object, what went wrong.
  const std::string& error() const noexcept { return error_; }
  // What went wrong only, for a caller whose own message already names the node and the object.
  const std::string& reason() const noexcept { return reason_; }
  std::uint64_t retries_used() const noexcept { return retries_used_; }
  std::uint8_t node_id() const noexcept { return node_id_; }
  can::Clock::time_point deadline() const noexcept { return deadline_; }

 private:
  enum class Phase : std::uint8_t { download_initiate, download_segment, upload_initiate, upload_segment };
  void begin_attempt(can::Clock::time_point now);
  void send_download_segment(can::Clock::time_point now);
  void send_upload_segment_request(can::Clock::time_point now);
  void send_request(const std::uint8_t (&bytes)[8], can::Clock::time_point now);
  void fail(std::uint32_t code, const std::string& reason, bool send_abort);
  std::string object_name() const;

  can::Bus& bus_;
  std::uint8_t node_id_;
  std::chrono::milliseconds timeout_;
  int retries_;

  Status status_ = Status::idle;
  Phase phase_ = Phase::download_initiate;
  bool upload_ = false;
  std::uint16_t index_ = 0;
  std::uint8_t sub_ = 0;
  std::vector<std::uint8_t> data_;  // download payload, or upload result
  std::size_t offset_ = 0;          // bytes of data_ already sent (download)
  std::size_t expected_size_ = 0;   // announced upload size (0 = not indicated)
  bool size_indicated_ = false;
  bool toggle_ = false;
  int attempts_left_ = 0;
  can::Clock::time_point deadline_{};
  std::uint32_t abort_code_ = 0;
  std::string error_;
  std::string reason_;
  std::uint64_t retries_used_ = 0;
};

}  // namespace tendril::canopen
