// HttpServer over real loopback sockets (port 0) against FakeControlApi (http_test_support.hpp).
// Publishing is stepped by calling publish_once() (publish_rate_hz = 0).
#include <algorithm>
#include <cstdio>
#include <thread>

#include "http_test_support.hpp"

namespace tendril_test {
namespace {

TEST_F(HttpServerTest, HealthNeedsNoToken) {
  start();
  EXPECT_NE(port_, 0);
  const Reply reply = http_request(port_, bhttp::verb::get, "/api/v1/health");
  ASSERT_EQ(reply.status, 200);
  EXPECT_EQ(reply.body()["status"], "ok");
  EXPECT_TRUE(reply.body()["version"].is_string());
  EXPECT_TRUE(reply.body()["uptime_s"].is_number());
}

TEST_F(HttpServerTest, ApiNeedsTheToken) {
  start();
  expect_error_shape(http_request(port_, bhttp::verb::get, "/api/v1/robots"), 401, "missing_token");
  expect_error_shape(
      http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Authorization", "Bearer nope"}}), 401,
      "bad_token");
  // The query token is for pages and the WS URL, not for REST.
  expect_error_shape(http_request(port_, bhttp::verb::get, std::string("/api/v1/robots?token=") + kToken),
                     401, "missing_token");
  const Reply ok = http_request(port_, bhttp::verb::get, "/api/v1/robots", "", bearer());
  ASSERT_EQ(ok.status, 200);
  EXPECT_EQ(ok.body()[0]["name"], "srmc");
  expect_error_shape(http_request(port_, bhttp::verb::get, "/metrics"), 401, "missing_token");
}

TEST_F(HttpServerTest, PageWithTokenSetsAnHttpOnlySessionCookieThatAuthenticates) {
  start();
  const Reply page = http_request(port_, bhttp::verb::get, std::string("/?token=") + kToken);
  ASSERT_EQ(page.status, 200);
  EXPECT_EQ(page.raw.body(), "<html>console</html>");
  const std::string cookie(page.raw[bhttp::field::set_cookie]);
  EXPECT_NE(cookie.find("tendril_session="), std::string::npos);
  EXPECT_NE(cookie.find("HttpOnly"), std::string::npos);
  EXPECT_NE(cookie.find("SameSite=Strict"), std::string::npos);
  EXPECT_EQ(cookie.find(kToken), std::string::npos) << "the cookie must not carry the token";
  const std::string pair = cookie.substr(0, cookie.find(';'));
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Cookie", pair}}).status, 200);
  expect_error_shape(
      http_request(port_, bhttp::verb::get, "/api/v1/robots", "", {{"Cookie", "tendril_session=forged"}}),
      401, "missing_token");
  expect_error_shape(http_request(port_, bhttp::verb::get, "/?token=wrong"), 401, "bad_token");
  // The cookie session is a lease identity of its own.
  const Reply lease = http_request(port_, bhttp::verb::post, "/api/v1/lease", "", {{"Cookie", pair}});
  ASSERT_EQ(lease.status, 200);
  EXPECT_EQ(lease.body()["holder"].get<std::string>().rfind("session:", 0), 0u);
  EXPECT_EQ(lease.raw.body().find(pair.substr(pair.find('=') + 1)), std::string::npos)
      << "the lease holder label must not reveal the session id";
}

TEST_F(HttpServerTest, LeaseGuardsCommandsButNotTheEstop) {
  start();
  const std::string command = R"({"command":"enable"})";
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, bearer("a")), 409,
      "lease_held");
  const Reply taken = http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("a"));
  ASSERT_EQ(taken.status, 200) << taken.raw.body();
  EXPECT_EQ(taken.body()["holder"], "client:a");
  EXPECT_GT(taken.body()["expires_in_s"].get<double>(), 0.0);
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("b")), 409,
                     "lease_held");
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, bearer("b")), 409,
      "lease_held");
  EXPECT_EQ(api_.state_commands, 0);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, bearer("a"))
                .status,
            200);
  EXPECT_EQ(api_.state_commands, 1);
  // E-stop: any authenticated client, lease or not. Reset needs the lease.
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "{}", bearer("b")).status, 200);
  EXPECT_EQ(api_.estops, 1);
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/estop/reset", "{}", bearer("b")), 409,
                     "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop/reset", "{}", bearer("a")).status, 200);
  EXPECT_EQ(api_.estop_resets, 1);
  // Release, then b may take it.
  expect_error_shape(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", bearer("b")), 409,
                     "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", bearer("a")).status, 200);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("b")).status, 200);
}

TEST_F(HttpServerTest, ViewersAreReadOnlyButMayStopTheRobot) {
  start();
  auto viewer = bearer("v");
  viewer["X-Tendril-Role"] = "viewer";
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", viewer), 403,
                     "forbidden_role");
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/move_jp", R"({"goal":[0]})", viewer), 403,
      "forbidden_role");
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/robots/srmc/measured_js", "", viewer).status, 200);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "", viewer).status, 200);
  EXPECT_EQ(api_.estops, 1);
  // The e-stop is recorded with who pressed it (issue 12).
  EXPECT_EQ(api_.last_estop_actor(), "client:v (viewer)");
  expect_error_shape(
      http_request(port_, bhttp::verb::get, "/api/v1/robots", "",
                   {{"Authorization", std::string("Bearer ") + kToken}, {"X-Tendril-Role", "root"}}),
      400, "bad_role");
}

TEST_F(HttpServerTest, BadRequestsGetTheErrorShape) {
  start();
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("a")).status, 200);
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/move_jp", "{\"goal\":[1,", bearer("a")),
      400, "malformed_json");
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/move_jp",
                                  "{\"goal\":\"" + std::string(4096, 'x') + "\"}", bearer("a")),
                     413, "body_too_large");
  expect_error_shape(
      http_request(port_, bhttp::verb::get, "/api/v1/robots/nope/measured_js", "", bearer("a")), 404,
      "unknown_robot");
  expect_error_shape(http_request(port_, bhttp::verb::get, "/api/v1/nothing", "", bearer("a")), 404,
                     "not_found");
  const Reply wrong_method =
      http_request(port_, bhttp::verb::get, "/api/v1/robots/srmc/move_jp", "", bearer("a"));
  expect_error_shape(wrong_method, 405, "method_not_allowed");
  EXPECT_EQ(wrong_method.raw[bhttp::field::allow], "POST");
  const Reply accepted =
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/move_jp", R"({"goal":[0.1]})", bearer("a"));
  EXPECT_EQ(accepted.status, 202);
  EXPECT_EQ(accepted.body()["duration_s"], 1.0);
  // A page from another origin may not call the API even with credentials.
  auto foreign = bearer("a");
  foreign["Origin"] = "http://evil.example";
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/estop", "", foreign), 403,
                     "origin_not_allowed");
}

TEST_F(HttpServerTest, StaticFilesWithMimeTypesAndNoTraversal) {
  start();
  const Reply index = http_request(port_, bhttp::verb::get, "/");
  ASSERT_EQ(index.status, 200);
  EXPECT_EQ(index.raw[bhttp::field::content_type], "text/html; charset=utf-8");
  const Reply js = http_request(port_, bhttp::verb::get, "/js/app.js");
  ASSERT_EQ(js.status, 200);
  EXPECT_EQ(js.raw[bhttp::field::content_type], "text/javascript; charset=utf-8");
  const Reply three = http_request(port_, bhttp::verb::get, "/vendor/three/three.module.js");
  ASSERT_EQ(three.status, 200);
  EXPECT_NE(three.raw.body().find("REVISION"), std::string::npos);
  for (const char* target : {"/../secret.txt", "/%2e%2e/secret.txt", "/js/..%2f..%2fsecret.txt",
                             "/vendor/three/../../secret.txt", "/vendor/three/%2e%2e/secret.txt"}) {
    const Reply reply = http_request(port_, bhttp::verb::get, target);
    EXPECT_NE(reply.status, 200) << target;
    EXPECT_EQ(reply.raw.body().find("TOP-SECRET"), std::string::npos) << target;
  }
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/missing.js").status, 404);
}

TEST_F(HttpServerTest, WebSocketHandshakeChecksTokenOriginAndSubprotocol) {
  start();
  // Refused handshakes get a plain HTTP error (Beast's client does not expose the refusal body).
  auto upgrade = [&](const std::string& target, std::map<std::string, std::string> headers) {
    headers["Connection"] = "Upgrade";
    headers["Upgrade"] = "websocket";
    headers["Sec-WebSocket-Version"] = "13";
    headers["Sec-WebSocket-Key"] = "dGhlIHNhbXBsZSBub25jZQ==";
    return http_request(port_, bhttp::verb::get, target, "", headers);
  };
  const std::map<std::string, std::string> foxglove = {{"Sec-WebSocket-Protocol", "foxglove.websocket.v1"}};
  expect_error_shape(upgrade("/ws", foxglove), 401, "missing_token");
  expect_error_shape(upgrade("/ws?token=wrong", foxglove), 401, "bad_token");
  auto evil = foxglove;
  evil["Origin"] = "http://evil.example";
  expect_error_shape(upgrade(ws_target(), evil), 403, "origin_not_allowed");
  expect_error_shape(upgrade(ws_target(), {}), 400, "subprotocol_required");
  {
    WsClient client;
    EXPECT_NE(client.connect(port_, "/ws"), 101);
  }
  {
    WsClient client;
    ASSERT_EQ(client.connect(port_, ws_target(), {{"Origin", "http://127.0.0.1:" + std::to_string(port_)}}),
              101);
    EXPECT_EQ(client.response_header("Sec-WebSocket-Protocol"), "foxglove.websocket.v1");
    const auto greeting = client.read_greeting();
    EXPECT_EQ(greeting[0]["op"], "serverInfo");
    EXPECT_EQ(greeting[0]["supportedEncodings"], json::array({"json"}));
    EXPECT_NE(std::find(greeting[0]["capabilities"].begin(), greeting[0]["capabilities"].end(), "services"),
              greeting[0]["capabilities"].end());
    EXPECT_FALSE(greeting[0]["sessionId"].get<std::string>().empty());
    EXPECT_EQ(greeting[1]["op"], "advertise");
    ASSERT_EQ(greeting[1]["channels"].size(), 2u);
    EXPECT_EQ(greeting[1]["channels"][0]["topic"], "/srmc/joint_states");
    EXPECT_EQ(greeting[1]["channels"][0]["encoding"], "json");
    EXPECT_EQ(greeting[2]["op"], "advertiseServices");
    EXPECT_GE(greeting[2]["services"].size(), 6u);
  }
}

TEST_F(HttpServerTest, SubscribeGetsBinaryFramesWithTheSubscriptionId) {
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  const auto greeting = client.read_greeting();
  const std::uint32_t channel = greeting[1]["channels"][0]["id"];
  client.send_text(
      json{{"op", "subscribe"}, {"subscriptions", {{{"id", 42}, {"channelId", channel}}}}}.dump());
  // Let the server process the subscribe before stepping the publisher.
  for (int i = 0; i < 200 && server_->connection_stats().at(0).subscriptions == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  server_->publish_once();
  const std::string frame = client.read_binary();
  const auto data = fg::parse_message_data(frame);
  ASSERT_TRUE(data);
  EXPECT_EQ(data->subscription_id, 42u);
  EXPECT_GT(data->log_time_ns, 0u);
  const json payload = json::parse(data->payload);
  EXPECT_EQ(payload["position"][0], static_cast<double>(api_.joint_version.load()));
}

// A topic source that records what the front end tells it about subscribers.
class DemandRecordingSource : public tendril::server::TopicSource {
 public:
  std::vector<tendril::server::TopicInfo> topics() const override {
    return {{"/fake/image", "foxglove.CompressedImage", "{}"}};
  }
  std::optional<tendril::server::TopicPayload> latest(const std::string&,
                                                      std::uint64_t since) const override {
    if (since >= 1) return std::nullopt;
    return tendril::server::TopicPayload{std::make_shared<const std::string>("{\"frame\":1}"), 1, 1};
  }
  void set_demand(const std::string& topic, bool wanted) override {
    std::lock_guard lock(mutex);
    calls.push_back(topic + (wanted ? " wanted" : " unwatched"));
  }
  std::vector<std::string> seen() {
    std::lock_guard lock(mutex);
    return calls;
  }
  std::mutex mutex;
  std::vector<std::string> calls;
};

TEST_F(HttpServerTest, TopicSourcesHearWhenTheirTopicsGainAndLoseSubscribers) {
  auto source = std::make_shared<DemandRecordingSource>();
  options_.topic_sources.push_back(source);
  start();
  server_->publish_once();
  EXPECT_TRUE(source->seen().empty()) << "every topic starts unwatched: nothing to say";
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  const auto greeting = client.read_greeting();
  std::uint32_t channel = 0;
  for (const auto& c : greeting[1]["channels"])
    if (c["topic"] == "/fake/image") channel = c["id"];
  ASSERT_NE(channel, 0u);
  client.send_text(
      json{{"op", "subscribe"}, {"subscriptions", {{{"id", 7}, {"channelId", channel}}}}}.dump());
  for (int i = 0; i < 200 && server_->connection_stats().at(0).subscriptions == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  server_->publish_once();
  server_->publish_once();  // told once, not every cycle
  EXPECT_EQ(source->seen(), std::vector<std::string>{"/fake/image wanted"});
  EXPECT_EQ(fg::parse_message_data(client.read_binary())->subscription_id, 7u);
  client.send_text(json{{"op", "unsubscribe"}, {"subscriptionIds", {7}}}.dump());
  for (int i = 0; i < 200 && server_->connection_stats().at(0).subscriptions != 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  server_->publish_once();
  EXPECT_EQ(source->seen(), (std::vector<std::string>{"/fake/image wanted", "/fake/image unwatched"}));
}

TEST_F(HttpServerTest, ServiceCallsRoundTripAndRespectTheLease) {
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  const auto greeting = client.read_greeting();
  std::map<std::string, std::uint32_t> ids;
  for (const auto& service : greeting[2]["services"]) ids[service["name"]] = service["id"];

  auto call = [&](const std::string& name, std::uint32_t call_id, const json& request) {
    client.send_binary(fg::encode_service_call_request(ids.at(name), call_id, "json", request.dump()));
    const std::string frame = client.read_binary();
    const auto response = fg::parse_service_call_response(frame);
    EXPECT_TRUE(response);
    if (!response) return json();
    EXPECT_EQ(response->call_id, call_id);
    EXPECT_EQ(response->service_id, ids.at(name));
    EXPECT_EQ(response->encoding, "json");
    return json::parse(response->payload);
  };
  const json refused = call("state_command", 1, {{"robot", "srmc"}, {"command", "enable"}});
  EXPECT_EQ(refused["status"], 409);
  EXPECT_EQ(refused["error"]["code"], "lease_held");
  EXPECT_EQ(call("lease", 2, json::object())["status"], 200);
  const json done = call("state_command", 3, {{"robot", "srmc"}, {"command", "enable"}});
  EXPECT_EQ(done["status"], 200);
  EXPECT_EQ(done["body"]["state"], "ENABLED");
  EXPECT_EQ(api_.state_commands, 1);
  EXPECT_EQ(call("estop", 4, json::object())["status"], 200);
  EXPECT_EQ(api_.estops, 1);
  // Unknown service: serviceCallFailure, connection kept.
  client.send_binary(fg::encode_service_call_request(999, 5, "json", "{}"));
  const json failure = client.read_op("serviceCallFailure");
  EXPECT_EQ(failure["callId"], 5);
  EXPECT_EQ(call("lease", 6, {{"action", "status"}})["body"]["yours"], true);
}

TEST_F(HttpServerTest, MalformedClientJsonGetsAStatusAndKeepsTheConnection) {
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  client.read_greeting();
  client.send_text("{not json");
  const json status = client.read_op("status");
  EXPECT_EQ(status["level"], 2);
  EXPECT_FALSE(status["message"].get<std::string>().empty());
  client.send_binary(fg::encode_service_call_request(7, 1, "json", R"({"action":"status"})"));
  EXPECT_TRUE(fg::parse_service_call_response(client.read_binary()));
}

TEST_F(HttpServerTest, RepeatedAbuseClosesTheConnection) {
  options_.ws_max_violations = 5;
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  client.read_greeting();
  for (int i = 0; i < 5; ++i) client.send_text("garbage");
  std::string message;
  bool binary = false;
  int statuses = 0;
  while (client.read(message, binary)) ++statuses;  // ends when the server closes
  EXPECT_GE(statuses, 5);
  EXPECT_NE(server_->metrics().find("tendril_ws_closed_for_abuse_total 1"), std::string::npos);
  for (int i = 0; i < 200 && !server_->connection_stats().empty(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_TRUE(server_->connection_stats().empty()) << "the closed connection must be unregistered";
}

TEST_F(HttpServerTest, ClientMessageRateIsLimited) {
  options_.ws_client_rate_hz = 0.001;  // practically no refill during the test
  options_.ws_client_burst = 3;
  options_.ws_max_violations = 3;
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  client.read_greeting();
  for (int i = 0; i < 6; ++i) client.send_text(R"({"op":"unsubscribe","subscriptionIds":[]})");
  const json status = client.read_op("status");
  EXPECT_NE(status["message"].get<std::string>().find("rate limit"), std::string::npos) << status;
  std::string message;
  bool binary = false;
  while (client.read(message, binary)) {
  }
  EXPECT_NE(server_->metrics().find("tendril_ws_client_violations_total 3"), std::string::npos);
}

TEST_F(HttpServerTest, ClosingTheLeaseHoldersSocketStopsServo) {
  start();
  WsClient holder;
  ASSERT_EQ(holder.connect(port_, ws_target(), {{"X-Tendril-Client", "console"}}), 101);
  holder.read_greeting();
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("console")).status, 200);
  WsClient bystander;
  ASSERT_EQ(bystander.connect(port_, ws_target()), 101);
  bystander.read_greeting();
  bystander.close();
  for (int i = 0; i < 100 && server_->connection_stats().size() > 1; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(api_.operator_lost_calls, 0) << "a non-holder leaving must not stop the robot";
  holder.close();
  for (int i = 0; i < 200 && api_.operator_lost_calls == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(api_.operator_lost_calls, 1);
  // The lease itself stays with the console until released or expired.
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer("x")).body()["holder"],
            "client:console");
}

TEST_F(HttpServerTest, ClientPublishStreamsServoForTheHolderOnly) {
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target(), {{"X-Tendril-Client", "pad"}}), 101);
  const auto greeting = client.read_greeting();
  EXPECT_EQ(greeting[0]["capabilities"][0], "clientPublish");
  client.send_text(R"({"op":"advertise","channels":[{"id":1,"topic":"/srmc/servo_jv","encoding":"json"}]})");
  client.send_binary(fg::encode_client_message_data(1, R"({"velocity":[0.1]})"));
  EXPECT_NE(client.read_op("status")["message"].get<std::string>().find("lease_held"), std::string::npos);
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("pad")).status, 200);
  client.send_binary(fg::encode_client_message_data(1, R"({"velocity":[0.1]})"));
  for (int i = 0; i < 200 && api_.servo_commands == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(api_.servo_commands, 1);
}

TEST_F(HttpServerTest, SlowReaderDropsOldMessagesAndStaysBounded) {
  api_.payload_padding = 64 * 1024;  // large frames fill the socket buffers quickly
  options_.max_ws_message_bytes = 4096;
  // This test is about the bounded queue of a reader that is slow; closing a client that stopped
  // reading altogether is test_http_hardening's.
  options_.ws_stalled_write_timeout = std::chrono::minutes(10);
  start();
  WsClient slow;
  ASSERT_EQ(slow.connect(port_, ws_target()), 101);
  const auto greeting = slow.read_greeting();
  const std::uint32_t channel = greeting[1]["channels"][0]["id"];
  slow.send_text(json{{"op", "subscribe"}, {"subscriptions", {{{"id", 1}, {"channelId", channel}}}}}.dump());
  for (int i = 0; i < 200 && server_->connection_stats().at(0).subscriptions == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  // The client now stops reading. 2000 fresh 64 KiB messages (~128 MiB) cannot all fit in the socket
  // buffers: the server must drop, and its queue for this client must never exceed one per subscription.
  std::size_t max_queued = 0;
  for (int i = 0; i < 2000; ++i) {
    server_->publish_once();
    const auto stats = server_->connection_stats();
    ASSERT_EQ(stats.size(), 1u);
    max_queued = std::max(max_queued, stats[0].queued_messages);
  }
  EXPECT_LE(max_queued, 1u);
  const auto stats = server_->connection_stats().at(0);
  EXPECT_GT(stats.dropped, 0u);
  std::printf("slow reader: 2000 publishes of 64 KiB, %llu dropped, max queued %zu\n",
              static_cast<unsigned long long>(stats.dropped), max_queued);
  const std::string metrics = server_->metrics();
  EXPECT_EQ(metrics.find("tendril_ws_messages_dropped_total 0\n"), std::string::npos);
  EXPECT_NE(metrics.find("tendril_ws_messages_dropped_total "), std::string::npos);

  // Another client is not held up by the slow one.
  WsClient fast;
  ASSERT_EQ(fast.connect(port_, ws_target()), 101);
  fast.read_greeting();
  fast.send_text(json{{"op", "subscribe"}, {"subscriptions", {{{"id", 9}, {"channelId", channel}}}}}.dump());
  const auto data = fg::parse_message_data(fast.read_binary());  // latest message is sent on subscribe
  ASSERT_TRUE(data);
  EXPECT_EQ(data->subscription_id, 9u);
}

TEST_F(HttpServerTest, MetricsCombineControlAndFrontEnd) {
  start();
  http_request(port_, bhttp::verb::get, "/api/v1/robots");  // a 401
  const Reply reply = http_request(port_, bhttp::verb::get, "/metrics", "", bearer());
  ASSERT_EQ(reply.status, 200);
  EXPECT_NE(reply.raw.body().find("fake_control_loop_overruns_total 0"), std::string::npos);
  EXPECT_NE(reply.raw.body().find("tendril_http_requests_total{status=\"401\"} 1"), std::string::npos);
  EXPECT_NE(reply.raw.body().find("tendril_ws_clients 0"), std::string::npos);
}

TEST_F(HttpServerTest, PortInUseIsAClearError) {
  start();
  HttpOptions second = options_;
  second.port = port_;
  HttpServer other(api_, second);
  try {
    other.start();
    FAIL() << "binding a taken port must throw";
  } catch (const tendril::server::HttpServerError& e) {
    EXPECT_NE(std::string(e.what()).find("already in use"), std::string::npos) << e.what();
  }
  HttpOptions no_token = options_;
  no_token.token.clear();
  EXPECT_THROW(HttpServer(api_, no_token), tendril::server::HttpServerError);
}

// Reads JSON messages until `pick` accepts one (skipping others); null when the connection ends.
template <class Pick>
json read_until(WsClient& client, Pick pick, int max_messages = 50) {
  for (int i = 0; i < max_messages; ++i) {
    const json message = client.read_json();
    if (message.is_null()) return nullptr;
    if (pick(message)) return message;
  }
  return nullptr;
}

TEST_F(HttpServerTest, LeaseTakeoverNeedsConfirmationAndNeverInterruptsServo) {
  start();
  WsClient old_holder;
  ASSERT_EQ(old_holder.connect(port_, ws_target(), {{"X-Tendril-Client", "a"}}), 101);
  old_holder.read_greeting();
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("a")).status, 200);

  // Refusal names the holder and offers a takeover token.
  const Reply refused = http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("b"));
  expect_error_shape(refused, 409, "lease_held");
  EXPECT_EQ(refused.body()["error"]["holder"], "client:a");
  const std::string token = refused.body()["error"]["takeover_token"].get<std::string>();
  EXPECT_GE(token.size(), 16u);
  // A token is bound to who asked for it, and a made-up one does nothing.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease",
                                  json{{"takeover_token", token}}.dump(), bearer("c")),
                     409, "bad_takeover_token");
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease",
                                  R"({"takeover_token":"0123456789abcdef"})", bearer("b")),
                     409, "bad_takeover_token");
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/lease", R"({"takeover_token":5})", bearer("b")), 400,
      "bad_request");

  // While the holder streams servo commands the takeover is refused (and the token stays usable).
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/servo_jv", R"({"velocity":[0.1]})",
                         bearer("a"))
                .status,
            200);
  const Reply servo = http_request(port_, bhttp::verb::post, "/api/v1/lease",
                                   json{{"takeover_token", token}}.dump(), bearer("b"));
  expect_error_shape(servo, 409, "servo_active");
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer("a")).body()["mine"], true);

  // After the command timeout (150 ms by default) the stream has ended: the confirmed takeover succeeds.
  std::this_thread::sleep_for(std::chrono::milliseconds(250));
  const Reply taken = http_request(port_, bhttp::verb::post, "/api/v1/lease",
                                   json{{"takeover_token", token}}.dump(), bearer("b"));
  ASSERT_EQ(taken.status, 200) << taken.raw.body();
  EXPECT_EQ(taken.body()["holder"], "client:b");
  EXPECT_EQ(taken.body()["mine"], true);
  EXPECT_EQ(taken.body()["held"], true);
  EXPECT_GT(taken.body()["expires_s"].get<double>(), 0.0);
  // The token was used up.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("a")), 409,
                     "lease_held");

  // The old holder's socket is told, with a warning.
  const json warning =
      read_until(old_holder, [](const json& m) { return m["op"] == "status" && m["level"] == 1; });
  ASSERT_TRUE(warning.is_object());
  EXPECT_NE(warning["message"].get<std::string>().find("taken over by client:b"), std::string::npos)
      << warning.dump();
  const Reply status_a = http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer("a"));
  EXPECT_EQ(status_a.body()["held"], true);
  EXPECT_EQ(status_a.body()["mine"], false);
  EXPECT_EQ(status_a.body()["holder"], "client:b");
  // The old holder's commands are refused now.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  R"({"command":"enable"})", bearer("a")),
                     409, "lease_held");
}

TEST(LeaseManagerTakeover, TokensExpireAfterFifteenSecondsAndAreSingleUse) {
  using tendril::server::http::LeaseManager;
  LeaseManager lease(std::chrono::milliseconds(30000));
  const auto t0 = LeaseManager::Clock::time_point{} + std::chrono::hours(1);
  ASSERT_TRUE(lease.acquire("a", "A", t0));
  lease.issue_takeover_token("b", "tok1", t0);
  std::string previous;
  EXPECT_EQ(lease.take_over("b", "B", "tok1", t0 + std::chrono::seconds(16), previous),
            LeaseManager::TakeoverResult::kBadToken);
  lease.issue_takeover_token("b", "tok2", t0);
  EXPECT_EQ(lease.take_over("b", "B", "tok2", t0 + std::chrono::seconds(14), previous),
            LeaseManager::TakeoverResult::kTaken);
  EXPECT_EQ(previous, "a");
  EXPECT_EQ(lease.holder(t0 + std::chrono::seconds(14)), "b");
  EXPECT_EQ(lease.take_over("b", "B", "tok2", t0 + std::chrono::seconds(14), previous),
            LeaseManager::TakeoverResult::kBadToken);
}

TEST_F(HttpServerTest, ParametersAreReadableByAllAndWritableByTheHolderOnly) {
  start();
  WsClient viewer;
  ASSERT_EQ(viewer.connect(port_, ws_target() + "&role=viewer"), 101);
  const auto greeting = viewer.read_greeting();
  const auto& capabilities = greeting[0]["capabilities"];
  EXPECT_NE(std::find(capabilities.begin(), capabilities.end(), "parameters"), capabilities.end());
  EXPECT_NE(std::find(capabilities.begin(), capabilities.end(), "parametersSubscribe"), capabilities.end());

  viewer.send_text(R"({"op":"getParameters","parameterNames":[],"id":"all"})");
  const json all = viewer.read_op("parameterValues");
  EXPECT_EQ(all["id"], "all");
  EXPECT_EQ(all["parameters"].size(), 2u);
  viewer.send_text(R"({"op":"getParameters","parameterNames":["/srmc/j1/upper","/nope"],"id":"one"})");
  const json one = viewer.read_op("parameterValues");
  ASSERT_EQ(one["parameters"].size(), 1u);
  EXPECT_EQ(one["parameters"][0]["value"], 10.0);
  viewer.send_text(R"({"op":"subscribeParameterUpdates","parameterNames":["/srmc/j1/upper"]})");

  // A viewer may not set; the refusal is a status, and the answer carries the unchanged value.
  viewer.send_text(R"({"op":"setParameters","parameters":[{"name":"/srmc/j1/upper","value":5}],"id":"v"})");
  const json viewer_refusal = viewer.read_op("status");
  EXPECT_EQ(viewer_refusal["level"], 2);
  EXPECT_NE(viewer_refusal["message"].get<std::string>().find("forbidden_role"), std::string::npos);
  EXPECT_EQ(viewer.read_op("parameterValues")["parameters"][0]["value"], 10.0);

  WsClient operator_client;
  ASSERT_EQ(operator_client.connect(port_, ws_target(), {{"X-Tendril-Client", "op"}}), 101);
  operator_client.read_greeting();
  operator_client.send_text(
      R"({"op":"setParameters","parameters":[{"name":"/srmc/j1/upper","value":5}],"id":"x"})");
  EXPECT_NE(operator_client.read_op("status")["message"].get<std::string>().find("lease_held"),
            std::string::npos);
  EXPECT_EQ(api_.parameter_sets, 0);

  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("op")).status, 200);
  operator_client.send_text(
      R"({"op":"setParameters","parameters":[{"name":"/srmc/j1/upper","value":12}],"id":"y"})");
  const json wide =
      read_until(operator_client, [](const json& m) { return m["op"] == "status" && m["level"] == 2; });
  EXPECT_NE(wide["message"].get<std::string>().find("out_of_range"), std::string::npos) << wide.dump();
  operator_client.send_text(
      R"({"op":"setParameters","parameters":[{"name":"/srmc/j1/upper","value":5}],"id":"z"})");
  const json answer = read_until(
      operator_client, [](const json& m) { return m["op"] == "parameterValues" && m["id"] == "z"; });
  ASSERT_TRUE(answer.is_object());
  EXPECT_EQ(answer["parameters"][0]["value"], 5.0);
  EXPECT_EQ(api_.parameter_sets, 1);
  // The subscriber is told, without an id.
  const json update =
      read_until(viewer, [](const json& m) { return m["op"] == "parameterValues" && !m.contains("id"); });
  ASSERT_TRUE(update.is_object());
  EXPECT_EQ(update["parameters"][0]["name"], "/srmc/j1/upper");
  EXPECT_EQ(update["parameters"][0]["value"], 5.0);
  // Malformed parameter ops are protocol errors, not crashes.
  operator_client.send_text(R"({"op":"getParameters","parameterNames":"all"})");
  EXPECT_EQ(read_until(operator_client,
                       [](const json& m) { return m["op"] == "status" && m["level"] == 2; })["message"]
                .get<std::string>()
                .find("getParameters"),
            0u);
}

TEST_F(HttpServerTest, FaultsAndRefusedServiceCallsBecomeStatusMessages) {
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  const auto greeting = client.read_greeting();
  server_->publish_once();  // the server notes what is already in the log (nothing)
  {
    std::lock_guard lock(api_.mutex);
    api_.fault_events = json::array({{{"robot", "srmc"},
                                      {"kind", "fault"},
                                      {"message", "drive 'roll' stopped sending heartbeats"},
                                      {"time", 1.0}}});
  }
  server_->publish_once();
  const json fault = read_until(client, [](const json& m) { return m["op"] == "status"; });
  ASSERT_TRUE(fault.is_object());
  EXPECT_EQ(fault["level"], 2);
  EXPECT_EQ(fault["id"], "safety/srmc");
  EXPECT_NE(fault["message"].get<std::string>().find("heartbeats"), std::string::npos);
  server_->publish_once();  // reported once only

  std::uint32_t state_command_id = 0;
  for (const auto& service : greeting[2]["services"])
    if (service["name"] == "state_command") state_command_id = service["id"];
  client.send_binary(
      fg::encode_service_call_request(state_command_id, 9, "json", R"({"robot":"srmc","command":"enable"})"));
  const json refusal = read_until(client, [](const json& m) { return m["op"] == "status"; });
  ASSERT_TRUE(refusal.is_object());
  EXPECT_EQ(refusal["level"], 1);
  EXPECT_NE(refusal["message"].get<std::string>().find("state_command: lease_held"), std::string::npos)
      << refusal.dump();
}

TEST_F(HttpServerTest, EveryDispatchedRouteIsInTheOpenApiDocument) {
  options_.openapi_file = std::string(TENDRIL_SOURCE_DIR) + "/server/openapi/openapi.json";
  start();
  const Reply reply = http_request(port_, bhttp::verb::get, "/api/v1/openapi.json");  // public, no token
  ASSERT_EQ(reply.status, 200);
  const json doc = reply.body();
  EXPECT_EQ(doc["openapi"].get<std::string>().rfind("3.1", 0), 0u);
  ASSERT_EQ(doc["servers"][0]["url"], "/api/v1");
  for (const auto& route : HttpServer::api_routes()) {
    ASSERT_EQ(route.path.rfind("/api/v1", 0), 0u) << route.path;
    const std::string path = route.path.substr(7);
    std::string method = route.method;
    std::transform(method.begin(), method.end(), method.begin(),
                   [](unsigned char c) { return std::tolower(c); });
    EXPECT_TRUE(doc["paths"].contains(path) && doc["paths"][path].contains(method))
        << route.method << " " << route.path << " is served but not documented";
  }
}

}  // namespace
}  // namespace tendril_test
