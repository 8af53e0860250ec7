#include "request_reader.hpp"

#include <new>
#include <stdexcept>

#include <boost/asio/error.hpp>
#include <boost/beast/core/error.hpp>
#include <boost/beast/core/string.hpp>
#include <boost/beast/http/error.hpp>
#include <boost/beast/http/rfc7230.hpp>

namespace tendril::server::http {

namespace bhttp = boost::beast::http;

namespace {

class RequestErrorCategory final : public boost::system::error_category {
 public:
  const char* name() const noexcept override { return "tendril.http.request"; }
  std::string message(int value) const override {
    switch (static_cast<RequestError>(value)) {
      case RequestError::trailers_not_accepted:
        return "chunked trailer fields are not accepted";
      case RequestError::field_too_large:
        return "a header field is too large";
      case RequestError::chunk_extension_too_large:
        return "a chunk extension is too large";
      case RequestError::transfer_encoding_not_chunked:
        return "the final transfer coding is not chunked";
      case RequestError::transfer_encoding_with_content_length:
        return "both Transfer-Encoding and Content-Length";
    }
    return "request error";
  }
};

}  // namespace

const boost::system::error_category& request_error_category() noexcept {
  static const RequestErrorCategory category;
  return category;
}

boost::system::error_code make_error_code(RequestError e) noexcept {
  return {static_cast<int>(e), request_error_category()};
}

BoundedRequestParser::BoundedRequestParser(std::size_t body_limit) {
  header_limit(static_cast<std::uint32_t>(kHeaderLimitBytes));
  this->body_limit(body_limit);
}

void BoundedRequestParser::on_request_impl(bhttp::verb method, string_view method_str, string_view target,
                                           int version, error_code& ec) {
  try {
    message_.target(target);
    if (method == bhttp::verb::unknown) {
      message_.method_string(method_str);
    } else {
      message_.method(method);
    }
    message_.version(version);
  } catch (const std::bad_alloc&) {
    ec = bhttp::error::bad_alloc;
  } catch (const std::exception&) {
    ec = RequestError::field_too_large;  // a target or method over the container's 64 KiB
  }
}

void BoundedRequestParser::on_response_impl(int, string_view, int, error_code& ec) {
  ec = bhttp::error::bad_version;  // a request parser never sees a status line
}

void BoundedRequestParser::on_field_impl(bhttp::field name, string_view name_string, string_view value,
                                         error_code& ec) {
  if (header_done_) {
    // Trailer fields: no route needs them, and accepting them would need a limit of their own.
    ec = RequestError::trailers_not_accepted;
    return;
  }
  try {
    message_.insert(name, name_string, value);
  } catch (const std::bad_alloc&) {
    ec = bhttp::error::bad_alloc;
  } catch (const std::exception&) {
    ec = RequestError::field_too_large;
  }
}

void BoundedRequestParser::on_header_impl(error_code& ec) {
  header_done_ = true;
  // Transfer-Encoding may be sent as several fields; together they are one list of codings.
  // The field values are bounded by the header limit.
  try {
    std::string codings;
    bool has_transfer_encoding = false;
    const auto [first, end] = message_.equal_range(bhttp::field::transfer_encoding);
    for (auto field = first; field != end; ++field) {
      if (has_transfer_encoding) codings.push_back(',');
      codings.append(field->value());
      has_transfer_encoding = true;
    }
    if (!has_transfer_encoding) return;
    if (message_.count(bhttp::field::content_length) != 0) {
      ec = RequestError::transfer_encoding_with_content_length;
      return;
    }
    string_view last;
    for (const auto coding : bhttp::token_list{codings}) last = coding;
    if (!boost::beast::iequals(last, "chunked")) ec = RequestError::transfer_encoding_not_chunked;
  } catch (const std::bad_alloc&) {
    ec = bhttp::error::bad_alloc;
  }
}

void BoundedRequestParser::on_body_init_impl(const boost::optional<std::uint64_t>& content_length,
                                             error_code& ec) {
  try {
    // The body limit was checked against the declared length by the caller (413 before the body).
    if (content_length && *content_length <= kReadBufferBytes)
      message_.body().reserve(static_cast<std::size_t>(*content_length));
  } catch (const std::bad_alloc&) {
    ec = bhttp::error::bad_alloc;
  }
}

std::size_t BoundedRequestParser::on_body_impl(string_view body, error_code& ec) {
  try {
    message_.body().append(body.data(), body.size());
  } catch (const std::bad_alloc&) {
    ec = bhttp::error::bad_alloc;
    return 0;
  }
  return body.size();
}

void BoundedRequestParser::on_chunk_header_impl(std::uint64_t, string_view extensions, error_code& ec) {
  if (extensions.size() > kChunkExtensionLimitBytes) ec = RequestError::chunk_extension_too_large;
}

std::size_t BoundedRequestParser::on_chunk_body_impl(std::uint64_t, string_view body, error_code& ec) {
  return on_body_impl(body, ec);
}

void BoundedRequestParser::on_finish_impl(error_code&) {}

std::optional<Refusal> refusal_for(const boost::beast::error_code& ec, std::size_t body_limit) {
  if (!ec || ec == bhttp::error::end_of_stream || ec == boost::beast::error::timeout ||
      ec == boost::asio::error::operation_aborted || ec == boost::asio::error::eof ||
      ec == boost::asio::error::connection_reset || ec == bhttp::error::partial_message)
    return std::nullopt;
  if (ec == bhttp::error::body_limit)
    return Refusal{413, "body_too_large",
                   "request body exceeds the limit of " + std::to_string(body_limit) + " bytes",
                   "body_limit"};
  if (ec == bhttp::error::header_limit)
    return Refusal{431, "headers_too_large",
                   "request headers exceed the limit of " + std::to_string(kHeaderLimitBytes) + " bytes",
                   "header_limit"};
  if (ec == RequestError::field_too_large)
    return Refusal{431, "headers_too_large", "a request header field is too large", "field_too_large"};
  if (ec == bhttp::error::buffer_overflow)
    return Refusal{431, "request_line_too_large",
                   "a request line, header, chunk line or trailer section exceeds " +
                       std::to_string(kReadBufferBytes) + " bytes",
                   "line_too_large"};
  if (ec == RequestError::trailers_not_accepted)
    return Refusal{400, "trailers_not_accepted", "chunked trailer fields are not accepted by this server",
                   "trailers"};
  if (ec == RequestError::chunk_extension_too_large)
    return Refusal{400, "bad_chunk",
                   "a chunk extension exceeds " + std::to_string(kChunkExtensionLimitBytes) + " bytes",
                   "chunk_extension"};
  if (ec == RequestError::transfer_encoding_not_chunked)
    return Refusal{400, "bad_transfer_encoding",
                   "Transfer-Encoding must end in \"chunked\" (RFC 9112 section 6.3); this server decodes no "
                   "other coding, so the body's length would be unknown",
                   "transfer_encoding"};
  if (ec == RequestError::transfer_encoding_with_content_length || ec == bhttp::error::bad_transfer_encoding)
    return Refusal{400, "bad_transfer_encoding",
                   "send either Transfer-Encoding: chunked or Content-Length, once each, never both "
                   "(RFC 9112 section 6.1)",
                   "transfer_encoding"};
  if (ec == bhttp::error::bad_chunk || ec == bhttp::error::bad_chunk_extension)
    return Refusal{400, "bad_chunk", "malformed chunked body (chunk size not hex, too large, or bad framing)",
                   "bad_chunk"};
  if (ec == bhttp::error::bad_alloc)
    return Refusal{503, "out_of_memory", "the server could not allocate memory for this request",
                   "bad_alloc"};
  if (ec == bhttp::error::bad_content_length)
    return Refusal{400, "bad_request", "malformed Content-Length", "malformed"};
  return Refusal{400, "bad_request", "malformed HTTP request (" + ec.message() + ")", "malformed"};
}

}  // namespace tendril::server::http
