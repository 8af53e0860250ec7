// HttpServer over real loopback sockets (port 0) against FakeControlApi (http_test_support.hpp).
// Publishing is stepped by calling publish_once() (publish_rate_hz = 0).
#include <algorithm>
#include <cstdio>
#include <map>
#include <mutex>
#include <thread>

#include "http_test_support.hpp"

namespace tendril_test {
namespace {

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
  ScriptClient a("a");
  ScriptClient b("b");
  const std::string command = R"({"command":"enable"})";
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, a.headers()), 409,
      "lease_held");
  const Reply taken = a.take_lease(port_);
  ASSERT_EQ(taken.status, 200) << taken.raw.body();
  EXPECT_EQ(taken.body()["holder"], "client:a");
  EXPECT_GT(taken.body()["expires_in_s"].get<double>(), 0.0);
  EXPECT_EQ(a.lease_token.size(), 32u) << "128 random bits, hex";
  expect_error_shape(b.take_lease(port_), 409, "lease_held");
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, b.headers()), 409,
      "lease_held");
  EXPECT_EQ(api_.state_commands, 0);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, a.headers())
                .status,
            200);
  EXPECT_EQ(api_.state_commands, 1);
  // E-stop: any authenticated client, lease or not. Reset needs the lease.
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "{}", b.headers()).status, 200);
  EXPECT_EQ(api_.estops, 1);
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/estop/reset", "{}", b.headers()), 409,
                     "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop/reset", "{}", a.headers()).status, 200);
  EXPECT_EQ(api_.estop_resets, 1);
  // Release, then b may take it.
  expect_error_shape(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", b.headers()), 409,
                     "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", a.headers()).status, 200);
  EXPECT_EQ(b.take_lease(port_).status, 200);
}

TEST_F(HttpServerTest, LeaseOwnershipCannotBeCopiedFromAName) {
  // Issue 10: the lease was held by the X-Tendril-Client name, which any token holder could send.
  start();
  ScriptClient holder("robot-script");
  ASSERT_EQ(holder.take_lease(port_).status, 200);
  const std::string command = R"({"command":"enable"})";
  ScriptClient copycat("robot-script");  // the same name, without the holder's lease token
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, copycat.headers()),
      409, "lease_held");
  // Neither the bearer token alone nor a made-up lease token holds it.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command,
                                  bearer("robot-script")),
                     409, "lease_held");
  auto forged = bearer("robot-script");
  forged["X-Tendril-Lease"] = std::string(32, '0');
  const Reply refused =
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, forged);
  expect_error_shape(refused, 409, "lease_held");
  EXPECT_NE(refused.body()["error"]["message"].get<std::string>().find("X-Tendril-Lease"), std::string::npos)
      << "a stale or wrong lease token is named as the likely cause";
  // A garbled token is a claim that holds nothing; it never stands between a caller and the e-stop.
  forged["X-Tendril-Lease"] = "not a token!";
  expect_error_shape(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, forged), 409,
      "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/estop", "", forged).status, 200);
  EXPECT_EQ(api_.state_commands, 0);
  // The holder's token works on any connection, with or without the name.
  auto token_only = bearer();
  token_only["X-Tendril-Lease"] = holder.lease_token;
  EXPECT_EQ(
      http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command", command, token_only).status,
      200);
  // The token is never shown to anyone else.
  const Reply status = http_request(port_, bhttp::verb::get, "/api/v1/lease", "", copycat.headers());
  EXPECT_EQ(status.body()["holder"], "client:robot-script");
  EXPECT_EQ(status.body()["mine"], false);
  EXPECT_EQ(status.raw.body().find(holder.lease_token), std::string::npos);
  EXPECT_FALSE(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", holder.headers())
                   .body()
                   .contains("lease_token"));
}

TEST_F(HttpServerTest, PlainBearerScriptKeepsTheLeaseAcrossConnections) {
  // Issue 14: a script using plain curl (bearer token only, one connection per call)
  // took the lease and was then refused by "connection:1", a connection that had already closed.
  start();
  const Reply taken = http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer());
  ASSERT_EQ(taken.status, 200) << taken.raw.body();
  EXPECT_EQ(taken.body()["holder"], "api-client");
  EXPECT_TRUE(taken.body()["lease_token"].is_string());
  // Each http_request is a new TCP connection, as each curl call is.
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                         R"({"command":"enable"})", bearer())
                .status,
            200);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/move_jp", R"({"goal":[1]})", bearer())
                .status,
            202);
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer()).body()["mine"], true);
  // The bearer identity is the token's: a client name is a label, not another identity.
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer("other-name")).body()["mine"],
            true);
  // A script with a lease token of its own is somebody else.
  ScriptClient script("script");
  expect_error_shape(script.take_lease(port_), 409, "lease_held");
  EXPECT_EQ(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", bearer()).status, 200);
  EXPECT_EQ(script.take_lease(port_).status, 200);
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  R"({"command":"enable"})", bearer()),
                     409, "lease_held");
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
  // Duplicate keys: the issue's probe got 200 here (the last copy won).
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/mode",
                                  R"({"mode":[],"mode":"telemanipulation"})", bearer("a")),
                     400, "duplicate_key");
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/lease",
                                  R"({"takeover_token":"x","takeover_token":"y"})", bearer("a")),
                     400, "duplicate_key");
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

// A source topic marked recorded_always (an arm's force) is produced and recorded with nobody watching;
// another source's topic (an image) is not — the recording's rule, with from_source as "costly".
TEST_F(HttpServerTest, ARecordingKeepsASourceTopicMarkedRecordedAlwaysWithoutSubscribers) {
  class AlwaysSource : public DemandRecordingSource {
   public:
    std::vector<tendril::server::TopicInfo> topics() const override {
      tendril::server::TopicInfo info{"/fake/force", "tendril.ArmForce", "{}"};
      info.recorded_always = true;
      return {info};
    }
  };
  class Tap : public tendril::server::http::PublishTap {
   public:
    bool wants(const std::string& /*topic*/, bool from_source) const override { return !from_source; }
    void channel(std::uint32_t id, const std::string& topic, const std::string& /*schema_name*/,
                 const std::string& /*schema*/, const std::string& /*encoding*/,
                 const std::string& /*schema_encoding*/) override {
      std::lock_guard lock(mutex);
      names[id] = topic;
    }
    void message(std::uint32_t id, std::uint64_t /*log_time_ns*/,
                 std::shared_ptr<const std::string> /*payload*/) override {
      std::lock_guard lock(mutex);
      recorded.push_back(names.count(id) ? names[id] : std::to_string(id));
    }
    void command(std::uint64_t /*time_ns*/, const std::string& /*robot*/, const std::string& /*command*/,
                 const std::string& /*who*/, const json& /*body*/, int /*status*/,
                 const std::string& /*error*/) override {}
    bool has(const std::string& topic) {
      std::lock_guard lock(mutex);
      return std::find(recorded.begin(), recorded.end(), topic) != recorded.end();
    }
    std::mutex mutex;
    std::map<std::uint32_t, std::string> names;
    std::vector<std::string> recorded;
  };
  auto image = std::make_shared<DemandRecordingSource>();
  auto force = std::make_shared<AlwaysSource>();
  auto tap = std::make_shared<Tap>();
  options_.topic_sources = {image, force};
  options_.tap = tap;
  start();
  server_->publish_once();
  server_->publish_once();
  EXPECT_EQ(force->seen(), std::vector<std::string>{"/fake/force wanted"});
  EXPECT_TRUE(image->seen().empty());
  EXPECT_TRUE(tap->has("/fake/force"));
  EXPECT_FALSE(tap->has("/fake/image"));
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
  // A payload with a duplicate key is refused like a REST body, and nothing runs.
  client.send_binary(fg::encode_service_call_request(
      ids.at("state_command"), 8, "json", R"({"robot":"srmc","command":"disable","command":"enable"})"));
  const std::string duplicate_frame = client.read_binary();
  const auto duplicate = fg::parse_service_call_response(duplicate_frame);
  ASSERT_TRUE(duplicate);
  const json duplicate_body = json::parse(duplicate->payload);
  EXPECT_EQ(duplicate_body["status"], 400);
  EXPECT_EQ(duplicate_body["error"]["code"], "duplicate_key");
  EXPECT_EQ(api_.state_commands, 1);
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
  ScriptClient console("console");
  ASSERT_EQ(console.take_lease(port_).status, 200);
  // The script's WebSocket presents its lease token, so it is the holder there too.
  WsClient holder;
  ASSERT_EQ(
      holder.connect(port_, ws_target() + "&lease=" + console.lease_token, {{"X-Tendril-Client", "console"}}),
      101);
  EXPECT_EQ(holder.read_greeting()[0]["metadata"]["client"], "client:console");
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
  // The lease belongs to the token, not to that socket: it stays until released or expired.
  const Reply lease = http_request(port_, bhttp::verb::get, "/api/v1/lease", "", console.headers());
  EXPECT_EQ(lease.body()["holder"], "client:console");
  EXPECT_EQ(lease.body()["mine"], true);
}

TEST_F(HttpServerTest, ALeaseTakenOnAWebSocketEndsWithItsConnection) {
  // A WebSocket client with the bearer token alone (Foxglove Studio with ?token=) is its own
  // identity: nobody else can use its lease, and when it goes the lease goes with it rather than
  // staying with a dead connection for lease_timeout.
  start();
  WsClient client;
  ASSERT_EQ(client.connect(port_, ws_target()), 101);
  client.read_greeting();
  client.send_binary(fg::encode_service_call_request(7, 1, "json", R"({"action":"acquire"})"));
  const std::string frame = client.read_binary();
  const auto response = fg::parse_service_call_response(frame);
  ASSERT_TRUE(response);
  const json granted = json::parse(response->payload);
  ASSERT_EQ(granted["status"], 200) << granted.dump();
  EXPECT_EQ(granted["body"]["holder"].get<std::string>().rfind("ws:", 0), 0u);
  // Another bearer caller is not the holder; the token handed to the socket is.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  R"({"command":"enable"})", bearer()),
                     409, "lease_held");
  auto with_token = bearer();
  with_token["X-Tendril-Lease"] = granted["body"]["lease_token"].get<std::string>();
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", with_token).body()["mine"], true);
  client.close();
  bool released = false;
  for (int i = 0; i < 200 && !released; ++i) {
    released =
        !http_request(port_, bhttp::verb::get, "/api/v1/lease", "", bearer()).body()["held"].get<bool>();
    if (!released) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_TRUE(released) << "the lease of a closed connection is free at once";
  EXPECT_EQ(api_.operator_lost_calls, 1);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer()).status, 200);
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
  // A REST caller with the same name and the bearer token is not this connection.
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "", bearer("pad")).status, 200);
  client.send_binary(fg::encode_client_message_data(1, R"({"velocity":[0.1]})"));
  const json refused = read_until(client, [](const json& m) {
    return m["op"] == "status" && m["message"].get<std::string>().find("lease_held") != std::string::npos;
  });
  EXPECT_TRUE(refused.is_object());
  EXPECT_EQ(api_.servo_commands, 0);
  ASSERT_EQ(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", bearer("pad")).status, 200);
  client.send_binary(fg::encode_service_call_request(7, 1, "json", R"({"action":"acquire"})"));
  ASSERT_TRUE(fg::parse_service_call_response(client.read_binary()));
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

TEST_F(HttpServerTest, LeaseTakeoverNeedsConfirmationAndNeverInterruptsServo) {
  start();
  ScriptClient a("a");
  ScriptClient b("b");
  ScriptClient c("c");
  ASSERT_EQ(a.take_lease(port_).status, 200);
  WsClient old_holder;
  ASSERT_EQ(old_holder.connect(port_, ws_target() + "&lease=" + a.lease_token), 101);
  old_holder.read_greeting();

  // Refusal names the holder and offers a takeover token.
  const Reply refused = b.take_lease(port_);
  expect_error_shape(refused, 409, "lease_held");
  EXPECT_EQ(refused.body()["error"]["holder"], "client:a");
  const std::string token = refused.body()["error"]["takeover_token"].get<std::string>();
  EXPECT_GE(token.size(), 16u);
  // A token is bound to who asked for it, and a made-up one does nothing.
  c.lease_token = "c-own";
  expect_error_shape(c.take_lease(port_, json{{"takeover_token", token}}.dump()), 409, "bad_takeover_token");
  expect_error_shape(b.take_lease(port_, R"({"takeover_token":"0123456789abcdef"})"), 409,
                     "bad_takeover_token");
  expect_error_shape(b.take_lease(port_, R"({"takeover_token":5})"), 400, "bad_request");

  // While the holder streams servo commands the takeover is refused (and the token stays usable).
  // The stream is sent with the token alone: the lease, not the key it was taken with, is streaming.
  auto token_only = bearer();
  token_only["X-Tendril-Lease"] = a.lease_token;
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/servo_jv", R"({"velocity":[0.1]})",
                         token_only)
                .status,
            200);
  expect_error_shape(b.take_lease(port_, json{{"takeover_token", token}}.dump()), 409, "servo_active");
  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/lease", "", a.headers()).body()["mine"], true);

  // After the command timeout (150 ms by default) the stream has ended: the confirmed takeover succeeds.
  std::this_thread::sleep_for(std::chrono::milliseconds(250));
  const std::string old_token = a.lease_token;
  const Reply taken = b.take_lease(port_, json{{"takeover_token", token}}.dump());
  ASSERT_EQ(taken.status, 200) << taken.raw.body();
  EXPECT_EQ(taken.body()["holder"], "client:b");
  EXPECT_EQ(taken.body()["mine"], true);
  EXPECT_EQ(taken.body()["held"], true);
  EXPECT_GT(taken.body()["expires_s"].get<double>(), 0.0);
  EXPECT_NE(b.lease_token, old_token) << "a takeover issues a new lease token";
  // The token was used up.
  expect_error_shape(a.take_lease(port_), 409, "lease_held");

  // The old holder's socket is told, with a warning.
  const json warning =
      read_until(old_holder, [](const json& m) { return m["op"] == "status" && m["level"] == 1; });
  ASSERT_TRUE(warning.is_object());
  EXPECT_NE(warning["message"].get<std::string>().find("taken over by client:b"), std::string::npos)
      << warning.dump();
  const Reply status_a = http_request(port_, bhttp::verb::get, "/api/v1/lease", "", a.headers());
  EXPECT_EQ(status_a.body()["held"], true);
  EXPECT_EQ(status_a.body()["mine"], false);
  EXPECT_EQ(status_a.body()["holder"], "client:b");
  // The old holder's commands are refused now.
  expect_error_shape(http_request(port_, bhttp::verb::post, "/api/v1/robots/srmc/state_command",
                                  R"({"command":"enable"})", a.headers()),
                     409, "lease_held");
}

TEST(LeaseManagerTakeover, TokensExpireAfterFifteenSecondsAndAreSingleUse) {
  using tendril::server::http::LeaseManager;
  LeaseManager lease(std::chrono::milliseconds(30000));
  const auto t0 = LeaseManager::Clock::time_point{} + std::chrono::hours(1);
  const auto granted = lease.acquire("session:a", "A", "lease-a", t0);
  ASSERT_TRUE(granted);
  EXPECT_EQ(granted->lease_token, "lease-a");
  lease.issue_takeover_token("session:b", "tok1", t0);
  EXPECT_EQ(lease.take_over("session:b", "B", "tok1", "lease-b", t0 + std::chrono::seconds(16)).result,
            LeaseManager::TakeoverResult::kBadToken);
  lease.issue_takeover_token("session:b", "tok2", t0);
  const auto taken = lease.take_over("session:b", "B", "tok2", "lease-b", t0 + std::chrono::seconds(14));
  EXPECT_EQ(taken.result, LeaseManager::TakeoverResult::kTaken);
  EXPECT_EQ(taken.grant.lease_token, "lease-b");
  EXPECT_EQ(taken.previous_keys, (std::vector<std::string>{"session:a", "lease:lease-a"}));
  EXPECT_TRUE(lease.holds("session:b", t0 + std::chrono::seconds(14)));
  EXPECT_FALSE(lease.holds("lease:lease-a", t0 + std::chrono::seconds(14)));
  EXPECT_EQ(lease.take_over("session:b", "B", "tok2", "lease-c", t0 + std::chrono::seconds(14)).result,
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

  ScriptClient op("op");
  WsClient without_lease;
  ASSERT_EQ(
      without_lease.connect(port_, ws_target(), {{"X-Tendril-Client", "op"}, {"X-Tendril-Lease", "new"}}),
      101);
  without_lease.read_greeting();
  without_lease.send_text(
      R"({"op":"setParameters","parameters":[{"name":"/srmc/j1/upper","value":5}],"id":"x"})");
  EXPECT_NE(without_lease.read_op("status")["message"].get<std::string>().find("lease_held"),
            std::string::npos);
  EXPECT_EQ(api_.parameter_sets, 0);

  // The operator takes the lease over REST; its socket presents the token (a handshake header).
  ASSERT_EQ(op.take_lease(port_).status, 200);
  WsClient operator_client;
  ASSERT_EQ(operator_client.connect(port_, ws_target(), op.headers()), 101);
  operator_client.read_greeting();
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

// A ReplayControl double: records the controls it was given.
class FakeReplay : public tendril::server::ReplayControl {
 public:
  ApiResult replay_status() const override { return ApiResult::success({{"playing", true}}); }
  ApiResult control_replay(const json& body) override {
    last = body;
    return ApiResult::success({{"playing", body.value("playing", true)}});
  }
  json last;
};

TEST_F(HttpServerTest, InReplayModeEveryCommandIsRefusedBeforeTheLeaseAndTheReplayRoutesAnswer) {
  // A live server: the replay routes say so.
  start();
  auto live = http_request(port_, bhttp::verb::get, "/api/v1/replay", "", bearer());
  EXPECT_EQ(live.status, 404);
  EXPECT_EQ(live.body()["error"]["code"], "not_replaying");
  server_->stop();

  auto replay = std::make_shared<FakeReplay>();
  options_.replay = replay;
  start();
  const auto refused = [&](bhttp::verb verb, const std::string& target, const std::string& body) {
    const auto reply = http_request(port_, verb, target, body, bearer());
    EXPECT_EQ(reply.status, 409) << target << ": " << reply.raw.body();
    EXPECT_EQ(reply.body()["error"]["code"], "replay_mode") << target;
  };
  // Without the lease: the answer is replay_mode, not lease_held.
  refused(bhttp::verb::post, "/api/v1/robots/srmc/state_command", R"({"command":"enable"})");
  refused(bhttp::verb::post, "/api/v1/estop", "{}");
  ASSERT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/lease", "{}", bearer()).status, 200);
  refused(bhttp::verb::post, "/api/v1/robots/srmc/state_command", R"({"command":"enable"})");
  refused(bhttp::verb::post, "/api/v1/robots/srmc/servo_jv", R"({"velocity":[1]})");
  refused(bhttp::verb::post, "/api/v1/estop/reset", "{}");
  EXPECT_EQ(api_.state_commands.load(), 0);
  EXPECT_EQ(api_.servo_commands.load(), 0);
  EXPECT_EQ(api_.estops.load(), 0);

  EXPECT_EQ(http_request(port_, bhttp::verb::get, "/api/v1/replay", "", bearer()).status, 200);
  const auto put = http_request(port_, bhttp::verb::put, "/api/v1/replay", R"({"playing":false})", bearer());
  EXPECT_EQ(put.status, 200) << put.raw.body();
  EXPECT_EQ(replay->last, (json{{"playing", false}}));
  auto viewer = bearer();
  viewer["X-Tendril-Role"] = "viewer";
  EXPECT_EQ(http_request(port_, bhttp::verb::put, "/api/v1/replay", R"({"playing":true})", viewer).status,
            403);
  EXPECT_EQ(http_request(port_, bhttp::verb::put, "/api/v1/replay", "{not json", bearer()).status, 400);
  EXPECT_EQ(http_request(port_, bhttp::verb::post, "/api/v1/replay", "{}", bearer()).status, 405);
  EXPECT_EQ(replay->last, (json{{"playing", false}}));
}

}  // namespace
}  // namespace tendril_test
