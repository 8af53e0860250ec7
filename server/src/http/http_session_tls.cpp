// HTTP connections over TLS (see http_session.hpp).
#include <boost/beast/ssl.hpp>

#include "http_session.hpp"

namespace tendril::server {

template class HttpSession<beast::ssl_stream<beast::tcp_stream>>;

void start_tls_http_session(tcp::socket&& socket, HttpServer::Impl& server) {
  std::make_shared<HttpSession<beast::ssl_stream<beast::tcp_stream>>>(server, std::move(socket),
                                                                      *server.tls_context)
      ->run();
}

}  // namespace tendril::server
