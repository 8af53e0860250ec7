// WebSocket connections over TLS (see ws_session.hpp).
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket/ssl.hpp>

#include "ws_session.hpp"

namespace tendril::server {

template void start_ws_session<beast::ssl_stream<beast::tcp_stream>>(
    beast::ssl_stream<beast::tcp_stream>&& stream, HttpServer::Impl& server, Identity identity,
    std::uint64_t id, Request request);

}  // namespace tendril::server
