// HttpServer: the listener, the I/O threads and the publisher thread of the REST + WebSocket front end
// (Boost.Beast advanced-server pattern: one port, upgrade on /ws, one strand per connection). The
// connections, routes and protocol live in the files listed in front_end.hpp. No code here runs in
// the real-time path.
#include <fcntl.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>

#include <boost/asio/post.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core/error.hpp>

#include "front_end.hpp"
#include "tendril/server/http/planning_routes.hpp"

namespace tendril::server {

namespace beast = boost::beast;
using nlohmann::json;
using namespace tendril::server::http;

std::string random_hex(std::size_t bytes) {
  static thread_local std::random_device device;
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < bytes; ++i) {
    const auto b = static_cast<unsigned>(device()) & 0xFF;
    out.push_back(kDigits[b >> 4]);
    out.push_back(kDigits[b & 0xF]);
  }
  return out;
}

std::string dump(const json& value) { return value.dump(-1, ' ', false, json::error_handler_t::replace); }

std::uint64_t wall_time_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

ApiResult unknown_robot_result(const std::string& robot) {
  return ApiResult::error(404, "unknown_robot",
                          "no robot named \"" + robot + "\"; GET /api/v1/robots lists them");
}

namespace {
std::vector<std::string> robot_names(const ControlApi& api) {
  std::vector<std::string> names;
  for (const auto& robot : api.robots()) names.push_back(robot.at("name").get<std::string>());
  return names;
}
}  // namespace

HttpServer::Impl::Impl(ControlApi& api_in, HttpOptions options_in)
    : api(api_in),
      opts(std::move(options_in)),
      leases(robot_names(api_in), opts.lease_timeout),
      service_defs(service_definitions(api_in)),
      services(service_list(service_defs)) {
  for (const auto& source : opts.topic_sources) {
    if (!source) continue;
    for (auto& info : source->topics()) {
      const std::string topic = info.topic;
      source_topics[topic] = {source.get(), std::move(info)};
    }
  }
}

void HttpServer::Impl::log(const std::string& line) const noexcept {
  try {
    if (opts.log) {
      opts.log(line);
    } else {
      std::cerr << "tendrild: http: " << line << std::endl;
    }
  } catch (...) {  // NOLINT(bugprone-empty-catch): a log line that cannot be written is dropped
  }
}

void HttpServer::Impl::connection_failed(std::uint64_t connection_id, const char* where,
                                         const char* what) noexcept {
  ++connection_exceptions;
  try {
    log("connection " + std::to_string(connection_id) + ": exception in " + where + ": " + what +
        "; that connection was closed, the server goes on");
  } catch (...) {  // NOLINT(bugprone-empty-catch): counted above; the message could not be built
  }
}

std::size_t HttpServer::Impl::largest_body_limit() const {
  std::size_t largest = opts.max_body_bytes;
  if (opts.planning != nullptr) largest = std::max(largest, opts.planning->max_vessel_bytes());
  return largest;
}

// The last line of defence: a handler that let an exception escape its connection's containment must
// not end the process (which would leave the drives to their heartbeat timeout). run() returns after
// such an exception; the thread counts it and goes back into run().
void HttpServer::Impl::run_io() noexcept {
  while (true) {
    try {
      ioc->run();
      return;
    } catch (const std::exception& e) {
      connection_failed(0, "an I/O handler", e.what());
    } catch (...) {
      connection_failed(0, "an I/O handler", "an exception that is not a std::exception");
    }
  }
}

namespace {

// accept() failed for want of descriptors or memory: accepting again at once would fail the same way
// and spin (the probe saw 70 % CPU).
bool out_of_descriptors(const beast::error_code& ec) {
  return ec == net::error::no_descriptors || ec == net::error::no_buffer_space ||
         ec == net::error::no_memory || ec == boost::system::errc::too_many_files_open_in_system;
}

int open_spare_descriptor() { return ::open("/dev/null", O_RDONLY | O_CLOEXEC); }

}  // namespace

// The listener (on the acceptor's strand): each accepted connection is admitted against the limits
// (connection_limits.hpp) before a session serves it.
void HttpServer::Impl::do_accept() {
  acceptor->async_accept(net::make_strand(*ioc), [this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor->is_open()) return;
    if (out_of_descriptors(ec)) return on_descriptors_exhausted();
    if (!ec) accept_connection(std::move(socket));
    do_accept();
  });
}

void HttpServer::Impl::accept_connection(tcp::socket socket) {
  beast::error_code ec;
  const auto remote = socket.remote_endpoint(ec);
  if (ec) return;  // the client left before it was served; the socket closes here
  accepted_slot = connections.admit(remote.address().to_string());
  if (!accepted_slot) return;  // over its limit with nobody to make room (counted): closed at once
  socket.set_option(tcp::no_delay(true), ec);  // small state messages should not wait for Nagle
  try {
    if (tls_context) {
      start_tls_http_session(std::move(socket), *this);
    } else {
      start_plain_http_session(std::move(socket), *this);
    }
  } catch (const std::exception& e) {
    connection_failed(0, "accept", e.what());
  }
  accepted_slot.reset();  // normally taken by the session already
}

// Out of descriptors: make room, then wait before accepting again. Room comes from the oldest idle
// unauthenticated connection: its close (posted to its strand) has run 1 ms later, and each retry costs
// one such connection, so this cannot spin; a backlog of new clients (an e-stop among them) gets in
// at about 1 ms each rather than 50. With none to close, the spare descriptor is given up for a moment
// to take the waiting client and close it (it hears "closed" at once rather than timing out), and the
// listener waits accept_backoff.
void HttpServer::Impl::on_descriptors_exhausted() {
  ++accept_backoffs;
  const bool evicted = connections.evict_oldest();
  if (!evicted && spare_descriptor >= 0) {
    ::close(spare_descriptor);
    const int waiting = ::accept4(acceptor->native_handle(), nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (waiting >= 0) {
      ::close(waiting);
      ++accepted_and_closed;
    }
    spare_descriptor = open_spare_descriptor();  // may fail while descriptors are short: retried below
  }
  accept_timer->expires_after(evicted ? std::chrono::milliseconds(1) : opts.accept_backoff);
  accept_timer->async_wait([this](beast::error_code ec) {
    if (ec || !acceptor->is_open()) return;
    if (spare_descriptor < 0) spare_descriptor = open_spare_descriptor();
    do_accept();
  });
}

// ------------------------------------------------------------------------------------------------
// HttpServer

HttpServer::HttpServer(ControlApi& api, HttpOptions options)
    : impl_(std::make_unique<Impl>(api, std::move(options))) {
  if (impl_->opts.token.empty()) {
    throw HttpServerError(
        "HttpServer needs an access token (HttpOptions::token); refusing to serve without one");
  }
  if (impl_->opts.io_threads < 1) throw HttpServerError("HttpOptions::io_threads must be at least 1");
}

HttpServer::~HttpServer() { stop(); }

namespace {

// The connection limits (README "Limits"): what HttpOptions leaves at 0 is derived from the descriptor
// limit, whose soft value is raised toward the hard one first (to at most kWantedDescriptors: a larger
// table helps no one). Inconsistent settings are set-up errors.
ConnectionRegistry::Limits connection_limits(const HttpOptions& opts) {
  constexpr rlim_t kWantedDescriptors = 65536;
  constexpr std::size_t kDefaultMaxConnections = 4096;
  constexpr std::size_t kFewestConnections = 8;
  std::size_t descriptors = 1024;
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) == 0) {
    const rlim_t wanted = std::min(limit.rlim_max, kWantedDescriptors);  // RLIM_INFINITY is the largest
    if (limit.rlim_cur < wanted) {
      rlimit raised = limit;
      raised.rlim_cur = wanted;
      if (::setrlimit(RLIMIT_NOFILE, &raised) == 0) limit = raised;
    }
    descriptors = static_cast<std::size_t>(std::min(limit.rlim_cur, kWantedDescriptors));
  }
  const std::string limit_text = "the process may open " + std::to_string(descriptors) +
                                 " file descriptors (ulimit -n; systemd LimitNOFILE=) and keeps " +
                                 std::to_string(opts.descriptor_reserve) + " of them (descriptor_reserve)";
  if (descriptors < opts.descriptor_reserve + kFewestConnections)
    throw HttpServerError("too few file descriptors for the HTTP server: " + limit_text);
  const std::size_t available = descriptors - opts.descriptor_reserve;
  ConnectionRegistry::Limits out;
  out.total = opts.max_connections != 0 ? opts.max_connections : std::min(kDefaultMaxConnections, available);
  if (out.total > available) {
    throw HttpServerError("max_connections " + std::to_string(out.total) + " is more than " + limit_text +
                          " allow; lower it or raise the descriptor limit");
  }
  out.unauthenticated =
      opts.max_unauthenticated_connections != 0 ? opts.max_unauthenticated_connections : out.total * 3 / 4;
  if (out.unauthenticated >= out.total) {
    throw HttpServerError("max_unauthenticated_connections (" + std::to_string(out.unauthenticated) +
                          ") must be below max_connections (" + std::to_string(out.total) +
                          "), so that room stays for operators");
  }
  out.per_address = opts.max_unauthenticated_per_address;
  if (out.per_address == 0) throw HttpServerError("max_unauthenticated_per_address must be at least 1");
  if (opts.handshake_timeout.count() < 1 || opts.idle_timeout.count() < 1)
    throw HttpServerError("handshake_timeout and idle_timeout must be at least 1 s");
  if (opts.accept_backoff.count() < 1) throw HttpServerError("accept_backoff must be at least 1 ms");
  return out;
}

}  // namespace

void HttpServer::start() {
  Impl& s = *impl_;
  std::lock_guard lifecycle(s.lifecycle_mutex);
  if (s.running) return;
  s.connections.set_limits(connection_limits(s.opts));
  beast::error_code ec;
  const std::string host = s.opts.host == "localhost" ? "127.0.0.1" : s.opts.host;
  const auto address = net::ip::make_address(host, ec);
  if (ec) throw HttpServerError("HTTP host \"" + s.opts.host + "\" is not an IP address (e.g. 127.0.0.1)");
  s.ioc = std::make_unique<net::io_context>(s.opts.io_threads);
  s.acceptor = std::make_unique<tcp::acceptor>(net::make_strand(*s.ioc));
  const tcp::endpoint endpoint{address, s.opts.port};
  const std::string where = s.opts.host + ":" + std::to_string(s.opts.port);
  s.acceptor->open(endpoint.protocol(), ec);
  if (!ec) s.acceptor->set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) s.acceptor->bind(endpoint, ec);
  if (ec == net::error::address_in_use) {
    s.acceptor.reset();
    s.ioc.reset();
    throw HttpServerError("cannot listen on " + where +
                          ": the port is already in use (is another tendrild running?); choose another port");
  }
  if (!ec) s.acceptor->listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    s.acceptor.reset();
    s.ioc.reset();
    throw HttpServerError("cannot listen on " + where + ": " + ec.message());
  }
  s.bound_port = s.acceptor->local_endpoint().port();
  s.allowed_origins = s.opts.allowed_origins;
  if (s.allowed_origins.empty()) {
    const std::string port = std::to_string(s.bound_port);
    const std::string scheme = s.opts.tls_certificate_file.empty() ? "http://" : "https://";
    s.allowed_origins.push_back(scheme + s.opts.host + ":" + port);
    // Same machine: a browser may say localhost or 127.0.0.1 (also when bound to all interfaces).
    if (address.is_loopback() || address.is_unspecified()) {
      s.allowed_origins.push_back(scheme + "localhost:" + port);
      s.allowed_origins.push_back(scheme + "127.0.0.1:" + port);
    }
  }
  if (!s.opts.openapi_file.empty()) {
    std::ifstream file(s.opts.openapi_file, std::ios::binary);
    std::ostringstream text;
    text << file.rdbuf();
    if (!file || json::parse(text.str(), nullptr, false).is_discarded()) {
      s.acceptor.reset();
      s.ioc.reset();
      throw HttpServerError("cannot read the OpenAPI document " + s.opts.openapi_file +
                            " (missing or not JSON); it is server/openapi/openapi.json in the source tree");
    }
    s.openapi_document = text.str();
  }
  if (!s.opts.tls_certificate_file.empty() || !s.opts.tls_private_key_file.empty()) {
    if (s.opts.tls_certificate_file.empty() || s.opts.tls_private_key_file.empty()) {
      s.acceptor.reset();
      s.ioc.reset();
      throw HttpServerError("TLS needs both a certificate and a private key (server.json \"tls\")");
    }
    auto context = std::make_unique<net::ssl::context>(net::ssl::context::tls_server);
    context->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                         net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 |
                         net::ssl::context::no_tlsv1_1);
    const auto load = [&](const std::string& what, const std::string& file, auto&& use) {
      beast::error_code tls_ec;
      use(file, tls_ec);
      if (tls_ec) {
        s.acceptor.reset();
        s.ioc.reset();
        throw HttpServerError("cannot use the TLS " + what + " " + file + ": " + tls_ec.message() +
                              " (expected a PEM file)");
      }
    };
    load("certificate", s.opts.tls_certificate_file, [&](const std::string& file, beast::error_code& e) {
      context->use_certificate_chain_file(file, e);
    });
    load("private key", s.opts.tls_private_key_file, [&](const std::string& file, beast::error_code& e) {
      context->use_private_key_file(file, net::ssl::context::pem, e);
    });
    s.tls_context = std::move(context);
  }
  // The takeover rule needs the longest servo command timeout of any robot.
  try {
    for (const auto& robot : s.api.robots()) {
      const auto timeout = robot.find("command_timeout_ms");
      if (timeout != robot.end() && timeout->is_number() && timeout->get<double>() > 0) {
        s.servo_window = std::max(s.servo_window, std::chrono::milliseconds(timeout->get<std::int64_t>()));
      }
    }
  } catch (const std::exception&) {
    // Keep the default window; robots() failing here shows up again on GET /robots.
  }
  s.refresh_channels();
  // Non-blocking at the OS level too: on_descriptors_exhausted() calls accept() on it directly.
  s.acceptor->native_non_blocking(true, ec);
  s.accept_timer = std::make_unique<net::steady_timer>(s.acceptor->get_executor());
  s.spare_descriptor = open_spare_descriptor();
  s.do_accept();
  s.stopping = false;
  // Registered under lifecycle_mutex; no source holds a callback yet (stop() clears them), so the
  // source's lock (taken around its callback, which then takes lifecycle_mutex) cannot be waiting here.
  for (const auto& source : s.opts.topic_sources) {
    if (!source) continue;
    source->set_ready_callback([&s] {
      {
        std::lock_guard lock(s.lifecycle_mutex);
        s.sources_ready = true;
      }
      s.publisher_wake.notify_all();
    });
  }
  // Below the I/O threads in priority: their work must never keep a thread from reading an e-stop.
  s.request_lane = std::make_unique<http::WorkLane>(
      http::WorkLane::Options{"requests", s.opts.request_threads, s.opts.request_queue, 5});
  s.upload_lane = std::make_unique<http::WorkLane>(
      http::WorkLane::Options{"uploads", s.opts.upload_threads, s.opts.upload_queue, 15});
  for (int i = 0; i < s.opts.io_threads; ++i) s.io_threads.emplace_back([&s] { s.run_io(); });
  if (s.opts.publish_rate_hz > 0) {
    s.publisher = std::thread([&s] {
      const auto period = std::chrono::duration_cast<SteadyClock::duration>(
          std::chrono::duration<double>(1.0 / s.opts.publish_rate_hz));
      auto next = SteadyClock::now();
      while (true) {
        bool only_sources = false;
        {
          std::unique_lock lock(s.lifecycle_mutex);
          s.publisher_wake.wait_until(lock, next, [&s] { return s.stopping || s.sources_ready; });
          if (s.stopping) return;
          // A source's new message (an image) goes out now; robot topics wait for their tick.
          only_sources = s.sources_ready && SteadyClock::now() < next;
          s.sources_ready = false;
        }
        s.publish_once(only_sources);
        if (only_sources) continue;
        next += period;
        const auto now = SteadyClock::now();
        if (next < now) next = now;  // after a stall, do not burst to catch up
      }
    });
  }
  s.running = true;
}

void HttpServer::stop() {
  Impl& s = *impl_;
  {
    std::lock_guard lifecycle(s.lifecycle_mutex);
    if (!s.running) return;
    s.running = false;
    s.stopping = true;
  }
  for (const auto& source : s.opts.topic_sources)
    if (source) source->set_ready_callback(nullptr);
  s.publisher_wake.notify_all();
  if (s.publisher.joinable()) s.publisher.join();
  net::post(s.acceptor->get_executor(), [&s] {
    beast::error_code ignored;
    s.acceptor->close(ignored);
  });
  for (auto& session : s.live_sessions()) {
    net::post(s.ioc->get_executor(), [session] { session->hard_close(); });
  }
  // The lanes first: a finished task posts its answer to a connection's strand, which needs the
  // io_context alive (stopped is fine). A task still running (an upload being parsed) is waited for.
  s.request_lane->stop();
  s.upload_lane->stop();
  s.ioc->stop();
  for (auto& thread : s.io_threads) thread.join();
  s.io_threads.clear();
  {
    std::lock_guard lock(s.ws_mutex);
    s.ws_sessions.clear();
  }
  s.accept_timer.reset();
  s.acceptor.reset();
  s.ioc.reset();  // destroys pending handlers and with them the sessions
  if (s.spare_descriptor >= 0) ::close(s.spare_descriptor);
  s.spare_descriptor = -1;
  s.request_lane.reset();
  s.upload_lane.reset();
}

unsigned short HttpServer::port() const { return impl_->bound_port; }
bool HttpServer::tls() const { return !impl_->opts.tls_certificate_file.empty(); }

std::string HttpServer::metrics() const { return impl_->metrics(); }
void HttpServer::publish_once() { impl_->publish_once(); }

std::vector<HttpServer::ConnectionStats> HttpServer::connection_stats() const {
  std::vector<ConnectionStats> result;
  for (const auto& session : impl_->live_sessions()) result.push_back(session->stats());
  return result;
}

}  // namespace tendril::server
