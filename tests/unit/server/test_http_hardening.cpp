// The HTTP edge under hostile input (issue "One unauthenticated request kills the server"): requests
// the parser must refuse with an answer, limits on every part of a request, exceptions contained per
// connection, and WebSocket clients that stop reading.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "http_test_support.hpp"

namespace tendril_test {
namespace {

// Status code of the first response in `raw` (0 when there is none).
int first_status(const std::string& raw) {
  if (raw.rfind("HTTP/1.", 0) != 0 || raw.size() < 12) return 0;
  return std::stoi(raw.substr(9, 3));
}

// The reproduction from the issue: a chunked GET whose trailer field value is 64 KiB - 2 bytes long.
std::string trailer_value_bomb(const std::string& method, const std::string& target) {
  return method + " " + target +
         " HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\nX: " + std::string(65534, 'a') +
         "\r\n\r\n";
}

class HttpHardeningTest : public HttpServerTest {
 protected:
  bool healthy() { return http_request(port_, bhttp::verb::get, "/api/v1/health").status == 200; }
  std::uint64_t metric(const std::string& name) {
    const std::string text = server_->metrics();
    const auto at = text.find("\n" + name + " ");
    if (at == std::string::npos) return ~std::uint64_t{0};
    return std::stoull(text.substr(at + name.size() + 2));
  }
  // Waits (at most 2 s) until a metric has a value; true when it did.
  bool metric_becomes(const std::string& name, std::uint64_t value) {
    for (int i = 0; i < 400; ++i) {
      if (metric(name) == value) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return false;
  }
};

// A client TCP connection at the socket level: it sends only what it is told to, so it can sit idle
// like the probe's connections, and it can come from another loopback address (Linux routes all of
// 127/8 to the loopback interface), which the server sees as another client machine.
class TestSocket {
 public:
  explicit TestSocket(unsigned short port, const char* from_address = nullptr)
      : fd_(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0)) {
    if (from_address != nullptr) {
      sockaddr_in local{};
      local.sin_family = AF_INET;
      ::inet_pton(AF_INET, from_address, &local.sin_addr);
      EXPECT_EQ(::bind(fd_, reinterpret_cast<const sockaddr*>(&local), sizeof local), 0);
    }
    sockaddr_in server{};
    server.sin_family = AF_INET;
    server.sin_port = htons(port);
    ::inet_pton(AF_INET, "127.0.0.1", &server.sin_addr);
    EXPECT_EQ(::connect(fd_, reinterpret_cast<const sockaddr*>(&server), sizeof server), 0);
  }
  ~TestSocket() { ::close(fd_); }
  TestSocket(const TestSocket&) = delete;
  TestSocket& operator=(const TestSocket&) = delete;

  void send(const std::string& bytes) { ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL); }
  // True when the server closed the connection within `wait` (what it wrote first is in received).
  bool closed_within(std::chrono::milliseconds wait) {
    const auto deadline = std::chrono::steady_clock::now() + wait;
    while (!closed_ && read_some(deadline)) {
    }
    return closed_;
  }
  // The next complete response (framed by its Content-Length), or "" when none came within `wait`.
  std::string response_within(std::chrono::milliseconds wait) {
    const auto deadline = std::chrono::steady_clock::now() + wait;
    while (true) {
      const auto header_end = received.find("\r\n\r\n");
      if (header_end != std::string::npos) {
        const auto length_at = received.find("Content-Length: ");
        const std::size_t length =
            length_at < header_end ? std::stoul(received.substr(length_at + 16)) : std::size_t{0};
        if (received.size() >= header_end + 4 + length) {
          std::string response = received.substr(0, header_end + 4 + length);
          received.erase(0, response.size());
          return response;
        }
      }
      if (closed_ || !read_some(deadline)) return {};
    }
  }
  std::string received;

 private:
  // Reads what arrives before `deadline`; false when nothing did.
  bool read_some(std::chrono::steady_clock::time_point deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    pollfd poll_fd{fd_, POLLIN, 0};
    if (left.count() <= 0 || ::poll(&poll_fd, 1, static_cast<int>(left.count())) <= 0) return false;
    char chunk[4096];
    const auto n = ::recv(fd_, chunk, sizeof chunk, 0);
    if (n <= 0) {
      closed_ = true;  // end of stream or reset
    } else {
      received.append(chunk, static_cast<std::size_t>(n));
    }
    return true;
  }

  int fd_;
  bool closed_ = false;
};

std::string authenticated_get(const std::string& target) {
  return "GET " + target + " HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + std::string(kToken) +
         "\r\n\r\n";
}

constexpr auto kUnauthenticatedConnections = "tendril_http_connections{state=\"unauthenticated\"}";
constexpr auto kAuthenticatedConnections = "tendril_http_connections{state=\"authenticated\"}";

TEST_F(HttpHardeningTest, OversizedTrailerValueIsRefusedAndTheServerLives) {
  start();
  const auto exchange = raw_exchange(port_, trailer_value_bomb("GET", "/"));
  // The trailer section does not fit the read buffer: refused with an answer, never read whole.
  EXPECT_EQ(first_status(exchange.received), 431) << exchange.received.substr(0, 200);
  EXPECT_NE(exchange.received.find("request_line_too_large"), std::string::npos);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, OversizedTrailerNameIsRefusedAndTheServerLives) {
  start();
  const std::string request =
      "GET /api/v1/health HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n" +
      std::string(65534, 'N') + ": v\r\n\r\n";
  const auto exchange = raw_exchange(port_, request);
  EXPECT_EQ(first_status(exchange.received), 431);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, AnyTrailerFieldIsRefusedWithItsReason) {
  start();
  const auto exchange = raw_exchange(
      port_,
      "GET /api/v1/health HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\nX-Small: 1\r\n\r\n");
  EXPECT_EQ(first_status(exchange.received), 400);
  EXPECT_NE(exchange.received.find("trailers_not_accepted"), std::string::npos);
  EXPECT_NE(exchange.received.find("Connection: close"), std::string::npos);
  EXPECT_EQ(metric("tendril_http_requests_refused_total{reason=\"trailers\"}"), 1u);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, HugeTrailerIsNotReadIntoMemory) {
  start();
  // 20,000 trailer fields of 1 KiB (20 MB) to the public /health: the server answers once the first
  // 32 KiB of trailer do not form a request, and stops reading; the rest is never buffered.
  std::string request = "GET /api/v1/health HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n";
  const std::string field = "X-Pad: " + std::string(1017, 'p') + "\r\n";
  request.reserve(request.size() + 20000 * field.size() + 2);
  for (int i = 0; i < 20000; ++i) request += field;
  request += "\r\n";
  const auto exchange = raw_exchange(port_, request);
  EXPECT_EQ(first_status(exchange.received), 431);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, OverflowingChunkSizeGets400NotASilentClose) {
  start();
  const auto exchange = raw_exchange(
      port_, "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + std::string(kToken) +
                 "\r\nTransfer-Encoding: chunked\r\n\r\nFFFFFFFFFFFFFFFFFFFFFF\r\n");
  EXPECT_EQ(first_status(exchange.received), 400) << exchange.received;
  EXPECT_NE(exchange.received.find("bad_chunk"), std::string::npos);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, LongChunkExtensionIsRefused) {
  start();
  const std::string request =
      "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + std::string(kToken) +
      "\r\nTransfer-Encoding: chunked\r\n\r\n2;x=" + std::string(1000, 'e') + "\r\n{}\r\n0\r\n\r\n";
  const auto exchange = raw_exchange(port_, request);
  EXPECT_EQ(first_status(exchange.received), 400);
  EXPECT_NE(exchange.received.find("bad_chunk"), std::string::npos);
}

TEST_F(HttpHardeningTest, ChunkedBodyWithinTheLimitStillWorks) {
  start();
  const std::string request =
      "POST /api/v1/robots/srmc/state_command HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
      std::string(kToken) +
      "\r\nTransfer-Encoding: chunked\r\n\r\nA;note=ok\r\n{\"command\"\r\nA\r\n:\"enable\"}\r\n0\r\n\r\n";
  // The lease of the bearer token holds on every connection, the raw one too.
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer()).status, 200);
  const auto exchange = raw_exchange(port_, request);
  // Parsed, reassembled from its chunks and executed.
  EXPECT_EQ(first_status(exchange.received), 200) << exchange.received;
  EXPECT_EQ(api_.state_commands, 1);
}

TEST_F(HttpHardeningTest, PipelinedRequestsAreAnsweredInOrder) {
  start();
  const std::string one = "GET /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n";
  const std::string two = "GET /api/v1/robots HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                          std::string(kToken) + "\r\nConnection: close\r\n\r\n";
  const auto exchange = raw_exchange(port_, one + two);
  const auto second = exchange.received.find("HTTP/1.1 ", 1);
  ASSERT_NE(second, std::string::npos) << exchange.received;
  EXPECT_EQ(first_status(exchange.received), 200);
  EXPECT_EQ(first_status(exchange.received.substr(second)), 200);
  EXPECT_NE(exchange.received.find("\"srmc\""), std::string::npos);
}

TEST_F(HttpHardeningTest, TheReproductionOnEveryRouteAndMethodLeavesTheServerRunning) {
  start();
  int requests = 0;
  for (const auto& route : HttpServer::api_routes()) {
    std::string target = route.path;
    for (const auto& [from, to] : {std::pair<std::string, std::string>{"{robot}", "srmc"}, {"{id}", "j1"}}) {
      if (const auto at = target.find(from); at != std::string::npos) target.replace(at, from.size(), to);
    }
    for (const std::string method : {"GET", "POST", "PUT", "DELETE", "PATCH"}) {
      const auto exchange = raw_exchange(port_, trailer_value_bomb(method, target));
      EXPECT_GE(first_status(exchange.received), 400) << method << " " << target;
      ++requests;
    }
  }
  for (const std::string target : {"/metrics", "/ws", "/index.html", "/no/such/file"}) {
    raw_exchange(port_, trailer_value_bomb("GET", target));
    ++requests;
  }
  EXPECT_GT(requests, 100);
  EXPECT_TRUE(healthy());
  EXPECT_EQ(metric("tendril_http_connection_exceptions_total"), 0u);
}

// A ControlApi that throws from a getter: a std::exception becomes 500, anything else closes only
// that connection; the server, its other connections and the robot's commands go on.
class ThrowingApi : public FakeControlApi {
 public:
  std::atomic<int> mode{0};  // 0: no throw, 1: std::runtime_error, 2: an int
  ApiResult measured_js(const std::string& robot) const override {
    if (mode == 1) throw std::runtime_error("measured_js failed");
    if (mode == 2) throw 42;  // not a std::exception: before the fix this reached std::terminate
    return FakeControlApi::measured_js(robot);
  }
};

TEST_F(HttpHardeningTest, AnExceptionInAHandlerClosesOnlyThatConnection) {
  ThrowingApi api;
  std::vector<std::string> log;
  std::mutex log_mutex;
  options_.log = [&](const std::string& line) {
    std::lock_guard lock(log_mutex);
    log.push_back(line);
  };
  server_ = std::make_unique<HttpServer>(api, options_);
  server_->start();
  port_ = server_->port();
  WsClient watcher;  // another connection, open throughout
  ASSERT_EQ(watcher.connect(port_, ws_target()), 101);
  watcher.read_greeting();

  api.mode = 1;
  expect_error_shape(http_request(port_, bhttp::verb::get, "/api/v1/robots/srmc/measured_js", "", bearer()),
                     500, "internal_error");
  api.mode = 2;
  const auto exchange = raw_exchange(port_,
                                     "GET /api/v1/robots/srmc/measured_js HTTP/1.1\r\nHost: x\r\n"
                                     "Authorization: Bearer " +
                                         std::string(kToken) + "\r\n\r\n");
  EXPECT_TRUE(exchange.received.empty()) << "the connection is closed without an answer";
  api.mode = 0;
  EXPECT_TRUE(healthy());
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("script")).status, 200);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                         R"({"command":"enable"})", bearer("script"))
                .status,
            200);
  EXPECT_EQ(api.state_commands, 1);
  EXPECT_EQ(metric("tendril_http_connection_exceptions_total"), 1u);
  {
    std::lock_guard lock(log_mutex);
    ASSERT_EQ(log.size(), 1u);
    EXPECT_NE(log[0].find("not a std::exception"), std::string::npos) << log[0];
  }
  // The WebSocket connection opened before is still served.
  watcher.send_text(R"({"op":"getParameters","parameterNames":[],"id":"x"})");
  EXPECT_FALSE(watcher.read_op("parameterValues").is_null());
  watcher.close();
  server_.reset();  // before `api` goes
}

TEST_F(HttpHardeningTest, AWebSocketClientThatStopsReadingIsClosedAndCounted) {
  api_.payload_padding = 256 * 1024;  // large frames fill the socket buffers at once
  options_.ws_stalled_write_timeout = std::chrono::milliseconds(300);
  start();
  WsClient stalled;
  ASSERT_EQ(stalled.connect(port_, ws_target()), 101);
  const auto greeting = stalled.read_greeting();
  const std::uint32_t channel = greeting[1]["channels"][0]["id"];
  stalled.send_text(
      json{{"op", "subscribe"}, {"subscriptions", {{{"id", 1}, {"channelId", channel}}}}}.dump());
  for (int i = 0; i < 400 && (server_->connection_stats().empty() ||
                              server_->connection_stats().at(0).subscriptions == 0);
       ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  // The client reads nothing more. Publishing goes on (as the publisher thread would, at 50 Hz) until
  // the server gives up on it; a bounded number of rounds, each a step of simulated publishing.
  for (int i = 0; i < 2000 && !server_->connection_stats().empty(); ++i) {
    server_->publish_once();
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_TRUE(server_->connection_stats().empty()) << "the stalled connection is still open";
  EXPECT_EQ(metric("tendril_ws_closed_for_backlog_total"), 1u);
  // A reading client is not affected.
  WsClient reader;
  ASSERT_EQ(reader.connect(port_, ws_target()), 101);
  reader.read_greeting();
}

// Issue 30: about 20,000 idle unauthenticated connections used up the descriptors and a new e-stop
// client got no answer. Now they form a bounded pool, and a new connection closes the oldest of them.
TEST_F(HttpHardeningTest, AFullPoolOfIdleConnectionsCannotKeepANewEstopOut) {
  options_.max_connections = 12;
  options_.max_unauthenticated_connections = 8;
  start();
  WsClient console;  // an operator's console, authenticated: never closed to make room
  ASSERT_EQ(console.connect(port_, ws_target()), 101);
  console.read_greeting();
  std::vector<std::unique_ptr<TestSocket>> idle;
  for (int i = 0; i < 8; ++i) {
    idle.push_back(std::make_unique<TestSocket>(port_));
    ASSERT_TRUE(metric_becomes(kUnauthenticatedConnections, i + 1u)) << "connection " << i;
  }
  const auto estop = http_request(port_, bhttp::verb::post, "/api/v1/estop", "", bearer());
  EXPECT_EQ(estop.status, 200) << estop.raw.body();
  EXPECT_EQ(api_.estops, 1);
  EXPECT_TRUE(idle.front()->closed_within(std::chrono::milliseconds(2000))) << "the oldest made room";
  EXPECT_FALSE(idle.back()->closed_within(std::chrono::milliseconds(50)));
  EXPECT_EQ(metric("tendril_http_connections_evicted_total"), 1u);
  console.send_text(R"({"op":"getParameters","parameterNames":[],"id":"x"})");
  EXPECT_FALSE(console.read_op("parameterValues").is_null());
}

TEST_F(HttpHardeningTest, AnAddressAtItsLimitPushesOutOnlyItsOwnConnections) {
  options_.max_unauthenticated_per_address = 3;
  start();
  TestSocket other_machine(port_, "127.0.0.2");
  std::vector<std::unique_ptr<TestSocket>> mine;
  for (int i = 0; i < 3; ++i) mine.push_back(std::make_unique<TestSocket>(port_, "127.0.0.1"));
  ASSERT_TRUE(metric_becomes(kUnauthenticatedConnections, 4u));
  TestSocket fourth(port_, "127.0.0.1");
  fourth.send("GET /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(fourth.response_within(std::chrono::milliseconds(2000)).rfind("HTTP/1.1 200", 0), 0u);
  EXPECT_TRUE(mine.front()->closed_within(std::chrono::milliseconds(2000)));
  EXPECT_FALSE(mine.back()->closed_within(std::chrono::milliseconds(50)));
  EXPECT_FALSE(other_machine.closed_within(std::chrono::milliseconds(50)));
}

TEST_F(HttpHardeningTest, AtTheTotalLimitANewConnectionIsRefusedAndOperatorsStay) {
  options_.max_connections = 3;
  options_.max_unauthenticated_connections = 2;
  start();
  std::vector<std::unique_ptr<TestSocket>> operators;
  for (int i = 0; i < 3; ++i) {
    operators.push_back(std::make_unique<TestSocket>(port_));
    operators.back()->send(authenticated_get("/api/v1/robots"));
    ASSERT_EQ(operators.back()->response_within(std::chrono::milliseconds(2000)).rfind("HTTP/1.1 200", 0),
              0u);
  }
  ASSERT_TRUE(metric_becomes(kAuthenticatedConnections, 3u));
  TestSocket late(port_);
  EXPECT_TRUE(late.closed_within(std::chrono::milliseconds(2000)));
  EXPECT_TRUE(late.received.empty()) << late.received;
  EXPECT_EQ(metric("tendril_http_connections_refused_total{limit=\"total\"}"), 1u);
  for (auto& keeper : operators) {
    keeper->send(authenticated_get("/api/v1/robots"));
    EXPECT_EQ(keeper->response_within(std::chrono::milliseconds(2000)).rfind("HTTP/1.1 200", 0), 0u);
  }
}

TEST_F(HttpHardeningTest, UnauthenticatedConnectionsMustSendTheirHeaderInTime) {
  options_.handshake_timeout = std::chrono::seconds(1);
  start();
  TestSocket silent(port_);
  TestSocket slow(port_);
  slow.send("GET /api/v1/health HTTP/1.1\r\nHost: x\r\n");  // a header that never ends
  TestSocket keeper(port_);
  keeper.send(authenticated_get("/api/v1/robots"));
  ASSERT_EQ(keeper.response_within(std::chrono::milliseconds(1000)).rfind("HTTP/1.1 200", 0), 0u);
  const auto started = std::chrono::steady_clock::now();
  EXPECT_TRUE(silent.closed_within(std::chrono::milliseconds(1800)));
  EXPECT_TRUE(slow.closed_within(std::chrono::milliseconds(500)));
  EXPECT_LT(std::chrono::steady_clock::now() - started, std::chrono::milliseconds(1800));
  // An authenticated connection idles longer (idle_timeout, 60 s) and is still served.
  std::this_thread::sleep_until(started + std::chrono::milliseconds(1300));
  keeper.send(authenticated_get("/api/v1/robots"));
  EXPECT_EQ(keeper.response_within(std::chrono::milliseconds(1000)).rfind("HTTP/1.1 200", 0), 0u);
}

// RFC 9112 §6.3: a Transfer-Encoding whose final coding is not chunked leaves the body length unknown
// (a proxy in front may frame it otherwise): 400 and close. With chunked last it is read as usual.
TEST_F(HttpHardeningTest, TransferEncodingMustEndInChunked) {
  start();
  for (const std::string fields : {"Transfer-Encoding: gzip\r\n", "Transfer-Encoding: chunked, gzip\r\n",
                                   "Transfer-Encoding: gzip\r\nContent-Length: 2\r\n",
                                   "Transfer-Encoding: chunked\r\nTransfer-Encoding: gzip\r\n"}) {
    const auto exchange =
        raw_exchange(port_, "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                                std::string(kToken) + "\r\n" + fields + "\r\n{}");
    EXPECT_EQ(first_status(exchange.received), 400) << fields << exchange.received;
    EXPECT_NE(exchange.received.find("bad_transfer_encoding"), std::string::npos) << fields;
    EXPECT_NE(exchange.received.find("Connection: close"), std::string::npos) << fields;
  }
  EXPECT_EQ(metric("tendril_http_requests_refused_total{reason=\"transfer_encoding\"}"), 4u);
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer()).status, 200);
  const auto accepted = raw_exchange(
      port_, "POST /api/v1/robots/srmc/state_command HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                 std::string(kToken) +
                 "\r\nTransfer-Encoding: gzip, chunked\r\n\r\n14\r\n{\"command\":\"enable\"}\r\n0\r\n\r\n");
  EXPECT_EQ(first_status(accepted.received), 200) << accepted.received;
  EXPECT_EQ(api_.state_commands, 1);
}

TEST_F(HttpHardeningTest, EveryOriginHeaderIsChecked) {
  start();
  const std::string allowed = "Origin: http://127.0.0.1:" + std::to_string(port_) + "\r\n";
  const std::string foreign = "Origin: http://evil.example\r\n";
  for (const std::string origins : {allowed + foreign, foreign + allowed, allowed + allowed}) {
    const auto rest = raw_exchange(port_, "GET /api/v1/robots HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                                              std::string(kToken) + "\r\n" + origins + "\r\n");
    EXPECT_EQ(first_status(rest.received), 403) << origins << rest.received;
    const auto upgrade =
        raw_exchange(port_, "GET " + ws_target() +
                                " HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                                "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
                                "Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n" +
                                origins + "\r\n");
    EXPECT_EQ(first_status(upgrade.received), 403) << origins << upgrade.received;
  }
  const auto one = raw_exchange(port_, "GET /api/v1/robots HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " +
                                           std::string(kToken) + "\r\n" + allowed + "\r\n");
  EXPECT_EQ(first_status(one.received), 200) << one.received;
}

TEST(TakeoverOffers, AtTheCapTheOldestOfferIsWithdrawn) {
  using tendril::server::http::LeaseManager;
  LeaseManager lease(std::chrono::seconds(30));
  const auto now = LeaseManager::Clock::now();
  ASSERT_TRUE(lease.acquire("bearer", "holder", "token", now));
  // The first offer's token sorts after every later one.
  lease.issue_takeover_token("lease:first", "zz-first", now);
  for (int i = 1; i < 64; ++i) {
    lease.issue_takeover_token("lease:" + std::to_string(i), "aa-" + std::to_string(100 + i),
                               now + std::chrono::milliseconds(i));
  }
  const auto later = now + std::chrono::milliseconds(100);
  ASSERT_TRUE(lease.takeover_token_valid("lease:first", "zz-first", later));
  lease.issue_takeover_token("lease:late", "mm-late", later);  // the 65th
  EXPECT_FALSE(lease.takeover_token_valid("lease:first", "zz-first", later)) << "the oldest goes";
  EXPECT_TRUE(lease.takeover_token_valid("lease:1", "aa-101", later));
  EXPECT_TRUE(lease.takeover_token_valid("lease:late", "mm-late", later));
}

// Opening pages with ?token= made new cookie sessions that pushed out the oldest: the console's.
std::string page_cookie(unsigned short port) {
  const Reply page = http_request(port, bhttp::verb::get, std::string("/?token=") + kToken);
  const std::string set_cookie(page.raw[bhttp::field::set_cookie]);
  return set_cookie.substr(0, set_cookie.find(';'));
}

TEST_F(HttpHardeningTest, TheConsoleSessionSurvivesAFloodOfNewSessions) {
  options_.max_sessions = 4;
  start();
  const std::string console_cookie = page_cookie(port_);
  ASSERT_FALSE(console_cookie.empty());
  WsClient console;
  ASSERT_EQ(console.connect(port_, "/ws", {{"Cookie", console_cookie}}), 101);
  console.read_greeting();
  int refused = 0;
  for (int i = 0; i < 10; ++i) {
    const Reply page = http_request(port_, bhttp::verb::get, std::string("/?token=") + kToken);
    if (page.status == 503) {
      ++refused;
      expect_error_shape(page, 503, "too_many_sessions");
    }
  }
  EXPECT_EQ(refused, 7);  // 3 more fit; every session was used just now
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Cookie", console_cookie}}).status,
            200);
}

TEST_F(HttpHardeningTest, AnIdleSessionMakesRoomButNotOneWithAWebSocket) {
  options_.max_sessions = 2;
  options_.lease_timeout = std::chrono::milliseconds(300);
  start();
  const std::string console_cookie = page_cookie(port_);
  WsClient console;
  ASSERT_EQ(console.connect(port_, "/ws", {{"Cookie", console_cookie}}), 101);
  console.read_greeting();
  const std::string idle_cookie = page_cookie(port_);
  ASSERT_FALSE(idle_cookie.empty());
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  EXPECT_FALSE(page_cookie(port_).empty()) << "the idle session made room";
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Cookie", idle_cookie}}).status,
            401);
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Cookie", console_cookie}}).status,
            200);
  EXPECT_EQ(http_request(port_, bhttp::verb::get, std::string("/?token=") + kToken).status, 503);
}

}  // namespace
}  // namespace tendril_test
