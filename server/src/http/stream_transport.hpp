// StreamTransport<S>: a concrete Beast stream as a ByteStream::Transport. Instantiated for plain TCP
// and TLS (byte_stream_tcp.cpp, byte_stream_tls.cpp) and for Beast's in-memory test stream by the HTTP
// fuzz target, which thereby drives the very session code the server runs. StreamSocket<S> says what
// the stream's socket does (timeouts, shutdown, close).
#pragma once

#include <utility>

#include <boost/asio/post.hpp>
#include <boost/asio/ssl/stream_base.hpp>
#include <boost/beast/websocket/teardown.hpp>

#include "byte_stream.hpp"

namespace tendril::server {

// Specialised to true for TLS streams (byte_stream_tls.cpp).
template <class S>
inline constexpr bool kIsTlsTransport = false;

template <class S>
class StreamTransport final : public ByteStream::Transport {
 public:
  template <class... Args>
  explicit StreamTransport(Args&&... args) : stream_(std::forward<Args>(args)...) {}

  ByteStream::executor_type get_executor() override { return stream_.get_executor(); }
  bool is_tls() const override { return kIsTlsTransport<S>; }

  void async_read_some(std::vector<boost::asio::mutable_buffer> buffers, IoCompletion done) override {
    stream_.async_read_some(buffers, std::move(done));
  }
  void async_write_some(std::vector<boost::asio::const_buffer> buffers, IoCompletion done) override {
    stream_.async_write_some(buffers, std::move(done));
  }
  void async_handshake(IoCompletion done) override {
    if constexpr (kIsTlsTransport<S>) {
      stream_.async_handshake(boost::asio::ssl::stream_base::server, std::move(done));
    } else {
      complete_later(std::move(done));
    }
  }
  void async_shutdown(IoCompletion done) override {
    if constexpr (kIsTlsTransport<S>) {
      stream_.async_shutdown(std::move(done));
    } else {
      StreamSocket<S>::shutdown_send(stream_);
      complete_later(std::move(done));
    }
  }
  void async_teardown(boost::beast::role_type role, IoCompletion done) override {
    using boost::beast::websocket::async_teardown;
    async_teardown(role, stream_, std::move(done));
  }
  void teardown(boost::beast::role_type role, boost::beast::error_code& ec) override {
    using boost::beast::websocket::teardown;
    teardown(role, stream_, ec);
  }
  void expires_after(std::chrono::seconds timeout) override {
    StreamSocket<S>::expires_after(stream_, timeout);
  }
  void expires_never() override { StreamSocket<S>::expires_never(stream_); }
  void shutdown_send() override { StreamSocket<S>::shutdown_send(stream_); }
  void close() override { StreamSocket<S>::close(stream_); }

 private:
  void complete_later(IoCompletion done) {
    boost::asio::post(stream_.get_executor(),
                      [done = std::move(done)]() mutable { done(boost::beast::error_code{}, 0); });
  }

  S stream_;
};

}  // namespace tendril::server
