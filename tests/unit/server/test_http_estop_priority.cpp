// The e-stop waits for no one (issue "The e-stop must not wait for anyone"): requests' work runs off
// the I/O threads, the e-stop is latched as soon as its header is read, and who may not send a body
// is refused before it is read or parsed. Each test fails on a front end that routes on the I/O
// threads or parses before it checks.
#include <array>
#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/write.hpp>

#include "http_test_support.hpp"

namespace tendril_test {
namespace {

namespace net = boost::asio;
using tcp = net::ip::tcp;
using Clock = std::chrono::steady_clock;

// A robot whose state commands take `slow` each (a handler that computes for a long time).
class SlowControlApi : public FakeControlApi {
 public:
  std::chrono::milliseconds slow{1500};
  std::atomic<int> in_progress{0};
  ApiResult state_command(const std::string& robot, const json& body) override {
    ++in_progress;
    std::this_thread::sleep_for(slow);
    --in_progress;
    return FakeControlApi::state_command(robot, body);
  }
};

class EstopPriorityTest : public HttpServerTest {
 protected:
  void start_slow() {
    server_ = std::make_unique<HttpServer>(slow_api_, options_);
    server_->start();
    port_ = server_->port();
  }
  // Starts `n` slow commands, each on its own connection, and waits until `running` of them run.
  void occupy(int n, int running) {
    for (int i = 0; i < n; ++i) {
      clients_.emplace_back([this] {
        http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", R"({"command":"enable"})",
                     lease_.headers());
      });
    }
    const auto deadline = Clock::now() + std::chrono::seconds(5);
    while (slow_api_.in_progress < running && Clock::now() < deadline)
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    ASSERT_GE(slow_api_.in_progress.load(), running);
  }
  void TearDown() override {
    for (auto& client : clients_) client.join();
    HttpServerTest::TearDown();
  }

  SlowControlApi slow_api_;
  ScriptClient lease_{"slow-script"};
  std::vector<std::thread> clients_;
};

TEST_F(EstopPriorityTest, AnEstopIsAnsweredAtOnceWhileEveryRequestWorkerIsBusy) {
  start_slow();
  ASSERT_EQ(lease_.take_lease(port_).status, 200);
  // More slow commands than there are I/O threads and request workers together.
  occupy(4, options_.request_threads);
  const auto sent = Clock::now();
  const Reply reply = http_request(port_, bhttp::verb::post, "/api/v1/estop", "", bearer("viewer-console"));
  const auto waited = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - sent);
  EXPECT_EQ(reply.status, 200) << reply.raw.body();
  EXPECT_EQ(slow_api_.estops.load(), 1);
  // The slow commands take 1.5 s each; an e-stop routed behind them would wait at least that long.
  EXPECT_LT(waited.count(), 500) << "the e-stop waited " << waited.count() << " ms behind slow requests";
  std::cout << "e-stop answered in " << waited.count() << " ms beside " << slow_api_.in_progress.load()
            << " running slow commands\n";
}

TEST_F(EstopPriorityTest, TheEstopIsLatchedWhenItsHeaderArrivesBeforeItsBody) {
  start();
  net::io_context ioc;
  tcp::socket socket(ioc);
  socket.connect({net::ip::make_address("127.0.0.1"), port_});
  // A body is announced but never comes: the e-stop must not wait for it.
  const std::string header = std::string("POST /api/v1/estop HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer ") +
                             kToken + "\r\nContent-Length: 10\r\n\r\n";
  net::write(socket, net::buffer(header));
  const auto deadline = Clock::now() + std::chrono::milliseconds(1000);
  while (api_.estops == 0 && Clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  EXPECT_EQ(api_.estops.load(), 1) << "the e-stop waited for its body";
  // Then the body arrives and the e-stop is answered.
  net::write(socket, net::buffer(std::string("{}        ")));
  std::string received;
  std::array<char, 4096> chunk{};
  boost::system::error_code ec;
  while (received.find("\r\n\r\n") == std::string::npos || received.find("estop") == std::string::npos) {
    const std::size_t n = socket.read_some(net::buffer(chunk), ec);
    if (ec) break;
    received.append(chunk.data(), n);
  }
  EXPECT_EQ(received.rfind("HTTP/1.1 200", 0), 0u) << received;
  EXPECT_EQ(api_.estops.load(), 1);
}

TEST_F(EstopPriorityTest, AViewersBodyIsRefusedBeforeItIsParsed) {
  start();
  auto viewer = bearer("watcher");
  viewer["X-Tendril-Role"] = "viewer";
  // Not JSON at all: parsed first, it would be a 400; the role is checked first, so it is a 403.
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", "[[[[not json", viewer),
      403, "forbidden_role");
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease", "[[[[not json", viewer), 403,
                     "forbidden_role");
  // Declared over the body limit: refused for the role, its bytes never read.
  const std::string big(options_.max_body_bytes * 4, '[');
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/mode", big, viewer), 403,
                     "forbidden_role");
  EXPECT_EQ(api_.state_commands.load(), 0);
  // A viewer's e-stop still works, whatever its body.
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "[[[[not json", viewer).status, 200);
  EXPECT_EQ(api_.estops.load(), 1);
}

TEST_F(EstopPriorityTest, ABodyWithoutATokenIsRefusedBeforeItIsRead) {
  start();
  // A chunked body that never ends: without a token it is not read at all.
  const auto exchange =
      raw_exchange(port_,
                   "POST /api/v1/lease HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
                   "\r\nFFFFFFFFFFFFFFFFFFFFFF\r\n");
  EXPECT_EQ(exchange.received.rfind("HTTP/1.1 401", 0), 0u) << exchange.received;
  EXPECT_NE(exchange.received.find("missing_token"), std::string::npos) << exchange.received;
}

TEST_F(EstopPriorityTest, ACommandWithoutTheLeaseIsRefusedBeforeItsBodyIsParsed) {
  start();
  ScriptClient holder("holder"), other("other");
  ASSERT_EQ(holder.take_lease(port_).status, 200);
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  "[[[[not json", other.headers()),
                     409, "lease_held");
  // The holder's own malformed body is still answered as malformed.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  "[[[[not json", holder.headers()),
                     400, "malformed_json");
}

TEST_F(EstopPriorityTest, AFullRequestQueueAnswersBusyAndTheEstopStillWorks) {
  options_.request_threads = 1;
  options_.request_queue = 1;
  // Long enough that the waiting command is still queued when the probe comes, on a loaded machine too.
  slow_api_.slow = std::chrono::milliseconds(4000);
  start_slow();
  ASSERT_EQ(lease_.take_lease(port_).status, 200);
  occupy(1, 1);  // the one worker is busy
  occupy(1, 1);  // and one request waits
  // Give the waiting one time to be queued (its worker stays busy for 4 s).
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));
  const Reply busy = http_request(port_, bhttp::verb::get, "/api/v1/robots/srmc/measured_js", "", bearer());
  expect_error_shape(busy, 503, "server_busy");
  EXPECT_EQ(busy.raw[bhttp::field::retry_after], "1");
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "", bearer()).status, 200);
  EXPECT_EQ(slow_api_.estops.load(), 1);
}

}  // namespace
}  // namespace tendril_test
