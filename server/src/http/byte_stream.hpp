// ByteStream: one connection's byte stream (plain TCP, TLS, or Beast's in-memory test stream) behind
// one type. The HTTP and WebSocket sessions are Beast's heaviest templates; written over ByteStream
// they are compiled once, not once per transport (issue 11: the plain and TLS copies took ~125 of the
// ~740 CPU-seconds of a release build). The price is one virtual call, one small buffer vector and
// one handler allocation per read or write, on the I/O threads only.
//
// A transport (stream_transport.hpp) adapts a concrete stream. Completion handlers keep their
// associated executor (the connection's strand), so Beast's composed operations run where they would
// on the concrete stream.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <utility>
#include <vector>

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/associated_executor.hpp>
#include <boost/asio/async_result.hpp>
#include <boost/asio/buffer.hpp>
#include <boost/beast/core/error.hpp>
#include <boost/beast/core/role.hpp>

#include "stream_socket.hpp"

namespace tendril::server {

// A move-only completion handler of signature void(error_code, std::size_t) (or void(error_code)),
// carrying the wrapped handler's associated executor.
class IoCompletion {
 public:
  using executor_type = boost::asio::any_io_executor;

  template <class Handler>
  IoCompletion(Handler&& handler, const executor_type& fallback)
      : executor_(boost::asio::get_associated_executor(handler, fallback)),
        impl_(std::make_unique<Impl<std::decay_t<Handler>>>(std::forward<Handler>(handler))) {}

  IoCompletion(IoCompletion&&) noexcept = default;
  IoCompletion& operator=(IoCompletion&&) noexcept = default;
  IoCompletion(const IoCompletion&) = delete;
  IoCompletion& operator=(const IoCompletion&) = delete;
  ~IoCompletion() = default;

  executor_type get_executor() const noexcept { return executor_; }

  // The handler's storage is released before the upcall (Asio's rule for composed operations).
  void operator()(boost::beast::error_code ec, std::size_t bytes) {
    auto impl = std::move(impl_);
    Base* raw = impl.get();
    raw->call(std::move(impl), ec, bytes);
  }
  void operator()(boost::beast::error_code ec) { (*this)(ec, 0); }

 private:
  struct Base {
    Base() = default;
    Base(const Base&) = delete;
    Base& operator=(const Base&) = delete;
    Base(Base&&) = delete;
    Base& operator=(Base&&) = delete;
    virtual ~Base() = default;
    virtual void call(std::unique_ptr<Base> self, boost::beast::error_code ec, std::size_t bytes) = 0;
  };
  template <class Handler>
  struct Impl final : Base {
    explicit Impl(Handler&& h) : handler(std::move(h)) {}
    explicit Impl(const Handler& h) : handler(h) {}
    void call(std::unique_ptr<Base> self, boost::beast::error_code ec, std::size_t bytes) override {
      Handler h(std::move(handler));
      self.reset();
      if constexpr (std::is_invocable_v<Handler&, boost::beast::error_code, std::size_t>) {
        h(ec, bytes);
      } else {
        h(ec);
      }
    }
    Handler handler;
  };

  executor_type executor_;
  std::unique_ptr<Base> impl_;
};

class ByteStream {
 public:
  using executor_type = boost::asio::any_io_executor;

  // What a concrete stream provides (stream_transport.hpp).
  class Transport {
   public:
    Transport() = default;
    Transport(const Transport&) = delete;
    Transport& operator=(const Transport&) = delete;
    Transport(Transport&&) = delete;
    Transport& operator=(Transport&&) = delete;
    virtual ~Transport() = default;

    virtual executor_type get_executor() = 0;
    virtual bool is_tls() const = 0;
    virtual void async_read_some(std::vector<boost::asio::mutable_buffer> buffers, IoCompletion done) = 0;
    virtual void async_write_some(std::vector<boost::asio::const_buffer> buffers, IoCompletion done) = 0;
    // TLS: the server's handshake; otherwise completes at once (posted).
    virtual void async_handshake(IoCompletion done) = 0;
    // The end of an HTTP connection: TLS close_notify, or a TCP half-close (then completes, posted).
    virtual void async_shutdown(IoCompletion done) = 0;
    // The end of a WebSocket connection (Beast's teardown for the concrete stream).
    virtual void async_teardown(boost::beast::role_type role, IoCompletion done) = 0;
    virtual void teardown(boost::beast::role_type role, boost::beast::error_code& ec) = 0;
    virtual void expires_after(std::chrono::seconds timeout) = 0;
    virtual void expires_never() = 0;
    virtual void shutdown_send() = 0;
    virtual void close() = 0;
  };

  explicit ByteStream(std::unique_ptr<Transport> transport) : transport_(std::move(transport)) {}

  executor_type get_executor() { return transport_->get_executor(); }
  bool is_tls() const { return transport_->is_tls(); }
  Transport& transport() { return *transport_; }

  template <class MutableBufferSequence, class ReadHandler>
  auto async_read_some(const MutableBufferSequence& buffers, ReadHandler&& handler) {
    return boost::asio::async_initiate<ReadHandler, void(boost::beast::error_code, std::size_t)>(
        [this](auto&& h, const MutableBufferSequence& b) {
          transport_->async_read_some(to_vector<boost::asio::mutable_buffer>(b),
                                      IoCompletion(std::forward<decltype(h)>(h), get_executor()));
        },
        handler, buffers);
  }

  template <class ConstBufferSequence, class WriteHandler>
  auto async_write_some(const ConstBufferSequence& buffers, WriteHandler&& handler) {
    return boost::asio::async_initiate<WriteHandler, void(boost::beast::error_code, std::size_t)>(
        [this](auto&& h, const ConstBufferSequence& b) {
          transport_->async_write_some(to_vector<boost::asio::const_buffer>(b),
                                       IoCompletion(std::forward<decltype(h)>(h), get_executor()));
        },
        handler, buffers);
  }

  template <class Handler>
  void async_handshake(Handler&& handler) {
    transport_->async_handshake(IoCompletion(std::forward<Handler>(handler), get_executor()));
  }
  template <class Handler>
  void async_shutdown(Handler&& handler) {
    transport_->async_shutdown(IoCompletion(std::forward<Handler>(handler), get_executor()));
  }

  // Beast's customisation points, found by argument-dependent lookup: closing the socket on a
  // WebSocket timeout, and the WebSocket closing handshake's teardown.
  friend void beast_close_socket(ByteStream& s) { s.transport_->close(); }
  friend void teardown(boost::beast::role_type role, ByteStream& s, boost::beast::error_code& ec) {
    s.transport_->teardown(role, ec);
  }
  template <class TeardownHandler>
  friend void async_teardown(boost::beast::role_type role, ByteStream& s, TeardownHandler&& handler) {
    s.transport_->async_teardown(role,
                                 IoCompletion(std::forward<TeardownHandler>(handler), s.get_executor()));
  }

 private:
  template <class Buffer, class Sequence>
  static std::vector<Buffer> to_vector(const Sequence& sequence) {
    std::vector<Buffer> out;
    const auto end = boost::asio::buffer_sequence_end(sequence);
    for (auto it = boost::asio::buffer_sequence_begin(sequence); it != end; ++it) out.emplace_back(*it);
    return out;
  }

  std::unique_ptr<Transport> transport_;
};

// The sessions' socket operations on a ByteStream go to its transport.
template <>
struct StreamSocket<ByteStream> {
  static void expires_after(ByteStream& s, std::chrono::seconds d) { s.transport().expires_after(d); }
  static void expires_never(ByteStream& s) { s.transport().expires_never(); }
  static void shutdown_send(ByteStream& s) { s.transport().shutdown_send(); }
  static void close(ByteStream& s) { s.transport().close(); }
};

}  // namespace tendril::server
