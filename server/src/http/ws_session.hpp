// WsSession<Stream>: the WebSocket transport of one connection (Beast websocket::stream over the
// connection's byte stream): handshake, read loop, one write in flight, close. The protocol is in
// WsConnection. Instantiated once, for ByteStream (ws_session.cpp), whatever the transport under it.
//
// Every completion handler runs inside contain(): an exception closes this connection only.
#pragma once

#include <array>

#include <boost/asio/buffer.hpp>
#include <boost/asio/dispatch.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/stream_traits.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket.hpp>

#include "stream_socket.hpp"
#include "ws_connection.hpp"

namespace tendril::server {

namespace beast = boost::beast;
namespace websocket = boost::beast::websocket;

template <class Stream>
class WsSession final : public WsConnection {
 public:
  WsSession(Stream&& stream, HttpServer::Impl& server, Identity identity, std::uint64_t id)
      : WsConnection(stream.get_executor(), server, std::move(identity), id), ws_(std::move(stream)) {}

  void run(Request request) {
    request_ = std::move(request);
    // The connection's slot (connection_limits.hpp) passes to this session: on the HTTP session's
    // strand, which is this one's, so its close hook sees the hand-over before it could run.
    slot_ = server_.connections.slot_of(id());
    if (slot_) {
      slot_->handed_over = true;
      slot_->attach(id(), [weak = std::weak_ptr<WsConnection>(shared_from_this())] {
        if (const auto self = weak.lock()) self->hard_close();
      });
    }
    net::dispatch(ws_.get_executor(),
                  [self = self_()] { self->contain("accept", [&] { self->do_accept(); }); });
  }

 private:
  std::shared_ptr<WsSession> self_() { return std::static_pointer_cast<WsSession>(shared_from_this()); }

  template <class F>
  void contain(const char* where, F&& body) noexcept {
    try {
      body();
    } catch (const std::exception& e) {
      failed(where, e.what());
    } catch (...) {
      failed(where, "an exception that is not a std::exception");
    }
  }
  void failed(const char* where, const char* what) noexcept {
    if (!failed_) server_.connection_failed(id(), where, what);
    failed_ = true;
    try {
      shutdown_socket();
      on_closed();
    } catch (...) {  // NOLINT(bugprone-empty-catch): nothing more can be done for this connection
    }
  }

  void do_accept() {
    // Timeouts (README "Limits"): the handshake answer within handshake_timeout; a peer that sends
    // nothing for idle_timeout is pinged at half of it and closed at the end (a vanished console's
    // descriptor comes back; every client answers pings by itself).
    auto timeouts = websocket::stream_base::timeout::suggested(beast::role_type::server);
    timeouts.handshake_timeout = server_.opts.handshake_timeout;
    timeouts.idle_timeout = server_.opts.idle_timeout;
    timeouts.keep_alive_pings = true;
    ws_.set_option(timeouts);
    ws_.set_option(websocket::stream_base::decorator([](websocket::response_type& res) {
      res.set(bhttp::field::server, "tendril");
      res.set(bhttp::field::sec_websocket_protocol, std::string(fg::kSubprotocol));
    }));
    ws_.read_message_max(server_.opts.max_ws_message_bytes);
    ws_.async_accept(request_, [self = self_()](beast::error_code ec) {
      self->contain("accept", [&] {
        if (ec) return;
        self->on_open();
        self->do_read();
      });
    });
  }

  void do_read() {
    ws_.async_read(buffer_, [self = self_()](beast::error_code ec, std::size_t) {
      self->contain("read", [&] { self->on_read(ec); });
    });
  }

  void on_read(beast::error_code ec) {
    if (ec) return on_closed();
    const bool is_text = ws_.got_text();
    std::string message = beast::buffers_to_string(buffer_.data());
    buffer_.consume(buffer_.size());
    if (on_message(is_text, message) && !closing()) do_read();
  }

  void resume_reading() override {
    net::post(ws_.get_executor(), [self = self_()] {
      self->contain("read", [&] {
        if (!self->closing()) self->do_read();
      });
    });
  }

  void write_message(const std::string& bytes, bool binary) override {
    ws_.binary(binary);
    ws_.async_write(net::buffer(bytes), [self = self_()](beast::error_code ec, std::size_t n) {
      self->contain("write", [&] { self->on_write_done(!ec, n); });
    });
  }

  void write_data(const PendingData& data) override {
    const std::array<net::const_buffer, 2> buffers = {net::buffer(data.header), net::buffer(*data.payload)};
    ws_.binary(true);
    ws_.async_write(buffers, [self = self_()](beast::error_code ec, std::size_t n) {
      self->contain("write", [&] { self->on_write_done(!ec, n); });
    });
  }

  void close_with(int code) override {
    ws_.async_close(static_cast<websocket::close_code>(code), [self = self_()](beast::error_code) {
      self->contain("close", [&] { self->on_closed(); });
    });
  }

  void shutdown_socket() override { StreamSocket<Stream>::close(ws_.next_layer()); }

  websocket::stream<Stream> ws_;
  beast::flat_buffer buffer_;
  Request request_;
  bool failed_ = false;
  std::shared_ptr<ConnectionSlot> slot_;
};

template <class Stream>
void start_ws_session(Stream&& stream, HttpServer::Impl& server, Identity identity, std::uint64_t id,
                      Request request) {
  std::make_shared<WsSession<Stream>>(std::forward<Stream>(stream), server, std::move(identity), id)
      ->run(std::move(request));
}

}  // namespace tendril::server
