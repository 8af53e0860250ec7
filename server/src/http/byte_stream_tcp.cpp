// Plain TCP connections: a Beast tcp_stream as the ByteStream of an HTTP session.
#include <memory>
#include <utility>

#include <boost/beast/core/tcp_stream.hpp>

#include "front_end.hpp"
#include "stream_transport.hpp"

namespace tendril::server {

void start_plain_http_session(tcp::socket&& socket, HttpServer::Impl& server) {
  start_http_session(
      ByteStream(std::make_unique<StreamTransport<boost::beast::tcp_stream>>(std::move(socket))), server);
}

}  // namespace tendril::server
