#include "tendril/drivers/canopen/sdo_client.hpp"

#include <algorithm>
#include <cstdio>

namespace tendril::canopen {
namespace {

// Command specifiers (upper 3 bits of byte 0).
constexpr std::uint8_t ccs_download_segment = 0x00, ccs_download_initiate = 0x20, ccs_upload_initiate = 0x40,
                       ccs_upload_segment = 0x60, cs_abort = 0x80;
constexpr std::uint8_t scs_upload_segment = 0x00, scs_download_segment = 0x20, scs_upload_initiate = 0x40,
                       scs_download_initiate = 0x60;

std::string hex(std::uint32_t v, int width) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", width, static_cast<unsigned>(v));
  return buf;
}

}  // namespace

SdoClient::SdoClient(can::Bus& bus, std::uint8_t node_id, std::chrono::milliseconds timeout, int retries)
    : bus_(bus), node_id_(node_id), timeout_(timeout), retries_(retries < 0 ? 0 : retries) {}

std::string SdoClient::object_name() const {
  return "node " + std::to_string(node_id_) + " object " + hex(index_, 4) + ":" + hex(sub_, 2);
}

void SdoClient::start_download(std::uint16_t index, std::uint8_t sub, std::vector<std::uint8_t> data,
                               can::Clock::time_point now) {
  upload_ = false;
  index_ = index;
  sub_ = sub;
  data_ = std::move(data);
  attempts_left_ = retries_;
  retries_used_ = 0;
  begin_attempt(now);
}

void SdoClient::start_upload(std::uint16_t index, std::uint8_t sub, can::Clock::time_point now) {
  upload_ = true;
  index_ = index;
  sub_ = sub;
  data_.clear();
  attempts_left_ = retries_;
  retries_used_ = 0;
  begin_attempt(now);
}

void SdoClient::begin_attempt(can::Clock::time_point now) {
  status_ = Status::busy;
  abort_code_ = 0;
  error_.clear();
  reason_.clear();
  offset_ = 0;
  toggle_ = false;
  std::uint8_t b[8]{};
  b[1] = static_cast<std::uint8_t>(index_);
  b[2] = static_cast<std::uint8_t>(index_ >> 8);
  b[3] = sub_;
  if (upload_) {
    data_.clear();
    expected_size_ = 0;
    size_indicated_ = false;
    phase_ = Phase::upload_initiate;
    b[0] = ccs_upload_initiate;
  } else if (data_.size() <= 4 && !data_.empty()) {
    // Expedited: e=1, s=1, n = number of unused bytes.
    phase_ = Phase::download_initiate;
    b[0] = static_cast<std::uint8_t>(ccs_download_initiate | ((4 - data_.size()) << 2) | 0x03);
    for (std::size_t i = 0; i < data_.size(); ++i) b[4 + i] = data_[i];
  } else {
    // Segmented: e=0, s=1, bytes 4..7 carry the size.
    phase_ = Phase::download_initiate;
    b[0] = static_cast<std::uint8_t>(ccs_download_initiate | 0x01);
    put_u32(&b[4], static_cast<std::uint32_t>(data_.size()));
  }
  send_request(b, now);
}

void SdoClient::send_request(const std::uint8_t (&bytes)[8], can::Clock::time_point now) {
  can::Frame f;
  f.id = cob::sdo_rx + node_id_;
  f.len = 8;
  for (int i = 0; i < 8; ++i) f.data[static_cast<std::size_t>(i)] = bytes[i];
  deadline_ = now + timeout_;
  // A failed send is left to the timeout/retry path: the bus may recover before it expires.
  (void)bus_.send(f);
}

void SdoClient::send_download_segment(can::Clock::time_point now) {
  const std::size_t remaining = data_.size() - offset_;
  const std::size_t chunk = remaining > 7 ? 7 : remaining;
  const bool last = offset_ + chunk >= data_.size();
  std::uint8_t b[8]{};
  b[0] = static_cast<std::uint8_t>(ccs_download_segment | (toggle_ ? 0x10 : 0) | ((7 - chunk) << 1) |
                                   (last ? 0x01 : 0));
  for (std::size_t i = 0; i < chunk; ++i) b[1 + i] = data_[offset_ + i];
  phase_ = Phase::download_segment;
  send_request(b, now);
}

void SdoClient::send_upload_segment_request(can::Clock::time_point now) {
  std::uint8_t b[8]{};
  b[0] = static_cast<std::uint8_t>(ccs_upload_segment | (toggle_ ? 0x10 : 0));
  phase_ = Phase::upload_segment;
  send_request(b, now);
}

void SdoClient::fail(std::uint32_t code, const std::string& reason, bool send_abort) {
  status_ = Status::failed;
  abort_code_ = code;
  reason_ = reason;
  error_ = "SDO " + std::string(upload_ ? "read of " : "write to ") + object_name() + " failed: " + reason;
  if (send_abort) {
    can::Frame f;
    f.id = cob::sdo_rx + node_id_;
    f.len = 8;
    f.data[0] = cs_abort;
    f.data[1] = static_cast<std::uint8_t>(index_);
    f.data[2] = static_cast<std::uint8_t>(index_ >> 8);
    f.data[3] = sub_;
    put_u32(&f.data[4], code);
    (void)bus_.send(f);
  }
}

bool SdoClient::handle(const can::Frame& frame, can::Clock::time_point now) {
  if (frame.error || frame.extended || frame.rtr || frame.id != cob::sdo_tx + node_id_) return false;
  if (status_ != Status::busy) return true;  // stray or late answer: ours, but nothing waits for it
  if (frame.len < 8) {
    fail(sdo_abort::invalid_command, "the server sent a " + std::to_string(frame.len) + "-byte SDO frame",
         true);
    return true;
  }
  const std::uint8_t* d = frame.data.data();
  const std::uint8_t cmd = d[0];
  const auto same_object = [&] { return get_u16(&d[1]) == index_ && d[3] == sub_; };

  if ((cmd & 0xE0) == cs_abort) {
    const std::uint32_t code = get_u32(&d[4]);
    char code_text[16];
    std::snprintf(code_text, sizeof code_text, "0x%08X", static_cast<unsigned>(code));
    fail(code,
         "the node aborted the transfer with " + std::string(code_text) + " (" + sdo_abort_text(code) + ")",
         false);
    return true;
  }

  switch (phase_) {
    case Phase::download_initiate: {
      if ((cmd & 0xE0) != scs_download_initiate || !same_object()) {
        fail(sdo_abort::invalid_command, "unexpected answer " + hex(cmd, 2) + " to a download request", true);
        return true;
      }
      if (data_.size() <= 4) {
        // Expedited (1-4 bytes) or zero-length segmented download: nothing more to send.
        status_ = Status::done;
      } else {
        send_download_segment(now);
      }
      return true;
    }
    case Phase::download_segment: {
      if ((cmd & 0xE0) != scs_download_segment) {
        fail(sdo_abort::invalid_command, "unexpected answer " + hex(cmd, 2) + " to a download segment", true);
        return true;
      }
      if (((cmd & 0x10) != 0) != toggle_) {
        fail(sdo_abort::toggle_bit, "toggle bit not alternated in a download segment answer", true);
        return true;
      }
      const std::size_t chunk = std::min<std::size_t>(7, data_.size() - offset_);
      offset_ += chunk;
      toggle_ = !toggle_;
      if (offset_ >= data_.size()) {
        status_ = Status::done;
      } else {
        send_download_segment(now);
      }
      return true;
    }
    case Phase::upload_initiate: {
      if ((cmd & 0xE0) != scs_upload_initiate || !same_object()) {
        fail(sdo_abort::invalid_command, "unexpected answer " + hex(cmd, 2) + " to an upload request", true);
        return true;
      }
      const bool expedited = cmd & 0x02;
      const bool size_indicated = cmd & 0x01;
      if (expedited) {
        const std::size_t n = size_indicated ? 4 - ((cmd >> 2) & 0x03) : 4;
        data_.assign(d + 4, d + 4 + n);
        status_ = Status::done;
        return true;
      }
      size_indicated_ = size_indicated;
      expected_size_ = size_indicated ? get_u32(&d[4]) : 0;
      data_.clear();
      send_upload_segment_request(now);
      return true;
    }
    case Phase::upload_segment: {
      if ((cmd & 0xE0) != scs_upload_segment) {
        fail(sdo_abort::invalid_command, "unexpected answer " + hex(cmd, 2) + " to an upload segment request",
             true);
        return true;
      }
      if (((cmd & 0x10) != 0) != toggle_) {
        fail(sdo_abort::toggle_bit, "toggle bit not alternated in an upload segment", true);
        return true;
      }
      const std::size_t n = 7 - ((cmd >> 1) & 0x07);
      data_.insert(data_.end(), d + 1, d + 1 + n);
      toggle_ = !toggle_;
      if (cmd & 0x01) {
        if (size_indicated_ && data_.size() != expected_size_) {
          fail(sdo_abort::length_mismatch,
               "the node announced " + std::to_string(expected_size_) + " bytes but sent " +
                   std::to_string(data_.size()),
               true);
          return true;
        }
        status_ = Status::done;
      } else if (size_indicated_ && data_.size() > expected_size_) {
        fail(sdo_abort::length_too_high,
             "the node sent more than the " + std::to_string(expected_size_) + " bytes it announced", true);
      } else {
        send_upload_segment_request(now);
      }
      return true;
    }
  }
  return true;
}

void SdoClient::poll(can::Clock::time_point now) {
  if (status_ != Status::busy || now < deadline_) return;
  if (attempts_left_ > 0) {
    --attempts_left_;
    ++retries_used_;
    begin_attempt(now);  // restart the whole transfer: a new initiate resets the server side too
    return;
  }
  fail(sdo_abort::timeout,
       "no answer within " + std::to_string(timeout_.count()) + " ms (" + std::to_string(retries_ + 1) +
           (retries_ == 0 ? " attempt)" : " attempts)"),
       true);
}

}  // namespace tendril::canopen
