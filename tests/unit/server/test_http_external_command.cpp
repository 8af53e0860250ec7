// HttpServer::command(), the entry other front ends of tendrild (the DDS bridge) command the robots
// through, and add_metrics_source(): the same lease and checks as REST, the same /metrics.
#include "http_test_support.hpp"

namespace tendril_test {
namespace {

TEST_F(HttpServerTest, ExternalCommandNeedsTheLeaseTokenLikeRest) {
  start();
  const json velocity = {{"velocity", {0.0}}};
  // No token, and a token that holds nothing: refused as REST refuses them, nothing reaches the robot.
  ApiResult refused = server_->command("srmc", "servo_jv", velocity, "", "dds:a");
  EXPECT_EQ(refused.status, 409);
  EXPECT_EQ(refused.code, "lease_held");
  EXPECT_FALSE(refused.message.empty());
  ScriptClient holder("holder");
  ASSERT_EQ(holder.take_lease(port_).status, 200);
  refused = server_->command("srmc", "servo_jv", velocity, "0123456789abcdef0123456789abcdef", "dds:b");
  EXPECT_EQ(refused.code, "lease_held");
  EXPECT_EQ(api_.servo_commands, 0);
  // The holder's token: accepted, and the command reaches ControlApi.
  const ApiResult accepted = server_->command("srmc", "servo_jv", velocity, holder.lease_token, "dds:holder");
  EXPECT_EQ(accepted.status, 200) << accepted.message;
  EXPECT_EQ(api_.servo_commands, 1);
  EXPECT_EQ(
      server_->command("srmc", "state_command", {{"command", "enable"}}, holder.lease_token, "dds:holder")
          .status,
      200);
  EXPECT_EQ(api_.state_commands, 1);
  // ControlApi's own checks still answer (here: the double's 400 for a body without "command").
  EXPECT_EQ(
      server_->command("srmc", "state_command", json::object(), holder.lease_token, "dds:holder").status,
      400);
  // Unknown robots and commands: 404, before the lease is looked at.
  EXPECT_EQ(server_->command("nope", "servo_jv", velocity, holder.lease_token, "dds:holder").status, 404);
  EXPECT_EQ(server_->command("srmc", "launch", velocity, holder.lease_token, "dds:holder").status, 404);
  // Releasing the lease over REST ends the token's right to command.
  ASSERT_EQ(http_request(port_, bhttp::verb::delete_, "/api/v1/lease", "", holder.headers()).status, 200);
  EXPECT_EQ(server_->command("srmc", "servo_jv", velocity, holder.lease_token, "dds:holder").code,
            "lease_held");
  EXPECT_EQ(api_.servo_commands, 1);
}

TEST_F(HttpServerTest, MetricsSourcesAreAppendedAndOnlyAddedBeforeStart) {
  server_ = std::make_unique<HttpServer>(api_, options_);
  server_->add_metrics_source([] { return std::string("tendril_dds_test_total 7\n"); });
  server_->start();
  port_ = server_->port();
  const Reply metrics = http_request(port_, bhttp::verb::get, "/metrics", "", bearer());
  ASSERT_EQ(metrics.status, 200);
  EXPECT_NE(metrics.raw.body().find("tendril_dds_test_total 7\n"), std::string::npos) << metrics.raw.body();
  EXPECT_THROW(server_->add_metrics_source([] { return std::string(); }), tendril::server::HttpServerError);
}

}  // namespace
}  // namespace tendril_test
