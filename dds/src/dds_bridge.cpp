// DdsBridge (dds_bridge.hpp): tendrild's DDS participant. The publisher thread turns the runtime's
// read-outs into ROS 2 and tendril_msgs samples; the command thread takes command samples and hands
// them to the server's command path.
#include "tendril/dds/dds_bridge.hpp"

#include <dds/dds.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <iostream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include "tendril/dds/wire.hpp"
#include "tendril/safety/safety_types.hpp"

namespace tendril::dds {
namespace {

using Clock = std::chrono::steady_clock;

// An entity that deletes itself (and, for a participant, everything under it).
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t e) : e_(e) {}
  ~Entity() { reset(); }
  Entity(Entity&& o) noexcept : e_(std::exchange(o.e_, 0)) {}
  Entity& operator=(Entity&& o) noexcept {
    if (this != &o) {
      reset();
      e_ = std::exchange(o.e_, 0);
    }
    return *this;
  }
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  dds_entity_t get() const { return e_; }
  void reset() {
    if (e_ > 0) dds_delete(e_);
    e_ = 0;
  }

 private:
  dds_entity_t e_ = 0;
};

dds_entity_t check(dds_entity_t e, const std::string& what) {
  if (e < 0) throw DdsError("DDS: cannot create " + what + ": " + retcode_text(e));
  return e;
}

// A string the sample owns only while it is written: Cyclone copies it during dds_write.
char* text(const std::string& s) { return const_cast<char*>(s.c_str()); }

// Joint-command samples are cut to this many values before anything else looks at them: more than any
// robot has joints, and little enough that a hostile sample cannot make the bridge build a large body.
constexpr std::uint32_t kMaxCommandValues = 64;
// Writers remembered for the rate limit; the one seen least recently is forgotten first.
constexpr std::size_t kMaxRateBuckets = 1024;
// Samples taken from one reader per wake-up.
constexpr int kTakeBatch = 32;

// The public label of a DDS commander: "dds:" and its client field cut to what X-Tendril-Client allows.
std::string client_label(const char* client) {
  std::string name;
  if (client) {
    for (const char* c = client; *c && name.size() < 64; ++c) {
      const char ch = *c;
      if ((ch >= 'A' && ch <= 'Z') || (ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9') || ch == '.' ||
          ch == '_' || ch == '-')
        name += ch;
    }
  }
  return "dds:" + (name.empty() ? std::string("anonymous") : name);
}

double wall_seconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

}  // namespace

struct DdsBridge::Impl {
  const server::RobotService& robots;
  CommandGate gate;
  DdsOptions opts;

  Entity participant;
  Entity events_topic, events_writer;
  Entity waitset, stop_guard;

  enum class CommandKind { kServoJv, kMoveJp, kStateCommand };
  struct CommandReader {
    std::size_t robot = 0;
    CommandKind kind;
    Entity topic, reader, condition;
  };
  struct RobotIo {
    std::string name;
    std::string base_frame;
    Entity js_topic, js_writer, os_topic, os_writer, pose_topic, pose_writer, result_topic, result_writer;
    Entity shape_topic, shape_writer;
    std::uint64_t last_tick = 0;
    bool has_tick = false;
    double last_shape_time = -1.0;
  };
  struct MapIo {
    std::size_t index = 0;  // in opts.maps
    Entity topic, writer;
  };
  std::vector<MapIo> map_io;
  std::vector<RobotIo> robot_io;
  std::vector<CommandReader> readers;
  std::uint64_t events_seen = 0;
  bool events_primed = false;

  // Rate limit per DDS publication (writer).
  struct Bucket {
    double tokens = 0;
    Clock::time_point refilled, last_used;
    bool has_id = false;
    std::uint32_t last_id = 0;  // the writer's last request_id, to count the samples that never came
  };
  std::unordered_map<dds_instance_handle_t, Bucket> buckets;  // command thread only

  // Metrics.
  std::atomic<std::uint64_t> published_state{0}, published_events{0}, published_maps{0}, publish_errors{0},
      commands_lost{0};
  mutable std::mutex counts_mutex;
  std::map<int, std::uint64_t> commands_by_status;
  std::map<std::string, std::uint64_t> refused_by_code;

  std::mutex lifecycle_mutex;
  std::condition_variable wake;
  bool running = false, stopping = false;
  std::thread publisher, commander;

  Impl(const server::RobotService& r, CommandGate g, DdsOptions o)
      : robots(r), gate(std::move(g)), opts(std::move(o)) {}

  void log(const std::string& line) const {
    if (opts.log)
      opts.log(line);
    else
      std::cerr << "tendrild: dds: " << line << std::endl;
  }

  void create() {
    if (opts.domain > 232)
      throw DdsError("DDS domain " + std::to_string(opts.domain) + " is out of range: expected 0 to 232");
    if (!(opts.publish_rate_hz > 0) || !std::isfinite(opts.publish_rate_hz))
      throw DdsError("DDS publish rate must be a positive number of Hz");
    participant = Entity(check(
        dds_create_participant(static_cast<dds_domainid_t>(opts.domain), nullptr, nullptr),
        "the participant in domain " + std::to_string(opts.domain) + " (check CYCLONEDDS_URI if it is set)"));
    const dds_entity_t p = participant.get();
    auto make_writer = [&](Entity& topic, Entity& writer, const dds_topic_descriptor_t* type,
                           const std::string& name, TopicKind kind) {
      dds_qos_t* qos = make_qos(kind);
      topic = Entity(check(dds_create_topic(p, type, name.c_str(), qos, nullptr), "topic " + name));
      writer = Entity(check(dds_create_writer(p, topic.get(), qos, nullptr), "the writer of " + name));
      dds_delete_qos(qos);
    };
    make_writer(events_topic, events_writer, &tendril_msgs_msg_dds__SafetyEvent__desc, kSafetyEventsTopic,
                TopicKind::kEvent);
    waitset = Entity(check(dds_create_waitset(p), "the command waitset"));
    stop_guard = Entity(check(dds_create_guardcondition(p), "the stop guard condition"));
    check(dds_waitset_attach(waitset.get(), stop_guard.get(), -1), "the stop guard's attachment");
    for (const auto& description : robots.robots()) {
      RobotIo io;
      io.name = description.name;
      io.base_frame = description.name + "_base";
      make_writer(io.js_topic, io.js_writer, &sensor_msgs_msg_dds__JointState__desc,
                  robot_topic(io.name, kJointStates), TopicKind::kState);
      make_writer(io.os_topic, io.os_writer, &tendril_msgs_msg_dds__OperatingState__desc,
                  robot_topic(io.name, kOperatingState), TopicKind::kState);
      make_writer(io.pose_topic, io.pose_writer, &geometry_msgs_msg_dds__PoseStamped__desc,
                  robot_topic(io.name, kTipPose), TopicKind::kState);
      make_writer(io.shape_topic, io.shape_writer, &geometry_msgs_msg_dds__PoseArray__desc,
                  robot_topic(io.name, kBackbone), TopicKind::kState);
      make_writer(io.result_topic, io.result_writer, &tendril_msgs_msg_dds__CommandResult__desc,
                  robot_topic(io.name, kCommandResult), TopicKind::kResult);
      robot_io.push_back(std::move(io));
    }
    for (std::size_t m = 0; m < opts.maps.size(); ++m) {
      const auto& map = opts.maps[m];
      if (map.name.empty() || map.name.find_first_of("/ ") != std::string::npos)
        throw DdsError("DDS map name '" + map.name + "' must be a non-empty topic leaf (no '/' or space)");
      MapIo io;
      io.index = m;
      make_writer(io.topic, io.writer, &sensor_msgs_msg_dds__PointCloud2__desc, map_topic(map.name),
                  TopicKind::kMap);
      map_io.push_back(std::move(io));
    }
    readers.reserve(robot_io.size() * 3);
    for (std::size_t r = 0; r < robot_io.size(); ++r) {
      const std::pair<CommandKind, const char*> kinds[] = {{CommandKind::kServoJv, kServoJv},
                                                           {CommandKind::kMoveJp, kMoveJp},
                                                           {CommandKind::kStateCommand, kStateCommand}};
      for (const auto& [kind, leaf] : kinds) {
        CommandReader cr;
        cr.robot = r;
        cr.kind = kind;
        const std::string name = robot_topic(robot_io[r].name, leaf);
        const dds_topic_descriptor_t* type = kind == CommandKind::kStateCommand
                                                 ? &tendril_msgs_msg_dds__StateCommand__desc
                                                 : &tendril_msgs_msg_dds__JointCommand__desc;
        dds_qos_t* qos = make_qos(TopicKind::kCommand);
        cr.topic = Entity(check(dds_create_topic(p, type, name.c_str(), qos, nullptr), "topic " + name));
        cr.reader =
            Entity(check(dds_create_reader(p, cr.topic.get(), qos, nullptr), "the reader of " + name));
        dds_delete_qos(qos);
        cr.condition = Entity(
            check(dds_create_readcondition(cr.reader.get(), DDS_ANY_STATE), "the condition of " + name));
        readers.push_back(std::move(cr));
        check(dds_waitset_attach(waitset.get(), readers.back().condition.get(),
                                 static_cast<dds_attach_t>(readers.size() - 1)),
              "the attachment of " + name);
      }
    }
  }

  // ---- publishing ----

  void count_write(dds_return_t rc, std::atomic<std::uint64_t>& ok) {
    if (rc == DDS_RETCODE_OK)
      ok.fetch_add(1, std::memory_order_relaxed);
    else
      publish_errors.fetch_add(1, std::memory_order_relaxed);
  }

  void publish_robot(RobotIo& io) {
    if (const auto js = robots.measured_js(io.name); js.ok() && (!io.has_tick || js->tick != io.last_tick)) {
      io.has_tick = true;
      io.last_tick = js->tick;
      count_write(write_joint_state(io.js_writer.get(), js->timestamp, io.base_frame, js->name, js->position,
                                    js->velocity, js->effort),
                  published_state);
    }
    if (const auto os = robots.operating_state(io.name); os.ok()) {
      const std::string state = safety::to_string(os->state);
      const std::string fault_code = os->fault ? os->fault->code : std::string();
      const std::string fault_message = os->fault ? os->fault->message : std::string();
      tendril_msgs_msg_dds__OperatingState_ m{};
      m.header.stamp = to_time(os->timestamp);
      m.header.frame_id = text(io.base_frame);
      m.robot = text(io.name);
      m.state = text(state);
      m.mode = text(os->mode);
      m.is_busy = os->busy;
      m.estop = os->estop;
      m.drives_ready = os->drives_ready;
      m.fault_code = text(fault_code);
      m.fault_message = text(fault_message);
      count_write(dds_write(io.os_writer.get(), &m), published_state);
    }
    if (const auto cp = robots.measured_cp(io.name); cp.ok()) {
      const std::string frame = cp->frame.empty() ? io.base_frame : cp->frame;
      geometry_msgs_msg_dds__PoseStamped_ m{};
      m.header.stamp = to_time(cp->timestamp);
      m.header.frame_id = text(frame);
      // ROS 2 poses are in metres (REP 103); tendril's API speaks mm.
      m.pose.position.x = cp->position.x() * 1e-3;
      m.pose.position.y = cp->position.y() * 1e-3;
      m.pose.position.z = cp->position.z() * 1e-3;
      m.pose.orientation.x = cp->orientation.x();
      m.pose.orientation.y = cp->orientation.y();
      m.pose.orientation.z = cp->orientation.z();
      m.pose.orientation.w = cp->orientation.w();
      count_write(dds_write(io.pose_writer.get(), &m), published_state);
    }
  }

  // The backbone as geometry_msgs/PoseArray in metres: each pose at a backbone point, its z axis along
  // the backbone towards the tip (the last pose keeps the previous direction).
  void publish_shape(RobotIo& io) {
    const auto shape = robots.shape(io.name);
    if (!shape.ok() || shape->points.size() < 2 || shape->timestamp == io.last_shape_time) return;
    io.last_shape_time = shape->timestamp;
    const auto& points = shape->points;
    std::vector<geometry_msgs_msg_dds__Pose_> poses(points.size());
    Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
    for (std::size_t i = 0; i < points.size(); ++i) {
      if (i + 1 < points.size()) {
        const Eigen::Vector3d along = points[i + 1] - points[i];
        if (along.norm() > 1e-9)
          orientation = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), along);
      }
      auto& pose = poses[i];
      pose.position.x = points[i].x() * 1e-3;
      pose.position.y = points[i].y() * 1e-3;
      pose.position.z = points[i].z() * 1e-3;
      pose.orientation.x = orientation.x();
      pose.orientation.y = orientation.y();
      pose.orientation.z = orientation.z();
      pose.orientation.w = orientation.w();
    }
    const std::string frame = shape->frame.empty() ? io.base_frame : shape->frame;
    geometry_msgs_msg_dds__PoseArray_ m{};
    m.header.stamp = to_time(shape->timestamp);
    m.header.frame_id = text(frame);
    m.poses._length = m.poses._maximum = static_cast<std::uint32_t>(poses.size());
    m.poses._buffer = poses.data();
    count_write(dds_write(io.shape_writer.get(), &m), published_state);
  }

  // Each map once, as sensor_msgs/PointCloud2: one row of x, y, z float32 (metres, little-endian).
  void publish_maps() {
    for (const auto& io : map_io) {
      const auto& map = opts.maps[io.index];
      std::vector<std::uint8_t> data(map.points_mm.size() * 12);
      for (std::size_t i = 0; i < map.points_mm.size(); ++i) {
        const float xyz[3] = {map.points_mm[i].x() * 1e-3f, map.points_mm[i].y() * 1e-3f,
                              map.points_mm[i].z() * 1e-3f};
        std::memcpy(data.data() + i * 12, xyz, 12);
      }
      char x[] = "x", y[] = "y", z[] = "z";
      sensor_msgs_msg_dds__PointField_ fields[3] = {{x, 0, 7, 1}, {y, 4, 7, 1}, {z, 8, 7, 1}};  // FLOAT32
      sensor_msgs_msg_dds__PointCloud2_ m{};
      const auto now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch());
      m.header.stamp = to_time(now.count());
      m.header.frame_id = text(map.frame_id);
      m.height = 1;
      m.width = static_cast<std::uint32_t>(map.points_mm.size());
      m.fields._length = m.fields._maximum = 3;
      m.fields._buffer = fields;
      m.is_bigendian = std::endian::native == std::endian::big;
      m.point_step = 12;
      m.row_step = static_cast<std::uint32_t>(data.size());
      m.data._length = m.data._maximum = static_cast<std::uint32_t>(data.size());
      m.data._buffer = data.data();
      m.is_dense = true;
      count_write(dds_write(io.writer.get(), &m), published_maps);
    }
  }

  void publish_events() {
    std::uint64_t total = 0;
    auto events = robots.events_since(events_seen, total);
    // Events logged before the bridge started are in GET /api/v1/faults; DDS carries what happens
    // while it runs.
    if (!events_primed) {
      events_primed = true;
      events_seen = total;
      return;
    }
    events_seen = total;
    for (const auto& e : events) {
      tendril_msgs_msg_dds__SafetyEvent_ m{};
      m.header.stamp = to_time(e.time);
      m.header.frame_id = const_cast<char*>("");
      m.robot = text(e.robot);
      m.kind = text(e.kind);
      m.code = text(e.code);
      m.from_state = text(e.from);
      m.to_state = text(e.to);
      m.joint = text(e.joint);
      m.message = text(e.message);
      count_write(dds_write(events_writer.get(), &m), published_events);
    }
  }

  void publish_once() {
    for (auto& io : robot_io) {
      publish_robot(io);
      publish_shape(io);
    }
    publish_events();
  }

  void publisher_loop() {
    const auto period = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(1.0 / opts.publish_rate_hz));
    auto next = Clock::now();
    std::unique_lock lock(lifecycle_mutex);
    while (!stopping) {
      lock.unlock();
      try {
        publish_once();
      } catch (const std::exception& e) {
        publish_errors.fetch_add(1, std::memory_order_relaxed);
        log(std::string("publishing failed: ") + e.what());
      }
      lock.lock();
      next += period;
      const auto now = Clock::now();
      if (next < now) next = now;  // a late pass is not made up for with a burst
      wake.wait_until(lock, next, [&] { return stopping; });
    }
  }

  // ---- commands ----

  // One token of the writer's bucket; false when it has none left. `request_id` numbers the writer's
  // samples: a gap means samples that never reached the bridge (overwritten in the reader's keep-last
  // history by a flood faster than the bridge takes them, or lost), counted as lost.
  bool take_token(dds_instance_handle_t writer, std::uint32_t request_id) {
    const auto now = Clock::now();
    auto it = buckets.find(writer);
    if (it == buckets.end()) {
      if (buckets.size() >= kMaxRateBuckets) {
        auto oldest = std::min_element(buckets.begin(), buckets.end(), [](const auto& a, const auto& b) {
          return a.second.last_used < b.second.last_used;
        });
        buckets.erase(oldest);
      }
      Bucket fresh;
      fresh.tokens = opts.command_burst;
      fresh.refilled = fresh.last_used = now;
      it = buckets.emplace(writer, fresh).first;
    }
    Bucket& b = it->second;
    // A gap up to a million; a larger jump or a step back is a writer that started counting anew.
    // A writer numbers its samples from 0 (dds/README.md), so the first one taken counts those before it
    // too: a flood overwrites the oldest in the reader's history before the bridge's first take, and
    // counted only between taken samples, those were missing from the total (a test run: 57).
    if (b.has_id && request_id > b.last_id && request_id - b.last_id <= 1'000'000)
      commands_lost.fetch_add(request_id - b.last_id - 1, std::memory_order_relaxed);
    else if (!b.has_id && request_id <= 1'000'000)
      commands_lost.fetch_add(request_id, std::memory_order_relaxed);
    b.has_id = true;
    b.last_id = request_id;
    const double elapsed = std::chrono::duration<double>(now - b.refilled).count();
    b.tokens = std::min(opts.command_burst, b.tokens + elapsed * opts.command_rate_hz);
    b.refilled = now;
    b.last_used = now;
    if (b.tokens < 1.0) return false;
    b.tokens -= 1.0;
    return true;
  }

  void answer(const RobotIo& io, const std::string& command, const std::string& client,
              std::uint32_t request_id, const server::ApiResult& result) {
    {
      std::lock_guard lock(counts_mutex);
      ++commands_by_status[result.status];
      if (!result.ok()) ++refused_by_code[result.code];
    }
    tendril_msgs_msg_dds__CommandResult_ m{};
    m.header.stamp = to_time(wall_seconds());
    m.header.frame_id = const_cast<char*>("");
    m.client = text(client);
    m.request_id = request_id;
    m.command = text(command);
    m.status = result.status;
    m.code = text(result.code);
    m.message = text(result.message);
    if (dds_write(io.result_writer.get(), &m) != DDS_RETCODE_OK)
      publish_errors.fetch_add(1, std::memory_order_relaxed);
  }

  server::ApiResult run(const RobotIo& io, const std::string& command, const nlohmann::json& body,
                        const char* lease_token, const std::string& client) {
    try {
      return gate(io.name, command, body, lease_token ? lease_token : "", client);
    } catch (const std::exception& e) {
      return server::ApiResult::error(500, "internal_error", e.what());
    }
  }

  void handle(CommandReader& cr) {
    std::array<void*, kTakeBatch> samples{};  // null: Cyclone lends its own buffers
    std::array<dds_sample_info_t, kTakeBatch> infos{};
    const dds_return_t n = dds_take(cr.reader.get(), samples.data(), infos.data(), kTakeBatch, kTakeBatch);
    if (n <= 0) return;
    // The loan goes back however this pass ends.
    struct Loan {
      dds_entity_t reader;
      void** samples;
      dds_return_t n;
      ~Loan() { dds_return_loan(reader, samples, n); }
    } loan{cr.reader.get(), samples.data(), n};
    const RobotIo& io = robot_io[cr.robot];
    for (dds_return_t i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      if (cr.kind == CommandKind::kStateCommand) {
        const auto* c = static_cast<const tendril_msgs_msg_dds__StateCommand_*>(samples[i]);
        const bool allowed = take_token(infos[i].publication_handle, c->request_id);
        const std::string client = client_label(c->client);
        if (!allowed) {
          answer(io, kStateCommand, client, c->request_id, rate_limited());
          continue;
        }
        const nlohmann::json body = {{"command", c->command ? c->command : ""}};
        answer(io, kStateCommand, client, c->request_id,
               run(io, kStateCommand, body, c->lease_token, client));
      } else {
        const auto* c = static_cast<const tendril_msgs_msg_dds__JointCommand_*>(samples[i]);
        const bool allowed = take_token(infos[i].publication_handle, c->request_id);
        const std::string client = client_label(c->client);
        const char* command = cr.kind == CommandKind::kServoJv ? kServoJv : kMoveJp;
        if (!allowed) {
          answer(io, command, client, c->request_id, rate_limited());
          continue;
        }
        if (c->values._length > kMaxCommandValues) {
          answer(io, command, client, c->request_id,
                 server::ApiResult::error(
                     422, "wrong_size",
                     std::to_string(c->values._length) + " values: more than any robot has joints"));
          continue;
        }
        // The REST body of the same command; a non-finite value stays one (nlohmann keeps NaN and
        // infinities as numbers) so the runtime's check refuses it as it would any other.
        nlohmann::json values = nlohmann::json::array();
        for (std::uint32_t k = 0; k < c->values._length; ++k) values.push_back(c->values._buffer[k]);
        const nlohmann::json body = {
            {cr.kind == CommandKind::kServoJv ? "velocity" : "goal", std::move(values)}};
        answer(io, command, client, c->request_id, run(io, command, body, c->lease_token, client));
      }
    }
  }

  server::ApiResult rate_limited() const {
    std::ostringstream m;
    m << "more than " << opts.command_rate_hz << " commands/s (burst " << opts.command_burst
      << ") from this DDS writer; this sample was dropped";
    return server::ApiResult::error(429, "rate_limited", m.str());
  }

  void command_loop() {
    std::vector<dds_attach_t> triggered(readers.size() + 1);
    for (;;) {
      {
        std::lock_guard lock(lifecycle_mutex);
        if (stopping) return;
      }
      const dds_return_t n =
          dds_waitset_wait(waitset.get(), triggered.data(), triggered.size(), DDS_MSECS(500));
      if (n < 0) {
        log("waiting for commands failed: " + retcode_text(n));
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        continue;
      }
      for (dds_return_t i = 0; i < n; ++i) {
        if (triggered[i] < 0 || static_cast<std::size_t>(triggered[i]) >= readers.size()) continue;
        try {
          handle(readers[static_cast<std::size_t>(triggered[i])]);
        } catch (const std::exception& e) {
          log(std::string("a command sample was dropped: ") + e.what());
        }
      }
    }
  }
};

DdsBridge::DdsBridge(const server::RobotService& robots, CommandGate gate, DdsOptions options)
    : impl_(std::make_unique<Impl>(robots, std::move(gate), std::move(options))) {
  impl_->create();
}

DdsBridge::~DdsBridge() {
  stop();
  // Readers and writers before the participant that owns them (the participant's deletion would
  // take them along, but our handles would then name deleted entities).
  impl_->readers.clear();
  impl_->robot_io.clear();
  impl_->events_writer.reset();
  impl_->events_topic.reset();
  impl_->stop_guard.reset();
  impl_->waitset.reset();
  impl_->participant.reset();
}

void DdsBridge::start() {
  Impl& s = *impl_;
  std::lock_guard lock(s.lifecycle_mutex);
  if (s.running || s.stopping) return;
  s.running = true;
  s.publish_maps();  // once: transient-local keeps them for whoever subscribes later
  s.publisher = std::thread([&s] { s.publisher_loop(); });
  s.commander = std::thread([&s] { s.command_loop(); });
}

void DdsBridge::stop() {
  Impl& s = *impl_;
  {
    std::lock_guard lock(s.lifecycle_mutex);
    if (!s.running) return;
    s.running = false;
    s.stopping = true;
  }
  s.wake.notify_all();
  dds_set_guardcondition(s.stop_guard.get(), true);
  if (s.publisher.joinable()) s.publisher.join();
  if (s.commander.joinable()) s.commander.join();
}

void DdsBridge::publish_once() { impl_->publish_once(); }

std::uint32_t DdsBridge::domain() const { return impl_->opts.domain; }

std::string DdsBridge::metrics() const {
  const Impl& s = *impl_;
  std::ostringstream out;
  out << "# HELP tendril_dds_samples_published_total DDS samples written, by kind (state: joint states, "
         "operating state, tip pose, backbone; event: safety events; map: maps).\n"
         "# TYPE tendril_dds_samples_published_total counter\n"
      << "tendril_dds_samples_published_total{kind=\"state\"} " << s.published_state.load() << '\n'
      << "tendril_dds_samples_published_total{kind=\"event\"} " << s.published_events.load() << '\n'
      << "tendril_dds_samples_published_total{kind=\"map\"} " << s.published_maps.load() << '\n'
      << "# HELP tendril_dds_write_errors_total DDS writes that failed.\n"
         "# TYPE tendril_dds_write_errors_total counter\n"
      << "tendril_dds_write_errors_total " << s.publish_errors.load() << '\n'
      << "# HELP tendril_dds_commands_total DDS command samples, by the status their REST twin would get.\n"
         "# TYPE tendril_dds_commands_total counter\n";
  std::lock_guard lock(s.counts_mutex);
  out << "# HELP tendril_dds_commands_lost_total DDS command samples that never reached the bridge, from "
         "gaps in each writer's request_id (a flood overwrites the oldest in the reader's keep-last 64).\n"
         "# TYPE tendril_dds_commands_lost_total counter\n"
      << "tendril_dds_commands_lost_total " << s.commands_lost.load() << '\n';
  for (const auto& [status, count] : s.commands_by_status)
    out << "tendril_dds_commands_total{status=\"" << status << "\"} " << count << '\n';
  out << "# HELP tendril_dds_commands_refused_total DDS command samples refused, by error code.\n"
         "# TYPE tendril_dds_commands_refused_total counter\n";
  for (const auto& [code, count] : s.refused_by_code)
    out << "tendril_dds_commands_refused_total{code=\"" << code << "\"} " << count << '\n';
  return out.str();
}

}  // namespace tendril::dds
