// HTTPS and WSS on the server's one port, with a self-signed certificate made by the openssl tool.
#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket.hpp>
#include <boost/beast/websocket/ssl.hpp>

#include "http_test_support.hpp"

namespace tendril_test {
namespace {

namespace beast = boost::beast;
namespace websocket = boost::beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

TEST_F(HttpServerTest, TlsServesHttpsAndWssOnTheSamePort) {
  // A self-signed certificate made for this test with the openssl command-line tool.
  const auto cert = dir_ / "cert.pem";
  const auto key = dir_ / "key.pem";
  const std::string make_cert =
      "openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=127.0.0.1 -keyout '" + key.string() +
      "' -out '" + cert.string() + "' >/dev/null 2>&1";
  ASSERT_EQ(std::system(make_cert.c_str()), 0) << "openssl req failed (is the openssl tool installed?)";
  options_.tls_certificate_file = cert.string();
  options_.tls_private_key_file = key.string();
  start();
  EXPECT_TRUE(server_->tls());

  net::io_context ioc;
  net::ssl::context client_tls(net::ssl::context::tls_client);
  client_tls.load_verify_file(cert.string());  // trust exactly this certificate
  client_tls.set_verify_mode(net::ssl::verify_peer);
  {
    beast::ssl_stream<beast::tcp_stream> stream(ioc, client_tls);
    beast::get_lowest_layer(stream).connect({net::ip::make_address("127.0.0.1"), port_});
    stream.handshake(net::ssl::stream_base::client);
    bhttp::request<bhttp::string_body> req{bhttp::verb::get, "/api/v1/robots", 11};
    req.set(bhttp::field::host, "127.0.0.1");
    req.set(bhttp::field::authorization, std::string("Bearer ") + kToken);
    bhttp::write(stream, req);
    beast::flat_buffer buffer;
    bhttp::response<bhttp::string_body> res;
    bhttp::read(stream, buffer, res);
    EXPECT_EQ(res.result_int(), 200);
    EXPECT_EQ(json::parse(res.body())[0]["name"], "srmc");
  }
  {
    websocket::stream<beast::ssl_stream<beast::tcp_stream>> ws(ioc, client_tls);
    beast::get_lowest_layer(ws).connect({net::ip::make_address("127.0.0.1"), port_});
    ws.next_layer().handshake(net::ssl::stream_base::client);
    ws.set_option(websocket::stream_base::decorator([](websocket::request_type& req) {
      req.set(bhttp::field::sec_websocket_protocol, "foxglove.websocket.v1");
      // A browser on the console's https origin is allowed by default.
      req.set(bhttp::field::origin, "https://127.0.0.1:" + std::to_string(0));
    }));
    beast::error_code ec;
    websocket::response_type response;
    ws.handshake(response, "127.0.0.1", ws_target(), ec);
    EXPECT_TRUE(ec) << "an origin of another port must be refused";
  }
  {
    websocket::stream<beast::ssl_stream<beast::tcp_stream>> ws(ioc, client_tls);
    beast::get_lowest_layer(ws).connect({net::ip::make_address("127.0.0.1"), port_});
    ws.next_layer().handshake(net::ssl::stream_base::client);
    const std::string origin = "https://127.0.0.1:" + std::to_string(port_);
    ws.set_option(websocket::stream_base::decorator([origin](websocket::request_type& req) {
      req.set(bhttp::field::sec_websocket_protocol, "foxglove.websocket.v1");
      req.set(bhttp::field::origin, origin);
    }));
    ws.handshake("127.0.0.1", ws_target());
    beast::flat_buffer buffer;
    ws.read(buffer);
    const json info = json::parse(beast::buffers_to_string(buffer.data()));
    EXPECT_EQ(info["op"], "serverInfo");
    beast::error_code ignored;
    ws.close(websocket::close_code::normal, ignored);
  }
  // Plain HTTP on the TLS port gets no answer.
  tcp::socket plain(ioc);
  plain.connect({net::ip::make_address("127.0.0.1"), port_});
  const std::string request = "GET /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n";
  net::write(plain, net::buffer(request));
  char reply[16];
  beast::error_code ec;
  const std::size_t n = plain.read_some(net::buffer(reply), ec);
  EXPECT_TRUE(ec || std::string(reply, n).rfind("HTTP/1.1 200", 0) != 0);
}

TEST_F(HttpServerTest, TlsNeedsReadableCertificateAndKey) {
  options_.tls_certificate_file = (dir_ / "missing.pem").string();
  options_.tls_private_key_file = (dir_ / "missing-key.pem").string();
  HttpServer server(api_, options_);
  try {
    server.start();
    FAIL() << "a missing certificate must be a start-up error";
  } catch (const tendril::server::HttpServerError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.pem"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace tendril_test
