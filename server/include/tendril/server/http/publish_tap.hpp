// PublishTap: a second reader of everything the front end publishes and receives, for a recorder.
// The publisher thread tells it each channel it advertises and each message it sends (the payload
// serialised once, shared, not copied), and the network threads each command they executed, with
// who sent it and how it ended. Called off the control thread only; an implementation must return
// at once (queue, never wait on a disk).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

namespace tendril::server::http {

class PublishTap {
 public:
  virtual ~PublishTap() = default;
  // True: fetch and pass on this topic's messages even while no client subscribes to it (a source
  // such as the imaging then produces them).
  virtual bool wants(const std::string& topic, bool from_source) const = 0;
  // `schema` is JSON schema text for schema_encoding "jsonschema", FileDescriptorSet bytes for
  // "protobuf"; `encoding` is the messages' ("json" or "protobuf").
  virtual void channel(std::uint32_t id, const std::string& topic, const std::string& schema_name,
                       const std::string& schema, const std::string& encoding,
                       const std::string& schema_encoding) = 0;
  virtual void message(std::uint32_t id, std::uint64_t log_time_ns,
                       std::shared_ptr<const std::string> payload) = 0;
  // A robot command (REST, Foxglove service, client-published stream) once executed. `robot` is empty
  // for the e-stop and its reset.
  virtual void command(std::uint64_t time_ns, const std::string& robot, const std::string& command,
                       const std::string& who, const nlohmann::json& body, int status,
                       const std::string& error) = 0;
};

}  // namespace tendril::server::http
