// Shared by the HTTP front-end tests: FakeControlApi (a test double of the robot runtime with one robot
// "srmc"), blocking HTTP and WebSocket clients over loopback, raw-byte exchanges, and the fixture that
// starts an HttpServer on a free port. The clients are compiled once, in http_test_support.cpp.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <boost/beast/http/verb.hpp>
#include <nlohmann/json.hpp>

#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/server/http/http_server.hpp"
#include "tendril/server/http/lease.hpp"

namespace tendril_test {

namespace bhttp = boost::beast::http;
using nlohmann::json;
using tendril::server::ApiResult;
using tendril::server::HttpOptions;
using tendril::server::HttpServer;
namespace fg = tendril::server::http::foxglove;

inline constexpr const char* kToken = "test-token-0123456789";

class FakeControlApi : public tendril::server::ControlApi {
 public:
  std::atomic<int> state_commands{0}, estops{0}, estop_resets{0}, servo_commands{0}, operator_lost_calls{0};
  std::atomic<bool> topics_change{true};
  std::atomic<std::size_t> payload_padding{0};
  mutable std::atomic<std::uint64_t> joint_version{0};

  json robots() const override { return json::array({{{"name", "srmc"}, {"kind", "test"}}}); }
  bool has_robot(const std::string& robot) const override { return robot == "srmc"; }
  ApiResult measured_js(const std::string&) const override {
    return ApiResult::success({{"name", {"j1"}}, {"position", {0.5}}});
  }
  ApiResult setpoint_js(const std::string&) const override {
    return ApiResult::success({{"position", {0.0}}});
  }
  ApiResult measured_cp(const std::string&) const override { return ApiResult::success({{"frame", "base"}}); }
  ApiResult shape(const std::string&) const override {
    return ApiResult::success({{"points", json::array()}});
  }
  ApiResult operating_state(const std::string&) const override {
    return ApiResult::success({{"state", "ENABLED"}});
  }
  ApiResult state_command(const std::string&, const json& body) override {
    if (!body.contains("command")) return ApiResult::error(400, "missing_field", "command is required");
    ++state_commands;
    return ApiResult::success({{"state", "ENABLED"}});
  }
  ApiResult mode(const std::string&, const json&) override { return ApiResult::success(json::object()); }
  ApiResult move_jp(const std::string&, const json&) override {
    return ApiResult::success({{"duration_s", 1.0}}, 202);
  }
  ApiResult servo_jv(const std::string&, const json&) override {
    ++servo_commands;
    return ApiResult::success(json::object());
  }
  ApiResult estop() override {
    ++estops;
    return ApiResult::success({{"estop", true}});
  }
  ApiResult estop_from(const std::string& actor) override {
    {
      std::lock_guard lock(actor_mutex);
      estop_actor = actor;
    }
    return estop();
  }
  std::string last_estop_actor() const {
    std::lock_guard lock(actor_mutex);
    return estop_actor;
  }
  mutable std::mutex actor_mutex;
  std::string estop_actor;  // guarded by actor_mutex
  ApiResult estop_reset() override {
    ++estop_resets;
    return ApiResult::success({{"estop", false}});
  }
  json faults(std::size_t) const override {
    std::lock_guard lock(mutex);
    return fault_events;
  }
  // One writable parameter "/srmc/j1/upper" in [0, 10] (configured 10) and one read-only.
  json parameters() const override {
    std::lock_guard lock(mutex);
    return json::array({{{"name", "/srmc/j1/upper"}, {"value", upper}, {"type", "float64"}},
                        {{"name", "/srmc/j1/configured_upper"}, {"value", 10.0}, {"type", "float64"}}});
  }
  ApiResult set_parameters(const json& list) override {
    std::lock_guard lock(mutex);
    if (!list.is_array() || list.size() != 1 || list[0]["name"] != "/srmc/j1/upper")
      return ApiResult::error(404, "unknown_parameter", "only /srmc/j1/upper is writable here");
    const double value = list[0].value("value", 10.0);
    if (value > 10.0 || value <= 0.0)
      return ApiResult::error(422, "out_of_range", "upper must be in (0, 10]");
    upper = value;
    ++parameter_sets;
    return ApiResult::success(
        json::array({{{"name", "/srmc/j1/upper"}, {"value", upper}, {"type", "float64"}}}));
  }
  mutable std::mutex mutex;
  json fault_events = json::array();  // newest first, as RobotRuntime::faults
  double upper = 10.0;
  std::atomic<int> parameter_sets{0};
  std::string metrics() const override { return "fake_control_loop_overruns_total 0\n"; }
  std::vector<std::string> topics() const override { return {"/srmc/joint_states", "/srmc/operating_state"}; }
  std::optional<json> topic_message(const std::string& topic, std::uint64_t since,
                                    std::uint64_t& version) const override {
    if (topic != "/srmc/joint_states") return std::nullopt;
    if (topics_change) ++joint_version;
    if (joint_version == since) return std::nullopt;
    version = joint_version;
    return json{{"position", {static_cast<double>(joint_version.load())}},
                {"padding", std::string(payload_padding.load(), 'x')}};
  }
  void operator_lost(const std::string& robot) override {
    (void)robot;
    ++operator_lost_calls;
  }
};

struct Reply {
  int status = 0;
  bhttp::response<bhttp::string_body> raw;
  json body() const { return json::parse(raw.body(), nullptr, false); }
};

Reply http_request(unsigned short port, bhttp::verb verb, const std::string& target,
                   const std::string& body = "", const std::map<std::string, std::string>& headers = {});

// Sends `bytes` as they are on a new connection, then reads until the server closes it (or `max_read`
// bytes arrived) and returns what it wrote. A send the server cuts short (it refused the request) is
// not an error: `sent_all` says whether every byte went out.
struct RawExchange {
  std::string received;
  bool sent_all = false;
};
RawExchange raw_exchange(unsigned short port, const std::string& bytes, std::size_t max_read = 1 << 20);

inline std::map<std::string, std::string> bearer(const std::string& client = "") {
  std::map<std::string, std::string> headers{{"Authorization", std::string("Bearer ") + kToken}};
  if (!client.empty()) headers["X-Tendril-Client"] = client;
  return headers;
}

// A script that wants a lease of its own, as the README shows: the bearer token, a name
// (X-Tendril-Client, a label only) and X-Tendril-Lease with the token of its last granted
// POST /api/v1/lease ("new" until then, which asks for a lease bound to its token alone).
struct ScriptClient {
  explicit ScriptClient(std::string client_name) : name(std::move(client_name)) {}
  std::string name;
  std::string lease_token = "new";
  std::map<std::string, std::string> headers() const {
    auto h = bearer(name);
    h["X-Tendril-Lease"] = lease_token;
    return h;
  }
  // POST /api/v1/lease (body: e.g. a takeover token); keeps the granted token.
  Reply take_lease(unsigned short port, const std::string& body = "") {
    Reply reply = http_request(port, bhttp::verb::post, "/api/v1/lease", body, headers());
    if (reply.status == 200) lease_token = reply.body().value("lease_token", std::string());
    return reply;
  }
};

inline void expect_error_shape(const Reply& reply, int status, const std::string& code) {
  EXPECT_EQ(reply.status, status) << reply.raw.body();
  const json body = reply.body();
  ASSERT_TRUE(body.is_object()) << reply.raw.body();
  EXPECT_EQ(body["error"]["code"], code) << reply.raw.body();
  EXPECT_TRUE(body["error"]["message"].is_string() && !body["error"]["message"].get<std::string>().empty());
}

// A blocking Foxglove WebSocket client.
class WsClient {
 public:
  WsClient();
  ~WsClient();
  WsClient(const WsClient&) = delete;
  WsClient& operator=(const WsClient&) = delete;
  // Returns the handshake response status (101 on success).
  int connect(unsigned short port, const std::string& target,
              const std::map<std::string, std::string>& headers = {}, bool offer_subprotocol = true);
  // A header of the handshake response ("" when absent).
  std::string response_header(const std::string& name) const;
  // Next message; `binary` tells which kind it was. Returns false when the connection ended.
  bool read(std::string& message, bool& binary);
  json read_json();
  // Reads until a JSON message with this op arrives (skipping others).
  json read_op(const std::string& op);
  std::string read_binary();
  void send_text(const std::string& text);
  void send_binary(const std::string& data);
  void close();
  // Reads the greeting (serverInfo, advertise, advertiseServices) and returns the three messages.
  std::vector<json> read_greeting() { return {read_json(), read_json(), read_json()}; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

class HttpServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("tendril-http-test-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_ / "web" / "js");
    std::filesystem::create_directories(dir_ / "three");
    std::ofstream(dir_ / "web" / "index.html") << "<html>console</html>";
    std::ofstream(dir_ / "web" / "js" / "app.js") << "console.log(1)";
    std::ofstream(dir_ / "three" / "three.module.js") << "export const REVISION = '1';";
    std::ofstream(dir_ / "secret.txt") << "TOP-SECRET";
    options_.port = 0;
    options_.token = kToken;
    options_.web_root = (dir_ / "web").string();
    options_.static_mounts["/vendor/three/"] = (dir_ / "three").string();
    options_.publish_rate_hz = 0;  // tests step publishing with publish_once()
    options_.max_body_bytes = 1024;
  }
  void TearDown() override {
    if (server_) server_->stop();
    std::error_code ignored;
    std::filesystem::remove_all(dir_, ignored);
  }
  void start() {
    server_ = std::make_unique<HttpServer>(api_, options_);
    server_->start();
    port_ = server_->port();
  }
  std::string ws_target() const { return std::string("/ws?token=") + kToken; }

  FakeControlApi api_;
  HttpOptions options_;
  std::unique_ptr<HttpServer> server_;
  unsigned short port_ = 0;
  std::filesystem::path dir_;
};

}  // namespace tendril_test
