// Foxglove WebSocket protocol v1 ("foxglove.websocket.v1") wire codecs as pure functions, so they can be
// unit-tested and fuzzed without sockets. Follows foxglove/ws-protocol docs/spec.md: text frames are JSON
// objects with an "op"; binary frames start with a one-byte opcode and use little-endian integers.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

namespace tendril::server::http::foxglove {

inline constexpr std::string_view kSubprotocol = "foxglove.websocket.v1";

// Binary opcodes. Server and client opcode spaces are separate in the spec.
enum class ServerBinaryOp : std::uint8_t { kMessageData = 0x01, kTime = 0x02, kServiceCallResponse = 0x03 };
enum class ClientBinaryOp : std::uint8_t { kMessageData = 0x01, kServiceCallRequest = 0x02 };
enum class StatusLevel : int { kInfo = 0, kWarning = 1, kError = 2 };

// ---- client → server, text ----
struct Subscription {
  std::uint32_t id = 0;
  std::uint32_t channel_id = 0;
};
struct SubscribeOp {
  std::vector<Subscription> subscriptions;
};
struct UnsubscribeOp {
  std::vector<std::uint32_t> subscription_ids;
};
// A channel the client wants to publish on (clientPublish capability).
struct ClientChannel {
  std::uint32_t id = 0;
  std::string topic;
  std::string encoding;
  std::string schema_name;
};
struct ClientAdvertiseOp {
  std::vector<ClientChannel> channels;
};
struct ClientUnadvertiseOp {
  std::vector<std::uint32_t> channel_ids;
};
// Parameters (capabilities "parameters" and "parametersSubscribe"). Empty name lists mean "all".
struct GetParametersOp {
  std::vector<std::string> names;
  std::optional<std::string> id;  // echoed in the parameterValues answer
};
struct SetParametersOp {
  nlohmann::json parameters;  // array of {"name", "value"?, "type"?}, shape checked
  std::optional<std::string> id;
};
struct SubscribeParameterUpdatesOp {
  std::vector<std::string> names;
};
struct UnsubscribeParameterUpdatesOp {
  std::vector<std::string> names;
};
// A well-formed op this server does not implement (fetchAsset, connection graph): not abuse.
struct UnsupportedOp {
  std::string op;
};
// Malformed input: not JSON, wrong types, missing fields. `message` is for a person.
struct ProtocolError {
  std::string message;
};

using ClientTextMessage = std::variant<SubscribeOp, UnsubscribeOp, ClientAdvertiseOp, ClientUnadvertiseOp,
                                       GetParametersOp, SetParametersOp, SubscribeParameterUpdatesOp,
                                       UnsubscribeParameterUpdatesOp, UnsupportedOp, ProtocolError>;

// Never throws; anything unexpected becomes ProtocolError. Nesting deeper than kMaxJsonDepth is refused.
ClientTextMessage parse_client_text(std::string_view text);

// ---- client → server, binary ----
struct ClientMessageData {
  std::uint32_t channel_id = 0;
  std::string_view payload;  // views into the input
};
struct ServiceCallRequest {
  std::uint32_t service_id = 0;
  std::uint32_t call_id = 0;
  std::string_view encoding;
  std::string_view payload;
};
using ClientBinaryMessage = std::variant<ClientMessageData, ServiceCallRequest, ProtocolError>;
ClientBinaryMessage parse_client_binary(std::string_view data);

// ---- server → client, binary ----
inline constexpr std::size_t kMessageDataHeaderBytes = 1 + 4 + 8;
std::array<std::uint8_t, kMessageDataHeaderBytes> message_data_header(std::uint32_t subscription_id,
                                                                      std::uint64_t log_time_ns);
std::string encode_message_data(std::uint32_t subscription_id, std::uint64_t log_time_ns,
                                std::string_view payload);
std::string encode_service_call_response(std::uint32_t service_id, std::uint32_t call_id,
                                         std::string_view encoding, std::string_view payload);

// Decoders of the server frames and encoders of the client frames, for clients and tests.
struct MessageData {
  std::uint32_t subscription_id = 0;
  std::uint64_t log_time_ns = 0;
  std::string_view payload;
};
std::optional<MessageData> parse_message_data(std::string_view data);
std::optional<ServiceCallRequest> parse_service_call_response(std::string_view data);
std::string encode_service_call_request(std::uint32_t service_id, std::uint32_t call_id,
                                        std::string_view encoding, std::string_view payload);
std::string encode_client_message_data(std::uint32_t channel_id, std::string_view payload);

// ---- server → client, text ----
struct Channel {
  std::uint32_t id = 0;
  std::string topic;
  std::string encoding = "json";  // of the messages: "json" or "protobuf"
  std::string schema_name;
  // "jsonschema": `schema` is the JSON schema text. "protobuf": `schema` is the binary
  // FileDescriptorSet, which the advertisement carries in base64 (the spec's form for binary schemas).
  std::string schema_encoding = "jsonschema";
  std::string schema;
};
// Channel description for one of tendril's topics: schema name and JSON schema by topic kind.
Channel channel_for_topic(std::uint32_t id, const std::string& topic);

// Standard base64 (RFC 4648, with padding), appended to `out`.
void append_base64(const std::uint8_t* data, std::size_t size, std::string& out);

struct Service {
  std::uint32_t id = 0;
  std::string name;
  std::string type;
  std::string request_schema;
  std::string response_schema;
};

nlohmann::json server_info(const std::string& name, const std::vector<std::string>& capabilities,
                           const nlohmann::json& metadata, const std::string& session_id);
nlohmann::json advertise(const std::vector<Channel>& channels);
nlohmann::json unadvertise(const std::vector<std::uint32_t>& channel_ids);
nlohmann::json advertise_services(const std::vector<Service>& services);
// `id` (optional in the spec) lets a later status with the same id replace it and removeStatus clear it.
nlohmann::json status(StatusLevel level, const std::string& message, const std::string& id = {});
nlohmann::json remove_status(const std::vector<std::string>& ids);
// parameterValues: `parameters` is an array of {"name","value","type"?}; `id` answers a request.
nlohmann::json parameter_values(const nlohmann::json& parameters, const std::optional<std::string>& id);
nlohmann::json service_call_failure(std::uint32_t service_id, std::uint32_t call_id,
                                    const std::string& message);

}  // namespace tendril::server::http::foxglove
