#include "tendril/server/http/foxglove_protocol.hpp"

#include <cstring>
#include <limits>

#include "tendril/server/http/request_codec.hpp"

namespace tendril::server::http::foxglove {
namespace {

using nlohmann::json;

void put_u32(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}
void put_u64(std::string& out, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xFF));
}
std::uint32_t get_u32(std::string_view data, std::size_t at) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i)
    v |= static_cast<std::uint32_t>(static_cast<unsigned char>(data[at + i])) << (8 * i);
  return v;
}
std::uint64_t get_u64(std::string_view data, std::size_t at) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i)
    v |= static_cast<std::uint64_t>(static_cast<unsigned char>(data[at + i])) << (8 * i);
  return v;
}

// Reads an unsigned 32-bit id field; the error message names the field for a person.
std::optional<std::uint32_t> get_id(const json& object, const char* field, std::string& error) {
  const auto it = object.find(field);
  if (it == object.end()) {
    error = std::string("missing field \"") + field + "\"";
    return std::nullopt;
  }
  if (!it->is_number_integer() ||
      (it->is_number_unsigned() ? it->get<std::uint64_t>() > 0xFFFFFFFFull
                                : (it->get<std::int64_t>() < 0 || it->get<std::int64_t>() > 0xFFFFFFFFll))) {
    error = std::string("field \"") + field + "\" must be an integer from 0 to 4294967295";
    return std::nullopt;
  }
  return static_cast<std::uint32_t>(it->get<std::uint64_t>());
}

std::optional<std::string> get_string(const json& object, const char* field, std::string& error) {
  const auto it = object.find(field);
  if (it == object.end() || !it->is_string()) {
    error = std::string("field \"") + field + "\" must be a string";
    return std::nullopt;
  }
  return it->get<std::string>();
}

const json* get_array(const json& object, const char* field, std::string& error) {
  const auto it = object.find(field);
  if (it == object.end() || !it->is_array()) {
    error = std::string("field \"") + field + "\" must be an array";
    return nullptr;
  }
  return &*it;
}

std::optional<std::vector<std::uint32_t>> get_id_array(const json& object, const char* field,
                                                       std::string& error) {
  const json* array = get_array(object, field, error);
  if (!array) return std::nullopt;
  std::vector<std::uint32_t> ids;
  for (const auto& item : *array) {
    if (!item.is_number_integer() ||
        (item.is_number_unsigned()
             ? item.get<std::uint64_t>() > 0xFFFFFFFFull
             : (item.get<std::int64_t>() < 0 || item.get<std::int64_t>() > 0xFFFFFFFFll))) {
      error = std::string("\"") + field + "\" must hold integers from 0 to 4294967295";
      return std::nullopt;
    }
    ids.push_back(static_cast<std::uint32_t>(item.get<std::uint64_t>()));
  }
  return ids;
}

std::optional<std::vector<std::string>> get_name_array(const json& object, const char* field,
                                                       std::string& error) {
  const json* array = get_array(object, field, error);
  if (!array) return std::nullopt;
  std::vector<std::string> names;
  for (const auto& item : *array) {
    if (!item.is_string()) {
      error = std::string("\"") + field + "\" must hold strings";
      return std::nullopt;
    }
    names.push_back(item.get<std::string>());
  }
  return names;
}

// The optional request id of getParameters/setParameters.
bool get_optional_id(const json& object, std::optional<std::string>& id, std::string& error) {
  const auto it = object.find("id");
  if (it == object.end() || it->is_null()) return true;
  if (!it->is_string()) {
    error = "field \"id\" must be a string";
    return false;
  }
  id = it->get<std::string>();
  return true;
}

}  // namespace

ClientTextMessage parse_client_text(std::string_view text) {
  if (json_nesting_exceeds(text, kMaxJsonDepth)) return ProtocolError{"message nests too deeply"};
  std::string duplicate_key;
  const json message = parse_json_unique_keys(text, duplicate_key);
  if (message.is_discarded() && !duplicate_key.empty()) {
    return ProtocolError{"message has the key \"" + duplicate_key + "\" twice in one object"};
  }
  if (message.is_discarded()) return ProtocolError{"message is not valid JSON"};
  if (!message.is_object()) return ProtocolError{"message must be a JSON object"};
  std::string error;
  const auto op = get_string(message, "op", error);
  if (!op) return ProtocolError{"message has no \"op\" string"};

  if (*op == "subscribe") {
    const json* subs = get_array(message, "subscriptions", error);
    if (!subs) return ProtocolError{"subscribe: " + error};
    SubscribeOp result;
    for (const auto& item : *subs) {
      if (!item.is_object()) return ProtocolError{"subscribe: each subscription must be an object"};
      const auto id = get_id(item, "id", error);
      const auto channel = id ? get_id(item, "channelId", error) : std::nullopt;
      if (!id || !channel) return ProtocolError{"subscribe: " + error};
      result.subscriptions.push_back({*id, *channel});
    }
    return result;
  }
  if (*op == "unsubscribe") {
    auto ids = get_id_array(message, "subscriptionIds", error);
    if (!ids) return ProtocolError{"unsubscribe: " + error};
    return UnsubscribeOp{std::move(*ids)};
  }
  if (*op == "advertise") {
    const json* channels = get_array(message, "channels", error);
    if (!channels) return ProtocolError{"advertise: " + error};
    ClientAdvertiseOp result;
    for (const auto& item : *channels) {
      if (!item.is_object()) return ProtocolError{"advertise: each channel must be an object"};
      ClientChannel channel;
      const auto id = get_id(item, "id", error);
      const auto topic = id ? get_string(item, "topic", error) : std::nullopt;
      const auto encoding = topic ? get_string(item, "encoding", error) : std::nullopt;
      if (!id || !topic || !encoding) return ProtocolError{"advertise: " + error};
      channel.id = *id;
      channel.topic = *topic;
      channel.encoding = *encoding;
      if (const auto it = item.find("schemaName"); it != item.end() && it->is_string()) {
        channel.schema_name = it->get<std::string>();
      }
      result.channels.push_back(std::move(channel));
    }
    return result;
  }
  if (*op == "unadvertise") {
    auto ids = get_id_array(message, "channelIds", error);
    if (!ids) return ProtocolError{"unadvertise: " + error};
    return ClientUnadvertiseOp{std::move(*ids)};
  }
  if (*op == "getParameters") {
    GetParametersOp result;
    auto names = get_name_array(message, "parameterNames", error);
    if (!names || !get_optional_id(message, result.id, error))
      return ProtocolError{"getParameters: " + error};
    result.names = std::move(*names);
    return result;
  }
  if (*op == "setParameters") {
    SetParametersOp result;
    const json* parameters = get_array(message, "parameters", error);
    if (!parameters || !get_optional_id(message, result.id, error))
      return ProtocolError{"setParameters: " + error};
    for (const auto& item : *parameters) {
      if (!item.is_object() || !item.contains("name") || !item["name"].is_string())
        return ProtocolError{"setParameters: each parameter must be an object with a \"name\" string"};
    }
    result.parameters = *parameters;
    return result;
  }
  if (*op == "subscribeParameterUpdates" || *op == "unsubscribeParameterUpdates") {
    auto names = get_name_array(message, "parameterNames", error);
    if (!names) return ProtocolError{*op + ": " + error};
    if (*op == "subscribeParameterUpdates") return SubscribeParameterUpdatesOp{std::move(*names)};
    return UnsubscribeParameterUpdatesOp{std::move(*names)};
  }
  static constexpr const char* kKnownUnsupported[] = {"subscribeConnectionGraph",
                                                      "unsubscribeConnectionGraph", "fetchAsset"};
  for (const char* known : kKnownUnsupported) {
    if (*op == known) return UnsupportedOp{*op};
  }
  return ProtocolError{"unknown op \"" + op->substr(0, 64) + "\""};
}

ClientBinaryMessage parse_client_binary(std::string_view data) {
  if (data.empty()) return ProtocolError{"empty binary message"};
  const auto opcode = static_cast<std::uint8_t>(data[0]);
  if (opcode == static_cast<std::uint8_t>(ClientBinaryOp::kMessageData)) {
    if (data.size() < 5) return ProtocolError{"client message data shorter than its 5-byte header"};
    return ClientMessageData{get_u32(data, 1), data.substr(5)};
  }
  if (opcode == static_cast<std::uint8_t>(ClientBinaryOp::kServiceCallRequest)) {
    if (data.size() < 13) return ProtocolError{"service call request shorter than its 13-byte header"};
    ServiceCallRequest request;
    request.service_id = get_u32(data, 1);
    request.call_id = get_u32(data, 5);
    const std::uint32_t encoding_length = get_u32(data, 9);
    if (encoding_length > data.size() - 13)
      return ProtocolError{"service call request encoding length overruns"};
    request.encoding = data.substr(13, encoding_length);
    request.payload = data.substr(13 + encoding_length);
    return request;
  }
  return ProtocolError{"unknown binary opcode " + std::to_string(opcode)};
}

std::array<std::uint8_t, kMessageDataHeaderBytes> message_data_header(std::uint32_t subscription_id,
                                                                      std::uint64_t log_time_ns) {
  std::array<std::uint8_t, kMessageDataHeaderBytes> header{};
  header[0] = static_cast<std::uint8_t>(ServerBinaryOp::kMessageData);
  for (int i = 0; i < 4; ++i) header[1 + i] = static_cast<std::uint8_t>((subscription_id >> (8 * i)) & 0xFF);
  for (int i = 0; i < 8; ++i) header[5 + i] = static_cast<std::uint8_t>((log_time_ns >> (8 * i)) & 0xFF);
  return header;
}

std::string encode_message_data(std::uint32_t subscription_id, std::uint64_t log_time_ns,
                                std::string_view payload) {
  std::string out;
  out.reserve(kMessageDataHeaderBytes + payload.size());
  out.push_back(static_cast<char>(ServerBinaryOp::kMessageData));
  put_u32(out, subscription_id);
  put_u64(out, log_time_ns);
  out.append(payload);
  return out;
}

static std::string encode_service_frame(std::uint8_t opcode, std::uint32_t service_id, std::uint32_t call_id,
                                        std::string_view encoding, std::string_view payload) {
  std::string out;
  out.reserve(13 + encoding.size() + payload.size());
  out.push_back(static_cast<char>(opcode));
  put_u32(out, service_id);
  put_u32(out, call_id);
  put_u32(out, static_cast<std::uint32_t>(encoding.size()));
  out.append(encoding);
  out.append(payload);
  return out;
}

std::string encode_service_call_response(std::uint32_t service_id, std::uint32_t call_id,
                                         std::string_view encoding, std::string_view payload) {
  return encode_service_frame(static_cast<std::uint8_t>(ServerBinaryOp::kServiceCallResponse), service_id,
                              call_id, encoding, payload);
}

std::string encode_service_call_request(std::uint32_t service_id, std::uint32_t call_id,
                                        std::string_view encoding, std::string_view payload) {
  return encode_service_frame(static_cast<std::uint8_t>(ClientBinaryOp::kServiceCallRequest), service_id,
                              call_id, encoding, payload);
}

std::string encode_client_message_data(std::uint32_t channel_id, std::string_view payload) {
  std::string out;
  out.push_back(static_cast<char>(ClientBinaryOp::kMessageData));
  put_u32(out, channel_id);
  out.append(payload);
  return out;
}

std::optional<MessageData> parse_message_data(std::string_view data) {
  if (data.size() < kMessageDataHeaderBytes || static_cast<std::uint8_t>(data[0]) != 0x01)
    return std::nullopt;
  return MessageData{get_u32(data, 1), get_u64(data, 5), data.substr(kMessageDataHeaderBytes)};
}

std::optional<ServiceCallRequest> parse_service_call_response(std::string_view data) {
  if (data.size() < 13 || static_cast<std::uint8_t>(data[0]) != 0x03) return std::nullopt;
  ServiceCallRequest response;
  response.service_id = get_u32(data, 1);
  response.call_id = get_u32(data, 5);
  const std::uint32_t encoding_length = get_u32(data, 9);
  if (encoding_length > data.size() - 13) return std::nullopt;
  response.encoding = data.substr(13, encoding_length);
  response.payload = data.substr(13 + encoding_length);
  return response;
}

namespace {

bool ends_with(const std::string& s, std::string_view suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

json number_array() { return {{"type", "array"}, {"items", {{"type", "number"}}}}; }

json joint_state_schema() {
  return {{"title", "tendril.JointState"},
          {"type", "object"},
          {"properties",
           {{"name", {{"type", "array"}, {"items", {{"type", "string"}}}}},
            {"position", number_array()},
            {"velocity", number_array()},
            {"effort", number_array()},
            {"setpoint_position", number_array()},
            {"setpoint_velocity", number_array()},
            {"timestamp", {{"type", "number"}}}}}};
}

json operating_state_schema() {
  return {{"title", "tendril.OperatingState"},
          {"type", "object"},
          {"properties",
           {{"state", {{"type", "string"}, {"enum", {"DISABLED", "ENABLED", "PAUSED", "FAULT"}}}},
            {"mode", {{"type", "string"}}},
            {"is_homed", {{"type", "boolean"}}},
            {"is_busy", {{"type", "boolean"}}},
            {"estop", {{"type", "boolean"}}}}}};
}

// A message carries the events new since the previous one and the most recent ones again (`recent`,
// oldest first): a slow reader gets only a topic's newest message, and `recent` fills what it missed.
json safety_event_schema() {
  const json event = {{"type", "object"},
                      {"properties",
                       {{"time", {{"type", "number"}}},
                        {"robot", {{"type", "string"}}},
                        {"kind", {{"type", "string"}}},
                        {"code", {{"type", "string"}}},
                        {"from", {{"type", "string"}}},
                        {"to", {{"type", "string"}}},
                        {"joint", {{"type", "string"}}},
                        {"message", {{"type", "string"}}}}}};
  const json list = {{"type", "array"}, {"items", event}};
  return {{"title", "tendril.SafetyEvent"},
          {"type", "object"},
          {"properties", {{"events", list}, {"recent", list}}}};
}

// Shape of foxglove.SceneUpdate (foxglove-sdk schemas/jsonschema), reduced to the top level:
// panels key on the schema name, the full entity schema is Foxglove's.
json scene_update_schema() {
  return {{"title", "foxglove.SceneUpdate"},
          {"type", "object"},
          {"properties",
           {{"deletions", {{"type", "array"}, {"items", {{"type", "object"}}}}},
            {"entities", {{"type", "array"}, {"items", {{"type", "object"}}}}}}}};
}

json frame_transforms_schema() {
  return {{"title", "foxglove.FrameTransforms"},
          {"type", "object"},
          {"properties", {{"transforms", {{"type", "array"}, {"items", {{"type", "object"}}}}}}}};
}

}  // namespace

Channel channel_for_topic(std::uint32_t id, const std::string& topic) {
  Channel channel;
  channel.id = id;
  channel.topic = topic;
  json schema;
  if (ends_with(topic, "/joint_states")) {
    channel.schema_name = "tendril.JointState";
    schema = joint_state_schema();
  } else if (ends_with(topic, "/operating_state")) {
    channel.schema_name = "tendril.OperatingState";
    schema = operating_state_schema();
  } else if (topic == "/safety/events") {
    channel.schema_name = "tendril.SafetyEvent";
    schema = safety_event_schema();
  } else if (ends_with(topic, "/scene")) {
    channel.schema_name = "foxglove.SceneUpdate";
    schema = scene_update_schema();
  } else if (topic == "/tf") {
    channel.schema_name = "foxglove.FrameTransforms";
    schema = frame_transforms_schema();
  } else if (ends_with(topic, "/diagnostics")) {
    // Control-loop health at 10 Hz (robot_api.cpp diagnostics()).
    const json numbers = {{"type", "array"}, {"items", {{"type", "number"}}}};
    const json quantiles = {
        {"type", "object"},
        {"properties",
         {{"p50", {{"type", "number"}}}, {"p99", {{"type", "number"}}}, {"max", {{"type", "number"}}}}}};
    channel.schema_name = "tendril.LoopDiagnostics";
    schema = {{"title", "tendril.LoopDiagnostics"},
              {"type", "object"},
              {"properties",
               {{"timestamp", {{"type", "object"}}},
                {"nominal_period_us", {{"type", "number"}}},
                {"period_us", quantiles},
                {"work_us", quantiles},
                {"overruns", {{"type", "integer"}}},
                {"late_cycles", {{"type", "integer"}}},
                {"lost_max_us", {{"type", "number"}}},
                {"bus_load", {{"type", "number"}}},
                {"setpoint", numbers},
                {"measured", numbers}}}};
  } else {
    channel.schema_name = "tendril.Json";
    schema = {{"title", "tendril.Json"}, {"type", "object"}};
  }
  channel.schema = schema.dump();
  return channel;
}

json server_info(const std::string& name, const std::vector<std::string>& capabilities, const json& metadata,
                 const std::string& session_id) {
  return {{"op", "serverInfo"},           {"name", name},
          {"capabilities", capabilities}, {"supportedEncodings", {"json"}},
          {"metadata", metadata},         {"sessionId", session_id}};
}

void append_base64(const std::uint8_t* data, std::size_t size, std::string& out) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const std::size_t start = out.size();
  out.resize(start + (size + 2) / 3 * 4);
  char* p = out.data() + start;
  std::size_t i = 0;
  for (; i + 3 <= size; i += 3) {
    const std::uint32_t v = (std::uint32_t{data[i]} << 16) | (std::uint32_t{data[i + 1]} << 8) | data[i + 2];
    *p++ = kAlphabet[(v >> 18) & 63];
    *p++ = kAlphabet[(v >> 12) & 63];
    *p++ = kAlphabet[(v >> 6) & 63];
    *p++ = kAlphabet[v & 63];
  }
  if (i < size) {
    std::uint32_t v = std::uint32_t{data[i]} << 16;
    if (i + 1 < size) v |= std::uint32_t{data[i + 1]} << 8;
    *p++ = kAlphabet[(v >> 18) & 63];
    *p++ = kAlphabet[(v >> 12) & 63];
    *p++ = i + 1 < size ? kAlphabet[(v >> 6) & 63] : '=';
    *p = '=';
  }
}

json advertise(const std::vector<Channel>& channels) {
  json list = json::array();
  for (const auto& c : channels) {
    std::string schema;
    if (c.schema_encoding == "jsonschema") {
      schema = c.schema;
    } else {
      append_base64(reinterpret_cast<const std::uint8_t*>(c.schema.data()), c.schema.size(), schema);
    }
    list.push_back({{"id", c.id},
                    {"topic", c.topic},
                    {"encoding", c.encoding},
                    {"schemaName", c.schema_name},
                    {"schema", std::move(schema)},
                    {"schemaEncoding", c.schema_encoding}});
  }
  return {{"op", "advertise"}, {"channels", std::move(list)}};
}

json unadvertise(const std::vector<std::uint32_t>& channel_ids) {
  return {{"op", "unadvertise"}, {"channelIds", channel_ids}};
}

json advertise_services(const std::vector<Service>& services) {
  json list = json::array();
  for (const auto& s : services) {
    // Both the current (request/response objects) and the older (requestSchema/responseSchema) forms,
    // so clients of either revision of the spec understand it.
    list.push_back({{"id", s.id},
                    {"name", s.name},
                    {"type", s.type},
                    {"request",
                     {{"encoding", "json"},
                      {"schemaName", s.type + "_Request"},
                      {"schemaEncoding", "jsonschema"},
                      {"schema", s.request_schema}}},
                    {"response",
                     {{"encoding", "json"},
                      {"schemaName", s.type + "_Response"},
                      {"schemaEncoding", "jsonschema"},
                      {"schema", s.response_schema}}},
                    {"requestSchema", s.request_schema},
                    {"responseSchema", s.response_schema}});
  }
  return {{"op", "advertiseServices"}, {"services", std::move(list)}};
}

json status(StatusLevel level, const std::string& message, const std::string& id) {
  json out = {{"op", "status"}, {"level", static_cast<int>(level)}, {"message", message}};
  if (!id.empty()) out["id"] = id;
  return out;
}

json remove_status(const std::vector<std::string>& ids) {
  return {{"op", "removeStatus"}, {"statusIds", ids}};
}

json parameter_values(const json& parameters, const std::optional<std::string>& id) {
  json out = {{"op", "parameterValues"}, {"parameters", parameters}};
  if (id) out["id"] = *id;
  return out;
}

json service_call_failure(std::uint32_t service_id, std::uint32_t call_id, const std::string& message) {
  return {{"op", "serviceCallFailure"}, {"serviceId", service_id}, {"callId", call_id}, {"message", message}};
}

}  // namespace tendril::server::http::foxglove
