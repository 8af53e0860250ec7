// BoundedRequestParser: the HTTP/1.1 request parser every connection reads with. Beast's stock parser
// has limits for the header and the body only: chunked trailers and chunk extensions are unbounded,
// and a trailer field over 64 KiB makes Boost 1.74's field container throw std::length_error out of
// the read (that killed tendrild once). This parser builds the same request message but
// - refuses trailer fields (no route takes any): error `trailers_not_accepted`;
// - refuses a Transfer-Encoding whose final coding is not `chunked` (RFC 9112 §6.3: its body length
//   cannot be known, and a proxy in front may frame it differently), and Transfer-Encoding together
//   with Content-Length (§6.1; Beast refuses only some orders of the two);
// - turns every exception of the field container into an error code (`field_too_large`, `bad_alloc`);
// - bounds each chunk extension (`chunk_extension_too_large`) and the body (Beast's body_limit);
// - with the connection's read buffer capped at kReadBufferBytes, no single line of the request (a
//   header, a chunk-size line, the trailer section) can hold more than that in memory.
// What a refused request is answered with: refusal_for().
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include <boost/beast/http/basic_parser.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <boost/system/error_code.hpp>

namespace tendril::server::http {

// The read buffer of a connection: a request line, a header or a chunk line longer than this is refused.
inline constexpr std::size_t kReadBufferBytes = std::size_t{32} * 1024;
inline constexpr std::size_t kHeaderLimitBytes = std::size_t{16} * 1024;
inline constexpr std::size_t kChunkExtensionLimitBytes = 256;

enum class RequestError {
  trailers_not_accepted = 1,
  field_too_large,
  chunk_extension_too_large,
  transfer_encoding_not_chunked,
  transfer_encoding_with_content_length,
};
const boost::system::error_category& request_error_category() noexcept;
boost::system::error_code make_error_code(RequestError e) noexcept;

class BoundedRequestParser final : public boost::beast::http::basic_parser<true> {
 public:
  using Request = boost::beast::http::request<boost::beast::http::string_body>;
  explicit BoundedRequestParser(std::size_t body_limit);

  Request& get() noexcept { return message_; }
  const Request& get() const noexcept { return message_; }
  Request release() noexcept { return std::move(message_); }

 private:
  using error_code = boost::beast::error_code;
  using string_view = boost::beast::string_view;
  void on_request_impl(boost::beast::http::verb method, string_view method_str, string_view target,
                       int version, error_code& ec) override;
  void on_response_impl(int, string_view, int, error_code& ec) override;
  void on_field_impl(boost::beast::http::field name, string_view name_string, string_view value,
                     error_code& ec) override;
  void on_header_impl(error_code& ec) override;
  void on_body_init_impl(const boost::optional<std::uint64_t>& content_length, error_code& ec) override;
  std::size_t on_body_impl(string_view body, error_code& ec) override;
  void on_chunk_header_impl(std::uint64_t size, string_view extensions, error_code& ec) override;
  std::size_t on_chunk_body_impl(std::uint64_t remain, string_view body, error_code& ec) override;
  void on_finish_impl(error_code& ec) override;

  Request message_;
  bool header_done_ = false;
};

// How a request that could not be read is answered: status, error code and message for a person.
// nullopt: the peer went away or timed out (nothing to answer).
struct Refusal {
  int status;
  std::string code;
  std::string message;
  std::string metric;  // label for tendril_http_requests_refused_total
};
std::optional<Refusal> refusal_for(const boost::beast::error_code& ec, std::size_t body_limit);

}  // namespace tendril::server::http

namespace boost::system {
template <>
struct is_error_code_enum<tendril::server::http::RequestError> : std::true_type {};
}  // namespace boost::system
