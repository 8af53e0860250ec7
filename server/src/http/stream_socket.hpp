// StreamSocket<Stream>: what a connection does to the socket under its byte stream (timeouts,
// shutdown, close). Specialised by the HTTP fuzz target for Beast's in-memory test stream, so that the
// fuzzer drives the very session code the server runs.
#pragma once

#include <chrono>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/error.hpp>
#include <boost/beast/core/stream_traits.hpp>

namespace tendril::server {

template <class Stream>
struct StreamSocket {
  static void expires_after(Stream& s, std::chrono::seconds d) {
    boost::beast::get_lowest_layer(s).expires_after(d);
  }
  static void expires_never(Stream& s) { boost::beast::get_lowest_layer(s).expires_never(); }
  static void shutdown_send(Stream& s) {
    boost::beast::error_code ignored;
    boost::beast::get_lowest_layer(s).socket().shutdown(boost::asio::ip::tcp::socket::shutdown_send, ignored);
  }
  static void close(Stream& s) {
    boost::beast::error_code ignored;
    auto& socket = boost::beast::get_lowest_layer(s).socket();
    socket.shutdown(boost::asio::ip::tcp::socket::shutdown_both, ignored);
    socket.close(ignored);
  }
};

}  // namespace tendril::server
