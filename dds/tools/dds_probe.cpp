// tendril-dds-probe: a small DDS participant for people and tests. It prints what tendrild publishes
// (one JSON object a line) and sends commands with a lease token, printing tendrild's answer to each.
// It speaks only DDS (Cyclone DDS C API, the types of dds/idl), never tendrild's HTTP API.
#include <dds/dds.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/dds/wire.hpp"
#include "tool_arguments.hpp"

namespace {

using namespace tendril::dds;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

constexpr const char* kUsage = R"(usage: tendril-dds-probe [--domain N] [--timeout S] COMMAND ...

Joins DDS domain N (default 0; Cyclone DDS reads its network settings from $CYCLONEDDS_URI) and
talks to tendrild over DDS only.

commands:
  echo ROBOT TOPIC [--count N]
      print N samples (default 1) of rt/ROBOT/TOPIC as JSON lines; TOPIC is joint_states,
      operating_state, measured_cp, backbone or command_result; ROBOT "maps" with TOPIC "vessel"
      prints rt/maps/vessel (a PointCloud2: its layout and bounds); ROBOT "safety" with TOPIC "events" prints
      rt/safety/events
  send ROBOT servo_jv|move_jp V1,V2,... [--lease TOKEN] [--client NAME] [--count N] [--rate HZ]
  send ROBOT state_command enable|disable|pause|resume|home [--lease TOKEN] [--client NAME]
      send the command N times (default 1) at HZ (default 100; 0 = as fast as possible) and print
      tendrild's answer to each (rt/ROBOT/command_result) as a JSON line; a value may be nan or inf

--timeout S: how long to wait for tendrild and for the samples or answers (default 10 s).
Exit status: 0 every sample arrived / every command was accepted, 1 a command was refused,
2 usage error, 3 nothing (or not everything) arrived in time.
)";

[[noreturn]] void usage_error(const std::string& message) {
  std::cerr << "tendril-dds-probe: " << message << "\n(see tendril-dds-probe --help)\n";
  std::exit(2);
}

dds_entity_t check(dds_entity_t e, const std::string& what) {
  if (e < 0) {
    std::cerr << "tendril-dds-probe: cannot create " << what << ": " << retcode_text(e) << "\n";
    std::exit(1);
  }
  return e;
}

std::string str(const char* s) { return s ? s : ""; }

json doubles(const dds_sequence_double& s) {
  json out = json::array();
  for (std::uint32_t i = 0; i < s._length; ++i) out.push_back(s._buffer[i]);
  return out;
}

json stamp(const builtin_interfaces_msg_dds__Time_& t) { return to_seconds(t); }

// Sample -> JSON, per type.
json to_json(const sensor_msgs_msg_dds__JointState_& m) {
  json names = json::array();
  for (std::uint32_t i = 0; i < m.name._length; ++i) names.push_back(str(m.name._buffer[i]));
  return {
      {"stamp", stamp(m.header.stamp)},  {"frame_id", str(m.header.frame_id)}, {"name", names},
      {"position", doubles(m.position)}, {"velocity", doubles(m.velocity)},    {"effort", doubles(m.effort)}};
}
json to_json(const tendril_msgs_msg_dds__OperatingState_& m) {
  return {{"stamp", stamp(m.header.stamp)},
          {"robot", str(m.robot)},
          {"state", str(m.state)},
          {"mode", str(m.mode)},
          {"is_busy", m.is_busy},
          {"estop", m.estop},
          {"drives_ready", m.drives_ready},
          {"fault_code", str(m.fault_code)},
          {"fault_message", str(m.fault_message)}};
}
json to_json(const geometry_msgs_msg_dds__PoseStamped_& m) {
  const auto& p = m.pose.position;
  const auto& q = m.pose.orientation;
  return {{"stamp", stamp(m.header.stamp)},
          {"frame_id", str(m.header.frame_id)},
          {"position_m", {p.x, p.y, p.z}},
          {"orientation", {q.x, q.y, q.z, q.w}}};
}
json to_json(const geometry_msgs_msg_dds__PoseArray_& m) {
  json positions = json::array();
  for (std::uint32_t i = 0; i < m.poses._length; ++i) {
    const auto& p = m.poses._buffer[i].position;
    positions.push_back({p.x, p.y, p.z});
  }
  const auto& q =
      m.poses._length ? m.poses._buffer[0].orientation : geometry_msgs_msg_dds__Quaternion_{0, 0, 0, 1};
  return {{"stamp", stamp(m.header.stamp)},
          {"frame_id", str(m.header.frame_id)},
          {"positions_m", positions},
          {"first_orientation", {q.x, q.y, q.z, q.w}}};
}
// A PointCloud2 summarised: its layout, and the bounding box of the x, y, z float32 points it holds.
json to_json(const sensor_msgs_msg_dds__PointCloud2_& m) {
  json fields = json::array();
  for (std::uint32_t i = 0; i < m.fields._length; ++i) {
    const auto& f = m.fields._buffer[i];
    fields.push_back(
        {{"name", str(f.name)}, {"offset", f.offset}, {"datatype", f.datatype}, {"count", f.count}});
  }
  json box = nullptr;
  if (m.point_step >= 12 && m.data._length >= static_cast<std::uint64_t>(m.width) * m.point_step &&
      m.width > 0) {
    float lo[3] = {1e30f, 1e30f, 1e30f}, hi[3] = {-1e30f, -1e30f, -1e30f};
    for (std::uint32_t i = 0; i < m.width; ++i) {
      float xyz[3];
      std::memcpy(xyz, m.data._buffer + static_cast<std::size_t>(i) * m.point_step, sizeof xyz);
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], xyz[k]);
        hi[k] = std::max(hi[k], xyz[k]);
      }
    }
    box = {{"min_m", {lo[0], lo[1], lo[2]}}, {"max_m", {hi[0], hi[1], hi[2]}}};
  }
  return {{"stamp", stamp(m.header.stamp)},
          {"frame_id", str(m.header.frame_id)},
          {"height", m.height},
          {"width", m.width},
          {"fields", fields},
          {"is_bigendian", m.is_bigendian},
          {"point_step", m.point_step},
          {"row_step", m.row_step},
          {"data_bytes", m.data._length},
          {"is_dense", m.is_dense},
          {"bounds", box}};
}
json to_json(const tendril_msgs_msg_dds__SafetyEvent_& m) {
  return {{"stamp", stamp(m.header.stamp)},
          {"robot", str(m.robot)},
          {"kind", str(m.kind)},
          {"code", str(m.code)},
          {"from", str(m.from_state)},
          {"to", str(m.to_state)},
          {"joint", str(m.joint)},
          {"message", str(m.message)}};
}
json to_json(const tendril_msgs_msg_dds__CommandResult_& m) {
  return {{"client", str(m.client)}, {"request_id", m.request_id}, {"command", str(m.command)},
          {"status", m.status},      {"code", str(m.code)},        {"message", str(m.message)}};
}

struct Options {
  std::uint32_t domain = 0;
  double timeout_s = 10;
  std::vector<std::string> positional;
  std::string lease, client = "probe";
  long count = 1;
  double rate_hz = 100;
};

// Reads up to `want` samples of type T from `reader`, printing each, until `deadline`.
template <class T>
long drain(dds_entity_t reader, long want, Clock::time_point deadline,
           const std::function<void(const T&)>& seen) {
  long got = 0;
  // At least one pass, so that a deadline of now still takes what has arrived.
  for (bool first = true; got < want && (first || Clock::now() < deadline); first = false) {
    void* samples[16] = {};
    dds_sample_info_t infos[16];
    const dds_return_t n = dds_take(reader, samples, infos, 16, 16);
    if (n < 0) {
      std::cerr << "tendril-dds-probe: take failed: " << retcode_text(n) << "\n";
      return got;
    }
    for (dds_return_t i = 0; i < n && got < want; ++i) {
      if (!infos[i].valid_data) continue;
      seen(*static_cast<const T*>(samples[i]));
      ++got;
    }
    if (n > 0) dds_return_loan(reader, samples, n);
    if (n == 0 && Clock::now() < deadline) std::this_thread::sleep_for(std::chrono::microseconds(200));
  }
  return got;
}

template <class T>
int echo(dds_entity_t participant, const dds_topic_descriptor_t* type, const std::string& name,
         TopicKind kind, const Options& o) {
  dds_qos_t* qos = make_qos(kind);
  const dds_entity_t topic =
      check(dds_create_topic(participant, type, name.c_str(), qos, nullptr), "topic " + name);
  const dds_entity_t reader =
      check(dds_create_reader(participant, topic, qos, nullptr), "a reader of " + name);
  dds_delete_qos(qos);
  const auto deadline =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.timeout_s));
  const long got =
      drain<T>(reader, o.count, deadline, [](const T& m) { std::cout << to_json(m).dump() << std::endl; });
  if (got < o.count) {
    std::cerr << "tendril-dds-probe: " << got << " of " << o.count << " samples of " << name << " in "
              << o.timeout_s << " s\n";
    return 3;
  }
  return 0;
}

bool wait_matched(dds_entity_t writer, dds_entity_t reader, Clock::time_point deadline) {
  while (Clock::now() < deadline) {
    dds_publication_matched_status_t pm{};
    dds_subscription_matched_status_t sm{};
    dds_get_publication_matched_status(writer, &pm);
    dds_get_subscription_matched_status(reader, &sm);
    if (pm.current_count > 0 && sm.current_count > 0) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return false;
}

std::vector<double> parse_values(const std::string& text) {
  std::vector<double> values;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);  // strtod reads nan and inf too
    if (item.empty() || end != item.c_str() + item.size()) usage_error("'" + item + "' is not a number");
    values.push_back(v);
  }
  return values;
}

int send(dds_entity_t participant, const Options& o) {
  if (o.positional.size() != 4) usage_error("send needs ROBOT COMMAND ARGUMENT");
  const std::string& robot = o.positional[1];
  const std::string& command = o.positional[2];
  const bool state = command == kStateCommand;
  if (!state && command != kServoJv && command != kMoveJp)
    usage_error("send: COMMAND is servo_jv, move_jp or state_command, got '" + command + "'");
  const std::string name = robot_topic(robot, command);
  const std::string result_name = robot_topic(robot, kCommandResult);
  dds_qos_t* qos = make_qos(TopicKind::kCommand);
  const auto* type =
      state ? &tendril_msgs_msg_dds__StateCommand__desc : &tendril_msgs_msg_dds__JointCommand__desc;
  const dds_entity_t topic =
      check(dds_create_topic(participant, type, name.c_str(), qos, nullptr), "topic " + name);
  const dds_entity_t writer =
      check(dds_create_writer(participant, topic, qos, nullptr), "a writer of " + name);
  dds_delete_qos(qos);
  qos = make_qos(TopicKind::kResult);
  // The answers of a flood must not be lost in the probe's own history.
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  const dds_entity_t result_topic =
      check(dds_create_topic(participant, &tendril_msgs_msg_dds__CommandResult__desc, result_name.c_str(),
                             qos, nullptr),
            "topic " + result_name);
  const dds_entity_t results =
      check(dds_create_reader(participant, result_topic, qos, nullptr), "a reader of " + result_name);
  dds_delete_qos(qos);
  const auto deadline =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.timeout_s));
  if (!wait_matched(writer, results, deadline)) {
    std::cerr << "tendril-dds-probe: no tendrild serves " << name << " in domain " << o.domain << " (waited "
              << o.timeout_s << " s)\n";
    return 3;
  }
  const std::vector<double> values = state ? std::vector<double>{} : parse_values(o.positional[3]);
  const auto period =
      o.rate_hz > 0
          ? std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / o.rate_hz))
          : Clock::duration::zero();
  auto next = Clock::now();
  std::map<std::int32_t, long> by_status;
  long answered = 0;
  bool refused = false;
  // When each request was written, for the round trip to its answer.
  std::vector<Clock::time_point> written(static_cast<std::size_t>(o.count));
  std::vector<double> round_trips_ms;
  auto print = [&](const tendril_msgs_msg_dds__CommandResult_& m) {
    if (str(m.client) != "dds:" + o.client) return;  // another commander's answer
    json line = to_json(m);
    if (m.request_id < written.size()) {
      const double ms =
          std::chrono::duration<double, std::milli>(Clock::now() - written[m.request_id]).count();
      round_trips_ms.push_back(ms);
      line["round_trip_ms"] = ms;
    }
    std::cout << line.dump() << std::endl;
    ++by_status[m.status];
    ++answered;
    refused = refused || m.status >= 400;
  };
  for (long i = 0; i < o.count; ++i) {
    if (period > Clock::duration::zero()) {
      // Answers are read while waiting for the next write, so each round trip is timed when it ends.
      drain<tendril_msgs_msg_dds__CommandResult_>(results, o.count, next, print);
      std::this_thread::sleep_until(next);
      next += period;
    }
    dds_return_t rc;
    written[static_cast<std::size_t>(i)] = Clock::now();
    const auto t =
        to_time(std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count());
    if (state) {
      tendril_msgs_msg_dds__StateCommand_ m{};
      m.header.stamp = t;
      m.header.frame_id = const_cast<char*>("");
      m.lease_token = const_cast<char*>(o.lease.c_str());
      m.client = const_cast<char*>(o.client.c_str());
      m.request_id = static_cast<std::uint32_t>(i);
      m.command = const_cast<char*>(o.positional[3].c_str());
      rc = dds_write(writer, &m);
    } else {
      tendril_msgs_msg_dds__JointCommand_ m{};
      m.header.stamp = t;
      m.header.frame_id = const_cast<char*>("");
      m.lease_token = const_cast<char*>(o.lease.c_str());
      m.client = const_cast<char*>(o.client.c_str());
      m.request_id = static_cast<std::uint32_t>(i);
      m.values._length = m.values._maximum = static_cast<std::uint32_t>(values.size());
      m.values._buffer = const_cast<double*>(values.data());
      rc = dds_write(writer, &m);
    }
    if (rc != DDS_RETCODE_OK) std::cerr << "tendril-dds-probe: write failed: " << retcode_text(rc) << "\n";
    drain<tendril_msgs_msg_dds__CommandResult_>(results, o.count, Clock::now(), print);
  }
  // Every sample delivered (acknowledged by tendrild's reader) before the answers are awaited: a
  // participant deleted with unacknowledged samples would take the tail of a flood with it.
  if (const dds_return_t rc = dds_wait_for_acks(writer, DDS_SECS(5)); rc != DDS_RETCODE_OK)
    std::cerr << "tendril-dds-probe: not every sample was acknowledged: " << retcode_text(rc) << "\n";
  // A flood's answers: as many as arrive before the deadline or a quiet second.
  auto quiet_until = Clock::now() + std::chrono::seconds(1);
  while (answered < o.count && Clock::now() < deadline && Clock::now() < quiet_until) {
    const long before = answered;
    drain<tendril_msgs_msg_dds__CommandResult_>(results, o.count - answered,
                                                Clock::now() + std::chrono::milliseconds(50), print);
    if (answered > before) quiet_until = Clock::now() + std::chrono::seconds(1);
  }
  std::cerr << "tendril-dds-probe: sent " << o.count << ", answered " << answered;
  for (const auto& [status, n] : by_status) std::cerr << ", " << status << ": " << n;
  if (!round_trips_ms.empty()) {
    std::sort(round_trips_ms.begin(), round_trips_ms.end());
    auto at = [&](double q) {
      return round_trips_ms[static_cast<std::size_t>(q * static_cast<double>(round_trips_ms.size() - 1))];
    };
    std::cerr << "; round trip ms p50 " << at(0.5) << ", p99 " << at(0.99) << ", max "
              << round_trips_ms.back();
  }
  std::cerr << "\n";
  if (answered == 0) return 3;
  if (refused) return 1;
  return answered < o.count ? 3 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  tools::ArgumentCursor args(argc, argv, usage_error);
  while (args.next()) {
    const std::string arg = args.current();
    auto value = [&](const char* name) { return args.value(name); };
    auto number = [&](const char* name) { return args.number(name); };
    if (arg == "--help" || arg == "-h") {
      std::cout << kUsage;
      return 0;
    } else if (arg == "--domain") {
      o.domain = args.domain();
    } else if (arg == "--timeout") {
      o.timeout_s = number("--timeout");
    } else if (arg == "--count") {
      o.count = static_cast<long>(number("--count"));
    } else if (arg == "--rate") {
      o.rate_hz = number("--rate");
    } else if (arg == "--lease") {
      o.lease = value("--lease");
    } else if (arg == "--client") {
      o.client = value("--client");
    } else if (arg.rfind("--", 0) == 0) {
      usage_error("unknown option '" + arg + "'");
    } else {
      o.positional.push_back(arg);
    }
  }
  if (o.positional.empty()) usage_error("a command is needed: echo or send");
  const dds_entity_t participant = check(
      dds_create_participant(static_cast<dds_domainid_t>(o.domain), nullptr, nullptr), "a DDS participant");
  int status = 2;
  const std::string& what = o.positional[0];
  if (what == "echo") {
    if (o.positional.size() != 3) usage_error("echo needs ROBOT TOPIC");
    const std::string& robot = o.positional[1];
    const std::string& leaf = o.positional[2];
    if (robot == "safety" && leaf == "events")
      status = echo<tendril_msgs_msg_dds__SafetyEvent_>(participant, &tendril_msgs_msg_dds__SafetyEvent__desc,
                                                        kSafetyEventsTopic, TopicKind::kEvent, o);
    else if (leaf == kJointStates)
      status = echo<sensor_msgs_msg_dds__JointState_>(participant, &sensor_msgs_msg_dds__JointState__desc,
                                                      robot_topic(robot, leaf), TopicKind::kState, o);
    else if (leaf == kOperatingState)
      status = echo<tendril_msgs_msg_dds__OperatingState_>(participant,
                                                           &tendril_msgs_msg_dds__OperatingState__desc,
                                                           robot_topic(robot, leaf), TopicKind::kState, o);
    else if (leaf == kTipPose)
      status =
          echo<geometry_msgs_msg_dds__PoseStamped_>(participant, &geometry_msgs_msg_dds__PoseStamped__desc,
                                                    robot_topic(robot, leaf), TopicKind::kState, o);
    else if (robot == "maps")
      status = echo<sensor_msgs_msg_dds__PointCloud2_>(participant, &sensor_msgs_msg_dds__PointCloud2__desc,
                                                       map_topic(leaf), TopicKind::kMap, o);
    else if (leaf == kBackbone)
      status = echo<geometry_msgs_msg_dds__PoseArray_>(participant, &geometry_msgs_msg_dds__PoseArray__desc,
                                                       robot_topic(robot, leaf), TopicKind::kState, o);
    else if (leaf == kCommandResult)
      status =
          echo<tendril_msgs_msg_dds__CommandResult_>(participant, &tendril_msgs_msg_dds__CommandResult__desc,
                                                     robot_topic(robot, leaf), TopicKind::kResult, o);
    else
      usage_error("echo: unknown topic '" + leaf + "'");
  } else if (what == "send") {
    status = send(participant, o);
  } else {
    usage_error("unknown command '" + what + "' (echo, send)");
  }
  dds_delete(participant);
  return status;
}
