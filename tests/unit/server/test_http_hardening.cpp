// The HTTP edge under hostile input (issue "One unauthenticated request kills the server"): requests
// the parser must refuse with an answer, limits on every part of a request, exceptions contained per
// connection, and WebSocket clients that stop reading.
#include <chrono>
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
};

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
  const auto exchange = raw_exchange(port_,
                                     "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: "
                                     "chunked\r\n\r\nFFFFFFFFFFFFFFFFFFFFFF\r\n");
  EXPECT_EQ(first_status(exchange.received), 400) << exchange.received;
  EXPECT_NE(exchange.received.find("bad_chunk"), std::string::npos);
  EXPECT_TRUE(healthy());
}

TEST_F(HttpHardeningTest, LongChunkExtensionIsRefused) {
  start();
  const std::string request =
      "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n2;x=" +
      std::string(1000, 'e') + "\r\n{}\r\n0\r\n\r\n";
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

}  // namespace
}  // namespace tendril_test
