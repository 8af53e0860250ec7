// TLS connections: a Beast ssl_stream over a tcp_stream as the ByteStream of an HTTP session (HTTPS
// and WSS on the same port).
#include <memory>
#include <utility>

#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket/ssl.hpp>

#include "front_end.hpp"
#include "stream_transport.hpp"

namespace tendril::server {

using TlsStream = boost::beast::ssl_stream<boost::beast::tcp_stream>;

template <>
inline constexpr bool kIsTlsTransport<TlsStream> = true;

void start_tls_http_session(tcp::socket&& socket, HttpServer::Impl& server) {
  start_http_session(
      ByteStream(std::make_unique<StreamTransport<TlsStream>>(std::move(socket), *server.tls_context)),
      server);
}

}  // namespace tendril::server
