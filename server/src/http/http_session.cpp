// The one instantiation of HttpSession (see http_session.hpp): over ByteStream, for every transport.
#include "http_session.hpp"

#include <memory>
#include <utility>

namespace tendril::server {

template class HttpSession<ByteStream>;

void start_http_session(ByteStream&& stream, HttpServer::Impl& server) {
  std::make_shared<HttpSession<ByteStream>>(server, std::move(stream))->run();
}

}  // namespace tendril::server
