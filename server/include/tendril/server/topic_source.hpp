// TopicSource: WebSocket topics that do not come from ControlApi (simulated or real imaging, maps).
// The front end advertises a source's topics next to the robots' and publishes its latest message to
// subscribers with the same newest-only backpressure. A message is serialised once by the source and
// shared by every connection (a 200 KB image is never copied per client).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace tendril::server {

struct TopicInfo {
  std::string topic;        // e.g. "/imaging/ap"
  std::string schema_name;  // e.g. "foxglove.CompressedImage"
  // With the default encodings: the JSON schema text, and the messages are JSON. With "protobuf" for
  // both: the binary FileDescriptorSet (the front end base64s it in its advertisement; a recording
  // stores the bytes), and the messages are protobuf.
  std::string schema;
  std::string encoding = "json";
  std::string schema_encoding = "jsonschema";
  // A session recording keeps this topic even while nobody watches it (a small stream that costs little
  // to make, such as an arm's force); other source topics are produced and recorded only while watched,
  // unless the recording keeps images always (each costs a render).
  bool recorded_always = false;
};

struct TopicPayload {
  std::shared_ptr<const std::string> payload;  // the serialised message (JSON text or protobuf bytes)
  std::uint64_t version = 0;                   // grows with every new message of the topic
  std::uint64_t log_time_ns = 0;               // wall-clock ns for the message header (capture time)
};

class TopicSource {
 public:
  virtual ~TopicSource() = default;
  // The topics this source publishes (stable while the server runs).
  virtual std::vector<TopicInfo> topics() const = 0;
  // The newest message of `topic` if its version is greater than `since_version`. Thread-safe.
  virtual std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const = 0;
  // The server registers a callback that the source calls (from its own thread, cheaply) when a new
  // message is ready, so that it goes out at once instead of at the next publisher tick.
  // By value: implementations keep the callback. The default source is polled only.
  // NOLINTNEXTLINE(performance-unnecessary-value-param)
  virtual void set_ready_callback(std::function<void()> /*ready*/) {}
  // The front end says whether `topic` has subscribers, each time that changes (publisher thread;
  // every topic starts unwatched). A source may produce nothing for a topic nobody watches, e.g. the
  // simulated fluoroscope renders a plane only while someone subscribes to it. Default: ignored.
  virtual void set_demand(const std::string& /*topic*/, bool /*wanted*/) {}
  // Prometheus text appended to GET /metrics.
  virtual std::string metrics() const { return {}; }
};

}  // namespace tendril::server
