// The one instantiation of WsSession (see ws_session.hpp): over ByteStream, for every transport.
#include "ws_session.hpp"

#include "byte_stream.hpp"

namespace tendril::server {

template void start_ws_session<ByteStream>(ByteStream&& stream, HttpServer::Impl& server, Identity identity,
                                           std::uint64_t id, Request request);

}  // namespace tendril::server
