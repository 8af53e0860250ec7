// HttpServer: the listener, the I/O threads and the publisher thread of the REST + WebSocket front end
// (Boost.Beast advanced-server pattern: one port, upgrade on /ws, one strand per connection). The
// connections, routes and protocol live in the files listed in front_end.hpp. No code here runs in
// the real-time path.
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

void HttpServer::Impl::do_accept() {
  acceptor->async_accept(net::make_strand(*ioc), [this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor->is_open()) return;
    if (!ec) {
      beast::error_code ignored;
      socket.set_option(tcp::no_delay(true), ignored);  // small state messages should not wait for Nagle
      try {
        if (tls_context) {
          start_tls_http_session(std::move(socket), *this);
        } else {
          start_plain_http_session(std::move(socket), *this);
        }
      } catch (const std::exception& e) {
        connection_failed(0, "accept", e.what());
      }
    }
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

void HttpServer::start() {
  Impl& s = *impl_;
  std::lock_guard lifecycle(s.lifecycle_mutex);
  if (s.running) return;
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
  s.ioc->stop();
  for (auto& thread : s.io_threads) thread.join();
  s.io_threads.clear();
  {
    std::lock_guard lock(s.ws_mutex);
    s.ws_sessions.clear();
  }
  s.acceptor.reset();
  s.ioc.reset();  // destroys pending handlers and with them the sessions
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
