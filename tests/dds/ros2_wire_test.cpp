// tendril's DDS face as ROS 2 sees it (dds/README.md, ROS 2 compatibility). No ROS 2 installation is
// at hand, so what ROS 2's rmw_cyclonedds would require is asserted from its definitions:
//   - the topics and DDS type names tendrild's bridge registers, read back from DDS discovery (the
//     DCPSPublication and DCPSSubscription built-in topics), with the QoS of each, so that a renamed
//     topic, a changed type name or QoS fails here;
//   - the bytes of a sensor_msgs/JointState and a geometry_msgs/PoseStamped sample on the wire,
//     against an encoder written here from the ROS 2 .msg definitions (plain CDR, little-endian, the
//     .msg field order), in both directions: what tendril writes, and what a ROS 2 node would write,
//     decoded by tendril's types;
//   - which ROS 2 QoS profiles match tendril's state writers.
#include <dds/dds.h>
#include <dds/ddsi/ddsi_serdata.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "tendril/dds/dds_bridge.hpp"
#include "tendril/dds/wire.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"

namespace {

using namespace tendril;
using Clock = std::chrono::steady_clock;
using Bytes = std::vector<unsigned char>;

const std::filesystem::path kSource(TENDRIL_SOURCE_DIR);

// A domain of this test's own (the shell tests use 1-219), loopback only.
std::uint32_t test_domain() { return 220 + static_cast<std::uint32_t>(getpid()) % 13; }

class Ros2WireTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const std::string uri = "file://" + (kSource / "tests/dds/loopback.xml").string();
    setenv("CYCLONEDDS_URI", uri.c_str(), 1);
  }
  void SetUp() override {
    participant = dds_create_participant(test_domain(), nullptr, nullptr);
    ASSERT_GT(participant, 0) << dds::retcode_text(participant);
  }
  void TearDown() override {
    if (participant > 0) dds_delete(participant);
  }
  dds_entity_t participant = 0;
};

// ---- the topics and type names of tendrild's bridge ----

struct Endpoint {
  std::string type;
  dds_reliability_kind_t reliability;
  dds_durability_kind_t durability;
  std::int32_t depth;  // keep-last depth
  bool operator==(const Endpoint&) const = default;
};

std::ostream& operator<<(std::ostream& out, const Endpoint& e) {
  return out << e.type << (e.reliability == DDS_RELIABILITY_RELIABLE ? " reliable" : " best-effort")
             << (e.durability == DDS_DURABILITY_TRANSIENT_LOCAL ? " transient-local" : " volatile")
             << " keep-last " << e.depth;
}

// Topic -> endpoint, for every "rt/..." endpoint discovery has announced on `builtin_topic`, until
// `want` of them are there or 10 s passed.
std::map<std::string, Endpoint> discovered(dds_entity_t participant, dds_entity_t builtin_topic,
                                           std::size_t want) {
  const dds_entity_t reader = dds_create_reader(participant, builtin_topic, nullptr, nullptr);
  std::map<std::string, Endpoint> found;
  const auto give_up = Clock::now() + std::chrono::seconds(10);
  while (found.size() < want && Clock::now() < give_up) {
    void* samples[64] = {};
    dds_sample_info_t infos[64];
    const dds_return_t n = dds_read(reader, samples, infos, 64, 64);
    for (dds_return_t i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const auto* e = static_cast<const dds_builtintopic_endpoint_t*>(samples[i]);
      const std::string topic = e->topic_name ? e->topic_name : "";
      if (topic.rfind("rt/", 0) != 0) continue;
      Endpoint ep{e->type_name ? e->type_name : "", DDS_RELIABILITY_BEST_EFFORT, DDS_DURABILITY_VOLATILE, -1};
      dds_duration_t blocking = 0;
      dds_history_kind_t history = DDS_HISTORY_KEEP_ALL;
      dds_qget_reliability(e->qos, &ep.reliability, &blocking);
      dds_qget_durability(e->qos, &ep.durability);
      dds_qget_history(e->qos, &history, &ep.depth);
      if (history != DDS_HISTORY_KEEP_LAST) ep.depth = -1;
      found[topic] = ep;
    }
    if (n > 0) dds_return_loan(reader, samples, n);
    if (found.size() < want) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  dds_delete(reader);
  return found;
}

TEST_F(Ros2WireTest, BridgeRegistersRos2TopicAndTypeNamesWithTheDocumentedQos) {
  auto robot = server::load_robot_config(kSource / "config/robots/srmc.json");
  robot.settings["catheter"]["simulation"].erase("vessel");
  server::RuntimeOptions o;
  o.stepped = true;  // nothing runs: the bridge only needs the robots' names
  server::RobotRuntime runtime({robot}, o, server::builtin_robot_types());
  dds::DdsOptions options;
  options.domain = test_domain();
  options.log = [](const std::string&) {};
  options.maps.push_back(
      {"vessel", "world", {Eigen::Vector3f(0.0f, 0.0f, 0.0f), Eigen::Vector3f(1.0f, 0.0f, 2.0f)}});
  dds::DdsBridge bridge(
      runtime,
      [](const std::string&, const std::string&, const nlohmann::json&, const std::string&,
         const std::string&) { return server::ApiResult::error(503, "test", "no commands in this test"); },
      options);

  constexpr auto kBestEffort = DDS_RELIABILITY_BEST_EFFORT;
  constexpr auto kReliable = DDS_RELIABILITY_RELIABLE;
  constexpr auto kVolatile = DDS_DURABILITY_VOLATILE;
  // The type names are spelled out, not taken from the generated descriptors: they are what ROS 2's
  // rmw_cyclonedds registers for sensor_msgs/msg/JointState and geometry_msgs/msg/PoseStamped
  // ("<package>::msg::dds_::<Type>_"; likewise geometry_msgs/msg/PoseArray and
  // sensor_msgs/msg/PointCloud2), and a reader of another name does not match.
  const std::map<std::string, Endpoint> writers = {
      {"rt/srmc/joint_states", {"sensor_msgs::msg::dds_::JointState_", kBestEffort, kVolatile, 1}},
      {"rt/srmc/measured_cp", {"geometry_msgs::msg::dds_::PoseStamped_", kBestEffort, kVolatile, 1}},
      {"rt/srmc/backbone", {"geometry_msgs::msg::dds_::PoseArray_", kBestEffort, kVolatile, 1}},
      {"rt/maps/vessel",
       {"sensor_msgs::msg::dds_::PointCloud2_", kReliable, DDS_DURABILITY_TRANSIENT_LOCAL, 1}},
      {"rt/srmc/operating_state", {"tendril_msgs::msg::dds_::OperatingState_", kBestEffort, kVolatile, 1}},
      {"rt/srmc/command_result", {"tendril_msgs::msg::dds_::CommandResult_", kReliable, kVolatile, 64}},
      {"rt/safety/events",
       {"tendril_msgs::msg::dds_::SafetyEvent_", kReliable, DDS_DURABILITY_TRANSIENT_LOCAL, 64}},
  };
  const std::map<std::string, Endpoint> readers = {
      {"rt/srmc/servo_jv", {"tendril_msgs::msg::dds_::JointCommand_", kReliable, kVolatile, 64}},
      {"rt/srmc/move_jp", {"tendril_msgs::msg::dds_::JointCommand_", kReliable, kVolatile, 64}},
      {"rt/srmc/state_command", {"tendril_msgs::msg::dds_::StateCommand_", kReliable, kVolatile, 64}},
  };
  EXPECT_EQ(discovered(participant, DDS_BUILTIN_TOPIC_DCPSPUBLICATION, writers.size()), writers);
  EXPECT_EQ(discovered(participant, DDS_BUILTIN_TOPIC_DCPSSUBSCRIPTION, readers.size()), readers);
}

TEST(Ros2Names, TopicNamesAreRos2sMappingOfTheRosTopic) {
  // ROS 2 maps the topic "/srmc/joint_states" onto the DDS topic "rt/srmc/joint_states".
  EXPECT_EQ(dds::robot_topic("srmc", dds::kJointStates), "rt/srmc/joint_states");
  EXPECT_EQ(dds::robot_topic("us_arm", dds::kTipPose), "rt/us_arm/measured_cp");
  EXPECT_STREQ(dds::kSafetyEventsTopic, "rt/safety/events");
  // The generated descriptors carry the same type names as the bridge registers.
  EXPECT_STREQ(sensor_msgs_msg_dds__JointState__desc.m_typename, "sensor_msgs::msg::dds_::JointState_");
  EXPECT_STREQ(geometry_msgs_msg_dds__PoseStamped__desc.m_typename, "geometry_msgs::msg::dds_::PoseStamped_");
}

// ---- the bytes on the wire ----

// Plain CDR (XCDR version 1), little-endian, as ROS 2's rmw_cyclonedds serialises a message
// (rmw_cyclonedds_cpp/src/Serialization.cpp, CDRWriter): a 4-byte encapsulation header 00 01 00 00
// (CDR_LE, options 0), then the fields in .msg order, each primitive aligned to its size counted from
// the end of the header (8 for float64), strings as a uint32 length with the terminating NUL and the
// bytes, sequences as a uint32 count and the elements; no padding at the end.
class Ros2Cdr {
 public:
  Ros2Cdr& i32(std::int32_t v) { return raw(&v, 4, 4); }
  Ros2Cdr& u32(std::uint32_t v) { return raw(&v, 4, 4); }
  Ros2Cdr& f64(double v) { return raw(&v, 8, 8); }
  Ros2Cdr& str(const std::string& s) {
    u32(static_cast<std::uint32_t>(s.size() + 1));
    bytes_.insert(bytes_.end(), s.begin(), s.end());
    bytes_.push_back(0);
    return *this;
  }
  // builtin_interfaces/Time stamp, string frame_id
  Ros2Cdr& header(std::int32_t sec, std::uint32_t nanosec, const std::string& frame_id) {
    return i32(sec).u32(nanosec).str(frame_id);
  }
  Ros2Cdr& f64s(const std::vector<double>& v) {
    u32(static_cast<std::uint32_t>(v.size()));
    for (const double x : v) f64(x);
    return *this;
  }
  Bytes done() const {
    Bytes out = {0x00, 0x01, 0x00, 0x00};
    out.insert(out.end(), bytes_.begin(), bytes_.end());
    return out;
  }

 private:
  Ros2Cdr& raw(const void* v, std::size_t size, std::size_t alignment) {
    while (bytes_.size() % alignment != 0) bytes_.push_back(0);
    const auto* p = static_cast<const unsigned char*>(v);
    bytes_.insert(bytes_.end(), p, p + size);  // this machine is little-endian (x86-64, arm64)
    return *this;
  }
  Bytes bytes_;
};

// A topic with a writer and a reader in one participant (delivered in-process, no network).
struct Loop {
  dds_entity_t topic, writer, reader;
  Loop(dds_entity_t participant, const dds_topic_descriptor_t* type, const char* name) {
    dds_qos_t* qos = dds_create_qos();
    dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
    dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
    topic = dds_create_topic(participant, type, name, qos, nullptr);
    writer = dds_create_writer(participant, topic, qos, nullptr);
    reader = dds_create_reader(participant, topic, qos, nullptr);
    dds_delete_qos(qos);
  }
  // The serialised form of the next sample, and the serdata (its type makes more of them).
  std::pair<Bytes, ddsi_serdata*> take_bytes() const {
    ddsi_serdata* sd = nullptr;
    dds_sample_info_t info;
    const auto give_up = Clock::now() + std::chrono::seconds(5);
    while (dds_takecdr(reader, &sd, 1, &info, DDS_ANY_STATE) != 1) {
      if (Clock::now() > give_up) return {{}, nullptr};
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    Bytes out(ddsi_serdata_size(sd));
    ddsi_serdata_to_ser(sd, 0, out.size(), out.data());
    return {out, sd};
  }
  // Writes bytes as they came from another node (the serdata's type is the topic's).
  void write_bytes(const ddsi_serdata* like, const Bytes& bytes) const {
    ddsrt_iovec_t iov{};
    iov.iov_base = const_cast<unsigned char*>(bytes.data());
    iov.iov_len = bytes.size();
    ddsi_serdata* sd = ddsi_serdata_from_ser_iov(like->type, SDK_DATA, 1, &iov, bytes.size());
    ASSERT_NE(sd, nullptr);
    ASSERT_EQ(dds_writecdr(writer, sd), DDS_RETCODE_OK);  // takes the reference
  }
  template <class T, class Check>
  void take(Check check) const {
    void* samples[1] = {};
    dds_sample_info_t info;
    const auto give_up = Clock::now() + std::chrono::seconds(5);
    dds_return_t n = 0;
    while ((n = dds_take(reader, samples, &info, 1, 1)) != 1 && Clock::now() < give_up)
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    ASSERT_EQ(n, 1);
    check(*static_cast<const T*>(samples[0]));
    dds_return_loan(reader, samples, 1);
  }
};

std::string hex(const Bytes& b) {
  static const char* digits = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < b.size(); ++i) {
    if (i > 0) out += (i % 4 == 0) ? " | " : " ";
    out += digits[b[i] >> 4];
    out += digits[b[i] & 15];
  }
  return out;
}

// What a ROS 2 reader gets from tendril's bytes: Cyclone pads the body to 4 bytes and counts the
// padding in the options' last two bits (DDS-XTypes 1.3, 7.6.3.1.2); rmw_cyclonedds reads the
// encapsulation identifier (CDR_LE, the first two bytes) and the fields, not the padding. So the
// message is the identifier and the body without that padding, and the options carry nothing else.
Bytes as_ros2_reads_it(const Bytes& written) {
  if (written.size() < 4) return written;
  const std::size_t pad = written[3] & 3u;
  EXPECT_EQ(written[2], 0) << "options other than padding";
  EXPECT_EQ(written[3] & ~3u, 0u) << "options other than padding";
  EXPECT_LE(pad, written.size() - 4);
  Bytes out = {written[0], written[1], 0x00, 0x00};
  out.insert(out.end(), written.begin() + 4, written.end() - static_cast<std::ptrdiff_t>(pad));
  return out;
}

TEST_F(Ros2WireTest, JointStateBytesAreRos2sInBothDirections) {
  const Loop loop(participant, &sensor_msgs_msg_dds__JointState__desc, "rt/wire_test/joint_states");
  ASSERT_GT(loop.reader, 0);
  // Through the bridge's own writer function; an odd-length frame and names exercise the alignment,
  // an empty velocity and a 3-element effort the sequences.
  ASSERT_EQ(dds::write_joint_state(loop.writer, 1700000000.25, "srmc_base", {"insertion", "roll"},
                                   {12.5, -0.75}, {}, {0.5, 1.5, 2.5}),
            DDS_RETCODE_OK);
  const Bytes ros2 = Ros2Cdr()
                         .header(1700000000, 250000000, "srmc_base")
                         .u32(2)
                         .str("insertion")
                         .str("roll")
                         .f64s({12.5, -0.75})
                         .f64s({})
                         .f64s({0.5, 1.5, 2.5})
                         .done();
  auto [written, sd] = loop.take_bytes();
  ASSERT_NE(sd, nullptr) << "no sample came back";
  EXPECT_EQ(hex(as_ros2_reads_it(written)), hex(ros2));

  // A ROS 2 node's sample (frame_id "", one joint) decodes into tendril's type.
  loop.write_bytes(sd, Ros2Cdr().header(3, 7, "").u32(1).str("j").f64s({1.0}).f64s({2.0}).f64s({3.0}).done());
  ddsi_serdata_unref(sd);
  loop.take<sensor_msgs_msg_dds__JointState_>([](const sensor_msgs_msg_dds__JointState_& m) {
    EXPECT_EQ(m.header.stamp.sec, 3);
    EXPECT_EQ(m.header.stamp.nanosec, 7u);
    EXPECT_STREQ(m.header.frame_id, "");
    ASSERT_EQ(m.name._length, 1u);
    EXPECT_STREQ(m.name._buffer[0], "j");
    ASSERT_EQ(m.position._length, 1u);
    ASSERT_EQ(m.velocity._length, 1u);
    ASSERT_EQ(m.effort._length, 1u);
    EXPECT_EQ(m.position._buffer[0], 1.0);
    EXPECT_EQ(m.velocity._buffer[0], 2.0);
    EXPECT_EQ(m.effort._buffer[0], 3.0);
  });
}

TEST_F(Ros2WireTest, PoseStampedBytesAreRos2sInBothDirections) {
  const Loop loop(participant, &geometry_msgs_msg_dds__PoseStamped__desc, "rt/wire_test/measured_cp");
  ASSERT_GT(loop.reader, 0);
  geometry_msgs_msg_dds__PoseStamped_ m{};
  m.header.stamp = dds::to_time(42.5);
  m.header.frame_id = const_cast<char*>("world");
  m.pose.position = {0.01, 0.02, 0.125};
  m.pose.orientation = {0.0, 0.0, 0.70710678118654757, 0.70710678118654757};
  ASSERT_EQ(dds_write(loop.writer, &m), DDS_RETCODE_OK);
  // Header, then geometry_msgs/Pose: Point position (x, y, z), Quaternion orientation (x, y, z, w).
  const Bytes ros2 = Ros2Cdr()
                         .header(42, 500000000, "world")
                         .f64(0.01)
                         .f64(0.02)
                         .f64(0.125)
                         .f64(0.0)
                         .f64(0.0)
                         .f64(0.70710678118654757)
                         .f64(0.70710678118654757)
                         .done();
  auto [written, sd] = loop.take_bytes();
  ASSERT_NE(sd, nullptr) << "no sample came back";
  EXPECT_EQ(hex(as_ros2_reads_it(written)), hex(ros2));

  loop.write_bytes(sd, Ros2Cdr().header(1, 2, "map").f64(1).f64(2).f64(3).f64(0).f64(0).f64(0).f64(1).done());
  ddsi_serdata_unref(sd);
  loop.take<geometry_msgs_msg_dds__PoseStamped_>([](const geometry_msgs_msg_dds__PoseStamped_& p) {
    EXPECT_EQ(p.header.stamp.sec, 1);
    EXPECT_EQ(p.header.stamp.nanosec, 2u);
    EXPECT_STREQ(p.header.frame_id, "map");
    EXPECT_EQ(p.pose.position.x, 1.0);
    EXPECT_EQ(p.pose.position.y, 2.0);
    EXPECT_EQ(p.pose.position.z, 3.0);
    EXPECT_EQ(p.pose.orientation.w, 1.0);
  });
}

// ---- QoS: which ROS 2 subscriptions get tendril's state ----

// Whether a reader with (reliability, depth) on a best-effort keep-last-1 state topic matches its
// writer within 5 s.
bool matches(dds_entity_t participant, const char* name, dds_reliability_kind_t reliability,
             std::int32_t depth) {
  dds_qos_t* state = dds::make_qos(dds::TopicKind::kState);
  const dds_entity_t topic =
      dds_create_topic(participant, &sensor_msgs_msg_dds__JointState__desc, name, state, nullptr);
  const dds_entity_t writer = dds_create_writer(participant, topic, state, nullptr);
  dds_delete_qos(state);
  dds_qos_t* qos = dds_create_qos();
  dds_qset_reliability(qos, reliability, DDS_MSECS(100));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, depth);
  dds_qset_durability(qos, DDS_DURABILITY_VOLATILE);
  const dds_entity_t reader = dds_create_reader(participant, topic, qos, nullptr);
  dds_delete_qos(qos);
  bool matched = false;
  const auto give_up = Clock::now() + std::chrono::seconds(5);
  while (!matched && Clock::now() < give_up) {
    dds_subscription_matched_status_t sm{};
    dds_requested_incompatible_qos_status_t iq{};
    dds_get_subscription_matched_status(reader, &sm);
    dds_get_requested_incompatible_qos_status(reader, &iq);
    matched = sm.current_count > 0;
    if (iq.total_count > 0) break;  // refused for its QoS: it will not match
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  dds_delete(reader);
  dds_delete(writer);
  dds_delete(topic);
  return matched;
}

TEST_F(Ros2WireTest, StateTopicsNeedRos2sSensorDataQos) {
  // rclcpp::SensorDataQoS(): best effort, keep last 5, volatile — matches.
  EXPECT_TRUE(matches(participant, "rt/qos_test/sensor_data", DDS_RELIABILITY_BEST_EFFORT, 5));
  // rclcpp's default subscription QoS: reliable, keep last 10 — a reliable reader is refused by a
  // best-effort writer (dds/README.md: ROS 2 subscribers of tendril's state use the sensor-data profile).
  EXPECT_FALSE(matches(participant, "rt/qos_test/default", DDS_RELIABILITY_RELIABLE, 10));
}

}  // namespace
