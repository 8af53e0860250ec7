// WsConnection: the Foxglove WebSocket protocol of one connection, independent of the byte stream.
// It parses client messages (subscriptions, parameters, client publishing, service calls), keeps the
// bounded outgoing queue (control messages in order, newest-only slots for topic data) and decides
// what to write next; the transport (WsSession<Stream>, ws_session.hpp) does the I/O.
//
// Threads: the transport's handlers run on the connection's strand; the publisher thread and other
// connections call send_text()/offer() from anywhere (guarded by out_mutex_).
//
// A client that stops reading: its newest-only slots keep being replaced (memory stays bounded), and
// when one write has waited longer than HttpOptions::ws_stalled_write_timeout the connection is
// closed and counted, rather than later flushing seconds of stale frames from the kernel buffer.
#pragma once

#include <array>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <unordered_map>

#include <boost/asio/any_io_executor.hpp>

#include "front_end.hpp"

namespace tendril::server {

class WsConnection : public WsConnectionBase, public std::enable_shared_from_this<WsConnection> {
 public:
  WsConnection(net::any_io_executor executor, HttpServer::Impl& server, Identity identity, std::uint64_t id);

  std::uint64_t id() const override { return id_; }
  const Identity& identity() const override { return identity_; }
  void send_text(const nlohmann::json& message) override;
  void offer(std::uint32_t channel_id, const std::shared_ptr<const std::string>& payload,
             std::uint64_t time_ns, std::optional<std::uint32_t> only_subscription = std::nullopt) override;
  void offer_parameter_updates(const nlohmann::json& changed) override;
  void subscribed_channels(std::set<std::uint32_t>& out) const override;
  void drop_channels(const std::vector<std::uint32_t>& removed) override;
  HttpServer::ConnectionStats stats() const override;
  void hard_close() override;

 protected:
  // Close codes the protocol asks the transport for (RFC 6455 values).
  static constexpr int kCloseNormal = 1000;
  static constexpr int kClosePolicy = 1008;

  struct PendingData {
    std::array<std::uint8_t, fg::kMessageDataHeaderBytes> header{};
    std::shared_ptr<const std::string> payload;
  };

  // Transport, on the strand.
  virtual void write_message(const std::string& bytes, bool binary) = 0;
  virtual void write_data(const PendingData& data) = 0;
  virtual void close_with(int code) = 0;  // a close frame, then on_closed()
  virtual void shutdown_socket() = 0;     // at once, no close frame
  virtual void resume_reading() = 0;      // from any thread: read the next message (after on_message false)

  // Called by the transport on the strand.
  void on_open();  // handshake done
  // One complete client message. False: its work runs on the request lane, and the transport reads
  // the next message only when resume_reading() is called (a connection's messages keep their order).
  bool on_message(bool is_text, const std::string& message);
  void on_write_done(bool ok, std::size_t bytes);
  void on_closed();
  bool closing() const noexcept { return closing_; }
  HttpServer::Impl& server_;

 private:
  void do_write();
  void post_write();
  void begin_close(int code);
  void finish_close();
  bool take_rate_token();
  void violation(const std::string& message);
  void handle_text(const std::string& text);
  bool handle_binary(const std::string& data);  // false: a service call went to the request lane
  nlohmann::json select_parameters(const std::vector<std::string>& names) const;
  void handle_set_parameters(const fg::SetParametersOp& set);
  void handle_subscribe(const fg::SubscribeOp& subscribe);
  void handle_client_advertise(const fg::ClientAdvertiseOp& advertise);
  bool run_service_call(const fg::ServiceCallRequest& call);
  void handle_service_call(const fg::ServiceCallRequest& call);
  void send_binary(std::string frame);
  // Under out_mutex_: true when a write has been stuck past the bound (the client stopped reading).
  bool write_stalled_locked(SteadyClock::time_point now) const;
  void close_for_backlog();

  net::any_io_executor executor_;
  const Identity identity_;
  const std::uint64_t id_;

  // Strand-only state.
  double tokens_;
  SteadyClock::time_point last_refill_;
  int violations_ = 0;
  bool closing_ = false;
  bool gone_ = false;
  int close_code_ = kCloseNormal;
  std::map<std::uint32_t, std::pair<std::string, CommandRef>> client_channels_;  // id -> robot, stream
  std::string current_text_;
  PendingData current_data_;

  // Shared with the publisher thread.
  mutable std::mutex out_mutex_;
  std::deque<std::string> control_queue_;
  std::set<std::uint64_t> binary_control_;  // sequence numbers of binary entries in control_queue_
  std::uint64_t control_popped_ = 0;
  std::unordered_map<std::uint32_t, PendingData> latest_;  // subscription id -> newest unsent message
  std::deque<std::uint32_t> latest_order_;                 // fair order of subscriptions with data
  std::map<std::uint32_t, std::uint32_t> subscriptions_;   // subscription id -> channel id
  std::set<std::string> parameter_subscriptions_;          // parametersSubscribe names
  bool writing_ = false;
  SteadyClock::time_point write_started_{};  // when the write in flight began
  bool closed_ = false;
  bool close_pending_ = false;
  bool backlog_close_posted_ = false;
  std::uint64_t dropped_ = 0;
};

}  // namespace tendril::server
