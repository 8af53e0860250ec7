// HttpSession<Stream>: one HTTP connection (Beast advanced-server pattern). Reads one request at a
// time with BoundedRequestParser (requests pipelined behind it wait in the read buffer), answers it
// through route_request(), and hands the stream to a WebSocket session on an upgrade to /ws.
//
// Containment: every completion handler runs inside contain(); an exception (from Beast, the routes or
// ControlApi) closes this connection only, is counted and logged once, and the I/O thread goes on.
//
// Instantiated once, for ByteStream (http_session.cpp): plain TCP and TLS differ only in the transport
// under it (byte_stream.hpp), so Beast's HTTP operations are compiled once.
#pragma once

#include <exception>
#include <limits>
#include <memory>
#include <optional>

#include <boost/asio/dispatch.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/stream_traits.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/write.hpp>
#include <boost/beast/websocket/rfc6455.hpp>

#include "byte_stream.hpp"
#include "front_end.hpp"
#include "request_reader.hpp"
#include "rest_routes.hpp"
#include "stream_socket.hpp"

namespace tendril::server {

namespace beast = boost::beast;

// The WebSocket side of an upgrade (ws_session_*.cpp): takes over the stream and the upgrade request.
template <class Stream>
void start_ws_session(Stream&& stream, HttpServer::Impl& server, Identity identity, std::uint64_t id,
                      Request request);

template <class Stream>
class HttpSession : public std::enable_shared_from_this<HttpSession<Stream>> {
 public:
  template <class... Args>
  HttpSession(HttpServer::Impl& server, Args&&... stream_args)
      : stream_(std::forward<Args>(stream_args)...),
        buffer_(http::kReadBufferBytes),
        server_(server),
        connection_id_(server.next_connection_id++) {}

  void run() {
    auto self = this->shared_from_this();
    take_connection_slot();
    net::dispatch(stream_.get_executor(), [self] {
      self->contain("start", [&] {
        // TLS first (a plain stream's handshake completes at once); the handshake and the first
        // request's header must arrive within handshake_timeout, or the client is dropped.
        StreamSocket<Stream>::expires_after(self->stream_, self->server_.opts.handshake_timeout);
        self->stream_.async_handshake([self](beast::error_code ec) {
          self->contain("tls handshake", [&] {
            if (!ec) self->do_read();
          });
        });
      });
    });
  }

 private:
  // Runs a handler body; an exception closes this connection and is counted and logged once.
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
    if (!failed_) server_.connection_failed(connection_id_, where, what);
    failed_ = true;
    StreamSocket<Stream>::close(stream_);
  }

  void do_read() {
    // Beast checks Content-Length against the body limit while it parses the header, before the
    // route and the caller are known: no limit here; on_header sets the route's for this caller (and
    // refuses a declared length over it) before a byte of the body is read.
    body_limit_ = server_.largest_body_limit();
    decision_ = {};
    parser_.emplace(body_limit_);
    // (Not boost::none: Boost 1.74 compares a length against an empty optional as "over the limit".)
    parser_->body_limit(std::numeric_limits<std::uint64_t>::max());
    wait_for_request();
    bhttp::async_read_header(stream_, buffer_, *parser_,
                             [self = this->shared_from_this()](beast::error_code ec, std::size_t) {
                               self->contain("read header", [&] {
                                 self->header_arrived(ec);
                                 self->on_header(ec);
                               });
                             });
  }

  void on_header(beast::error_code ec) {
    if (ec) return on_read(ec);
    const auto& header = parser_->get();
    const auto declared = parser_->content_length();
    const bool has_body = parser_->chunked() || (declared && *declared > 0);
    // The e-stop is latched here; a caller who may not send this body is known here too.
    decision_ = decide_header(server_, header, has_body, connection_id_);
    body_limit_ = decision_.refusal ? server_.opts.max_body_bytes : decision_.body_limit;
    // A declared length over the route's limit is refused before the body is read; a chunked body
    // is held to the limit chunk by chunk. A refused caller's small body is read (never parsed), so
    // that the answer reaches it and the connection stays usable; a larger one is not read at all.
    if (declared && *declared > body_limit_) return on_read(bhttp::error::body_limit);
    parser_->body_limit(body_limit_);
    // 30 s for a body, plus a second for each MiB a large one may have (32 MiB: 62 s).
    StreamSocket<Stream>::expires_after(stream_,
                                        std::chrono::seconds(30 + static_cast<long>(body_limit_ >> 20)));
    bhttp::async_read(stream_, buffer_, *parser_,
                      [self = this->shared_from_this()](beast::error_code ec, std::size_t) {
                        self->contain("read body", [&] { self->on_read(ec); });
                      });
  }

  void on_read(beast::error_code ec) {
    if (ec) {
      const auto refusal = http::refusal_for(ec, body_limit_);
      // The rest of the connection's bytes cannot be trusted to frame a next request: answer and close.
      Request partial;
      partial.version(parser_ && parser_->is_header_done() ? parser_->get().version() : 11);
      partial.keep_alive(false);
      // An e-stop already latched is answered as one, whatever became of its body.
      if (decision_.estop) return send(api_response(partial, *decision_.estop));
      if (!refusal) return do_close();
      if (decision_.refusal) return send(api_response(partial, *decision_.refusal));
      server_.count_refused(refusal->metric);
      return send(
          error_response(partial, ApiResult::error(refusal->status, refusal->code, refusal->message)));
    }
    Request request = parser_->release();
    if (decision_.estop) return send(api_response(request, *decision_.estop));
    if (decision_.refusal) {
      server_.count_refused("before_body");
      return send(api_response(request, *decision_.refusal));
    }
    if (boost::beast::websocket::is_upgrade(request)) return handle_upgrade(std::move(request));
    // Without lanes (an Impl that was never started, as the framing fuzzer drives it) the work runs
    // here, as it did on every request before there were lanes.
    http::WorkLane* lane = decision_.lane == RequestLane::kRequests  ? server_.request_lane.get()
                           : decision_.lane == RequestLane::kUploads ? server_.upload_lane.get()
                                                                     : nullptr;
    if (lane != nullptr) return run_in_lane(*lane, std::move(request));
    send(route_request(server_, request, connection_id_));
  }

  // The request's work on a worker of `lane`; its answer is written from this connection's strand.
  // Nothing more is read from this connection meanwhile (one request at a time, as before).
  void run_in_lane(http::WorkLane& lane, Request&& request) {
    auto shared_request = std::make_shared<Request>(std::move(request));
    const bool queued =
        lane.try_submit([self = this->shared_from_this(), executor = stream_.get_executor(), shared_request] {
          // An exception that escaped the route is contained on the connection's strand, as one there
          // would be: counted, logged once, and only this connection closed.
          std::shared_ptr<RouteResult> result;
          std::exception_ptr escaped;
          try {
            result = std::make_shared<RouteResult>(
                route_request(self->server_, *shared_request, self->connection_id_));
          } catch (...) {
            escaped = std::current_exception();
          }
          net::post(executor, [self, result, escaped] {
            self->contain("route", [&] {
              if (escaped) std::rethrow_exception(escaped);
              self->send(std::move(*result));
            });
          });
        });
    if (queued) return;
    server_.count_refused("busy_" + lane.name());
    auto response = error_response(
        *shared_request,
        ApiResult::error(503, "server_busy",
                         lane.name() == "uploads"
                             ? "the server is already working on " + std::to_string(lane.max_queued()) +
                                   " large requests (uploads, pictures); send this one again when one of "
                                   "them has finished"
                             : "the server has " + std::to_string(lane.max_queued()) +
                                   " requests waiting; send this one again in a moment"));
    response.set(bhttp::field::retry_after, "1");
    send(std::move(response));
  }

  static StringResponse api_response(const Request& request, const ApiResult& result) {
    return result.ok() ? json_response(request, result.status, result.body) : error_response(request, result);
  }

  void handle_upgrade(Request req) {
    UpgradeDecision decision = decide_upgrade(server_, req, connection_id_);
    if (decision.refusal) return send(std::move(*decision.refusal));
    StreamSocket<Stream>::expires_never(stream_);
    start_ws_session(std::move(stream_), server_, std::move(decision.identity), connection_id_,
                     std::move(req));
  }

  void send(RouteResult&& result) {
    std::visit([this](auto& response) { this->send(std::move(response)); }, result);
  }

  template <class Body>
  void send(bhttp::response<Body>&& response) {
    server_.count_status(response.result_int());
    // The answer has its own time: the work before it (an upload waiting for its worker) may have
    // taken longer than the time the request had to arrive.
    StreamSocket<Stream>::expires_after(stream_, std::chrono::seconds(30));
    auto shared = std::make_shared<bhttp::response<Body>>(std::move(response));
    bhttp::async_write(stream_, *shared,
                       [self = this->shared_from_this(), shared](beast::error_code ec, std::size_t) {
                         self->contain("write", [&] { self->on_write(ec, shared->need_eof()); });
                       });
  }

  void on_write(beast::error_code ec, bool close) {
    if (ec) return;
    if (close) return do_close();
    do_read();
  }

  void do_close() {
    // TLS close_notify or a TCP half-close; the socket goes with the session.
    stream_.async_shutdown([self = this->shared_from_this()](beast::error_code) {});
  }

  // Connection limits and timeouts (connection_limits.hpp, README "Limits").
  // The slot the listener admitted this connection into (none for a session the fuzzer starts), and
  // how the registry closes the connection to make room (from any thread; posted to its strand).
  void take_connection_slot() {
    slot_ = std::move(server_.accepted_slot);
    if (!slot_) return;
    slot_->attach(connection_id_, [weak = this->weak_from_this(), executor = stream_.get_executor()] {
      net::post(executor, [weak] {
        const auto self = weak.lock();
        if (!self || self->slot_->handed_over) return;  // gone, or now a WebSocket's stream
        StreamSocket<Stream>::close(self->stream_);
      });
    });
  }
  // Idle, waiting for a request: until authenticated, each request header must arrive within
  // handshake_timeout (the first one's time runs from the accept, set in run()); once authenticated,
  // the connection may idle idle_timeout between requests.
  void wait_for_request() {
    if (slot_) slot_->set_idle(true);
    if (!awaited_request_) {
      awaited_request_ = true;
      return;
    }
    const bool authenticated = !slot_ || slot_->authenticated();
    StreamSocket<Stream>::expires_after(
        stream_, authenticated ? server_.opts.idle_timeout : server_.opts.handshake_timeout);
  }
  // A header arrived: busy (never closed to make room) until the next wait; the body and the answer
  // have the usual 30 s.
  void header_arrived(beast::error_code ec) {
    if (ec) return;
    if (slot_) slot_->set_idle(false);
    StreamSocket<Stream>::expires_after(stream_, std::chrono::seconds(30));
  }

  Stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::BoundedRequestParser> parser_;
  std::size_t body_limit_ = 0;  // of the request being read
  HeaderDecision decision_;     // of the request being read (decide_header)
  HttpServer::Impl& server_;
  const std::uint64_t connection_id_;
  bool failed_ = false;
  std::shared_ptr<ConnectionSlot> slot_;
  bool awaited_request_ = false;  // the first request's wait is timed from the accept
};

}  // namespace tendril::server
