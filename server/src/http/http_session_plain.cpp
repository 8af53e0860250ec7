// HTTP connections over Plain TCP (see http_session.hpp).
#include <boost/beast/core/tcp_stream.hpp>

#include "http_session.hpp"

namespace tendril::server {

template class HttpSession<beast::tcp_stream>;

void start_plain_http_session(tcp::socket&& socket, HttpServer::Impl& server) {
  std::make_shared<HttpSession<beast::tcp_stream>>(server, std::move(socket))->run();
}

}  // namespace tendril::server
