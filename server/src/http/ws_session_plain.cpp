// WebSocket connections over Plain TCP (see ws_session.hpp).
#include <boost/beast/core/tcp_stream.hpp>

#include "ws_session.hpp"

namespace tendril::server {

template void start_ws_session<beast::tcp_stream>(beast::tcp_stream&& stream, HttpServer::Impl& server,
                                                  Identity identity, std::uint64_t id, Request request);

}  // namespace tendril::server
