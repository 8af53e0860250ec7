// Topic names, QoS and time stamps of tendril's DDS topics (wire.hpp).
#include "tendril/dds/wire.hpp"

#include <algorithm>
#include <cmath>

namespace tendril::dds {

dds_qos_t* make_qos(TopicKind kind) {
  dds_qos_t* qos = dds_create_qos();
  switch (kind) {
    case TopicKind::kState:
      dds_qset_reliability(qos, DDS_RELIABILITY_BEST_EFFORT, 0);
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 1);
      dds_qset_durability(qos, DDS_DURABILITY_VOLATILE);
      break;
    case TopicKind::kEvent:
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
      dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
      break;
    case TopicKind::kCommand:
    case TopicKind::kResult:
      // max_blocking_time bounds how long a write may wait for a full reader history; the bridge
      // never writes commands, and a result write that would block longer is dropped.
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
      dds_qset_durability(qos, DDS_DURABILITY_VOLATILE);
      break;
    case TopicKind::kMap:
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 1);
      dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
      break;
  }
  return qos;
}

dds_return_t write_joint_state(dds_entity_t writer, double stamp_unix_s, const std::string& frame_id,
                               const std::vector<std::string>& name, const std::vector<double>& position,
                               const std::vector<double>& velocity, const std::vector<double>& effort) {
  // The sample only borrows the strings and arrays: Cyclone serialises them during dds_write.
  std::vector<char*> names;
  names.reserve(name.size());
  for (const auto& n : name) names.push_back(const_cast<char*>(n.c_str()));
  auto doubles = [](const std::vector<double>& v) {
    dds_sequence_double s{};
    s._length = s._maximum = static_cast<std::uint32_t>(v.size());
    s._buffer = const_cast<double*>(v.data());
    return s;
  };
  sensor_msgs_msg_dds__JointState_ m{};
  m.header.stamp = to_time(stamp_unix_s);
  m.header.frame_id = const_cast<char*>(frame_id.c_str());
  m.name._length = m.name._maximum = static_cast<std::uint32_t>(names.size());
  m.name._buffer = names.data();
  m.position = doubles(position);
  m.velocity = doubles(velocity);
  m.effort = doubles(effort);
  return dds_write(writer, &m);
}

std::string robot_topic(const std::string& robot, const std::string& leaf) {
  return "rt/" + robot + "/" + leaf;
}

std::string map_topic(const std::string& name) { return "rt/maps/" + name; }

builtin_interfaces_msg_dds__Time_ to_time(double unix_seconds) {
  builtin_interfaces_msg_dds__Time_ t{};
  if (!std::isfinite(unix_seconds) || unix_seconds < 0) return t;
  const double whole = std::floor(unix_seconds);
  t.sec = static_cast<std::int32_t>(whole);
  t.nanosec = static_cast<std::uint32_t>(std::min(999'999'999.0, (unix_seconds - whole) * 1e9));
  return t;
}

double to_seconds(const builtin_interfaces_msg_dds__Time_& t) {
  return static_cast<double>(t.sec) + static_cast<double>(t.nanosec) * 1e-9;
}

std::string retcode_text(dds_return_t rc) {
  const char* text = dds_strretcode(rc);
  return text ? text : "DDS error " + std::to_string(rc);
}

}  // namespace tendril::dds
