// Fuzz target: HTTP/1.1 framing into the real session code. The input is the byte stream a client
// sends on one connection (request lines, headers, chunked bodies, chunk extensions, trailers,
// pipelined requests, an upgrade to /ws); it is fed to tendril's HttpSession over a ByteStream whose
// transport is Beast's in-memory test stream, with the same parser, limits and routes as a TCP
// connection, against a ControlApi that answers every call. Checked: nothing crashes or throws out of
// the session (a contained exception is a finding too: it is counted and aborts here), and every byte
// the server writes back is a sequence of HTTP responses (or the WebSocket handshake followed by frames).
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include <boost/beast/_experimental/test/stream.hpp>

#include "front_end.hpp"
#include "stream_transport.hpp"

namespace tendril::server {

// Beast's test stream has no socket and no timer: timeouts are no-ops, closing closes the stream.
template <>
struct StreamSocket<boost::beast::test::stream> {
  static void expires_after(boost::beast::test::stream&, std::chrono::seconds) {}
  static void expires_never(boost::beast::test::stream&) {}
  static void shutdown_send(boost::beast::test::stream& s) { s.close(); }
  static void close(boost::beast::test::stream& s) { s.close(); }
};

namespace {

// Answers every call like a robot that exists and accepts everything (the framing is under test).
class AcceptingApi final : public ControlApi {
 public:
  nlohmann::json robots() const override { return nlohmann::json::array(); }
  bool has_robot(const std::string& robot) const override { return robot == "r"; }
  ApiResult measured_js(const std::string&) const override { return ApiResult::success({{"position", {0}}}); }
  ApiResult setpoint_js(const std::string&) const override { return ApiResult::success({{"position", {0}}}); }
  ApiResult measured_cp(const std::string&) const override {
    return ApiResult::success(nlohmann::json::object());
  }
  ApiResult shape(const std::string&) const override { return ApiResult::success(nlohmann::json::object()); }
  ApiResult operating_state(const std::string&) const override {
    return ApiResult::success({{"state", "DISABLED"}});
  }
  ApiResult state_command(const std::string&, const nlohmann::json&) override { return ok(); }
  ApiResult mode(const std::string&, const nlohmann::json&) override { return ok(); }
  ApiResult move_jp(const std::string&, const nlohmann::json&) override { return ok(); }
  ApiResult servo_jv(const std::string&, const nlohmann::json&) override { return ok(); }
  ApiResult estop() override { return ok(); }
  ApiResult estop_reset() override { return ok(); }
  nlohmann::json faults(std::size_t) const override { return nlohmann::json::array(); }
  std::string metrics() const override { return {}; }
  std::vector<std::string> topics() const override { return {}; }
  std::optional<nlohmann::json> topic_message(const std::string&, std::uint64_t,
                                              std::uint64_t&) const override {
    return std::nullopt;
  }
  void operator_lost(const std::string& robot) override { (void)robot; }

 private:
  static ApiResult ok() { return ApiResult::success(nlohmann::json::object()); }
};

// True when `out` is a sequence of HTTP/1.x responses, each framed by its Content-Length (the server
// never answers chunked), optionally ending in a WebSocket 101 after which frames follow.
bool well_framed(std::string_view out) {
  while (!out.empty()) {
    if (out.substr(0, 9) != "HTTP/1.1 " && out.substr(0, 9) != "HTTP/1.0 ") return false;
    const auto end = out.find("\r\n\r\n");
    if (end == std::string_view::npos) return false;
    const std::string_view header = out.substr(0, end + 4);
    if (header.substr(9, 3) == "101") return true;  // WebSocket frames follow
    const auto at = header.find("Content-Length: ");
    if (at == std::string_view::npos) return false;
    const std::size_t length = std::strtoull(std::string(header.substr(at + 16, 20)).c_str(), nullptr, 10);
    if (out.size() < end + 4 + length) return false;
    out.remove_prefix(end + 4 + length);
  }
  return true;
}

}  // namespace
}  // namespace tendril::server

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tendril::server;
  static AcceptingApi api;
  static HttpServer::Impl* server = [] {
    HttpOptions options;
    options.token = "fuzz-token";
    options.log = [](const std::string&) {};
    return new HttpServer::Impl(api, std::move(options));  // lives for the whole fuzzing run
  }();
  const auto exceptions_before = server->connection_exceptions.load();
  {
    net::io_context ioc;
    boost::beast::test::stream client(ioc);
    boost::beast::test::stream server_end(ioc, std::string_view(reinterpret_cast<const char*>(data), size));
    client.connect(server_end);
    server_end.close_remote();  // the server reads the input, then end of stream
    // The server's own session code over a ByteStream, as for a TCP or TLS connection.
    start_http_session(
        ByteStream(std::make_unique<StreamTransport<boost::beast::test::stream>>(std::move(server_end))),
        *server);
    // Everything completes without real time passing; timers (WebSocket idle pings) never become due.
    for (int rounds = 0; rounds < 100000 && ioc.poll() > 0; ++rounds) {
    }
    if (!well_framed(client.str())) std::abort();
  }
  if (server->connection_exceptions.load() != exceptions_before) std::abort();
  return 0;
}
