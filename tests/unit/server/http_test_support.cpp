#include "http_test_support.hpp"

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

namespace tendril_test {

namespace beast = boost::beast;
namespace websocket = boost::beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

Reply http_request(unsigned short port, bhttp::verb verb, const std::string& target, const std::string& body,
                   const std::map<std::string, std::string>& headers) {
  net::io_context ioc;
  tcp::socket socket(ioc);
  socket.connect({net::ip::make_address("127.0.0.1"), port});
  bhttp::request<bhttp::string_body> req{verb, target, 11};
  req.set(bhttp::field::host, "127.0.0.1");
  for (const auto& [name, value] : headers) req.set(name, value);
  req.body() = body;
  req.prepare_payload();
  bhttp::write(socket, req);
  beast::flat_buffer buffer;
  Reply reply;
  bhttp::response_parser<bhttp::string_body> parser;
  parser.body_limit(64 * 1024 * 1024);
  bhttp::read(socket, buffer, parser);
  reply.raw = parser.release();
  reply.status = reply.raw.result_int();
  return reply;
}

RawExchange raw_exchange(unsigned short port, const std::string& bytes, std::size_t max_read) {
  net::io_context ioc;
  tcp::socket socket(ioc);
  socket.connect({net::ip::make_address("127.0.0.1"), port});
  RawExchange out;
  beast::error_code ec;
  net::write(socket, net::buffer(bytes), ec);
  out.sent_all = !ec;
  socket.shutdown(tcp::socket::shutdown_send, ec);
  std::array<char, 65536> chunk{};
  while (out.received.size() < max_read) {
    const std::size_t n = socket.read_some(net::buffer(chunk), ec);
    if (ec) break;
    out.received.append(chunk.data(), n);
  }
  return out;
}

struct WsClient::Impl {
  net::io_context ioc;
  websocket::stream<tcp::socket> ws{ioc};
  websocket::response_type response;
};

WsClient::WsClient() : impl_(std::make_unique<Impl>()) {}
WsClient::~WsClient() = default;

int WsClient::connect(unsigned short port, const std::string& target,
                      const std::map<std::string, std::string>& headers, bool offer_subprotocol) {
  auto& ws = impl_->ws;
  beast::get_lowest_layer(ws).connect({net::ip::make_address("127.0.0.1"), port});
  ws.set_option(websocket::stream_base::decorator([headers, offer_subprotocol](websocket::request_type& req) {
    if (offer_subprotocol) req.set(bhttp::field::sec_websocket_protocol, "foxglove.websocket.v1");
    for (const auto& [name, value] : headers) req.set(name, value);
  }));
  beast::error_code ec;
  ws.handshake(impl_->response, "127.0.0.1:" + std::to_string(port), target, ec);
  return impl_->response.result_int();
}

std::string WsClient::response_header(const std::string& name) const {
  const auto it = impl_->response.find(name);
  return it == impl_->response.end() ? std::string() : std::string(it->value());
}

bool WsClient::read(std::string& message, bool& binary) {
  beast::flat_buffer buffer;
  beast::error_code ec;
  impl_->ws.read(buffer, ec);
  if (ec) return false;
  message = beast::buffers_to_string(buffer.data());
  binary = impl_->ws.got_binary();
  return true;
}

json WsClient::read_json() {
  std::string message;
  bool binary = false;
  while (read(message, binary)) {
    if (!binary) return json::parse(message);
  }
  return nullptr;
}

json WsClient::read_op(const std::string& op) {
  for (int i = 0; i < 50; ++i) {
    const json message = read_json();
    if (message.is_null()) return nullptr;
    if (message["op"] == op) return message;
  }
  return nullptr;
}

std::string WsClient::read_binary() {
  std::string message;
  bool binary = false;
  while (read(message, binary)) {
    if (binary) return message;
  }
  return {};
}

void WsClient::send_text(const std::string& text) {
  impl_->ws.text(true);
  impl_->ws.write(net::buffer(text));
}

void WsClient::send_binary(const std::string& data) {
  impl_->ws.binary(true);
  impl_->ws.write(net::buffer(data));
}

void WsClient::close() {
  beast::error_code ec;
  impl_->ws.close(websocket::close_code::normal, ec);
}

}  // namespace tendril_test
