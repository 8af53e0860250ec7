// Fuzz target: everything a WebSocket client can send (text ops and binary frames).
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/server/http/request_codec.hpp"

namespace fg = tendril::server::http::foxglove;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  (void)fg::parse_client_text(input);
  const auto binary = fg::parse_client_binary(input);
  if (const auto* call = std::get_if<fg::ServiceCallRequest>(&binary)) {
    // Re-encoding a parsed request must give back the same bytes.
    if (fg::encode_service_call_request(call->service_id, call->call_id, call->encoding, call->payload) !=
        input) {
      std::abort();
    }
    (void)tendril::server::http::parse_json_body(call->payload, 64 * 1024);
  } else if (const auto* message = std::get_if<fg::ClientMessageData>(&binary)) {
    if (fg::encode_client_message_data(message->channel_id, message->payload) != input) std::abort();
    (void)tendril::server::http::parse_json_body(message->payload, 64 * 1024);
  }
  return 0;
}
