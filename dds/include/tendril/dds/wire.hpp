// The DDS face of tendril on the wire: topic names, the QoS of each topic and time stamps, shared by
// tendrild's bridge and tendril-dds-probe so that the two cannot disagree. The types themselves are
// the IDL under dds/idl (ros2_msgs.idl: the ROS 2 ones; tendril_msgs.idl: tendril's own), compiled
// by idlc into ros2_msgs.h / tendril_msgs.h.
//
// Names follow ROS 2's mapping of a topic "/srmc/joint_states" onto DDS: the prefix "rt" (ROS topic)
// and no leading slash, "rt/srmc/joint_states".
#pragma once

#include <dds/dds.h>

#include <cstdint>
#include <string>
#include <vector>

#include "ros2_msgs.h"
#include "tendril_msgs.h"

namespace tendril::dds {

// What a topic carries, which decides its QoS (dds/README.md):
//   kState:   best-effort, keep-last 1, volatile: a lost sample is replaced by the next one.
//   kEvent:   reliable, keep-last 64, transient-local: a late subscriber gets the recent events.
//   kCommand: reliable, keep-last 64: a command is not lost on the way, a flood is cut by the rate
//             limit of the bridge, not by the network.
//   kResult:  reliable, keep-last 64, volatile: the answer to each command sample.
//   kMap:     reliable, keep-last 1, transient-local: a map is written when it is made and a late
//             subscriber still gets it (as ROS 2's latched maps).
enum class TopicKind { kState, kEvent, kCommand, kResult, kMap };

// The QoS of `kind`; the caller owns it (dds_delete_qos).
dds_qos_t* make_qos(TopicKind kind);

// "rt/<robot>/<leaf>", e.g. robot_topic("srmc", "joint_states") = "rt/srmc/joint_states".
std::string robot_topic(const std::string& robot, const std::string& leaf);
inline constexpr const char* kSafetyEventsTopic = "rt/safety/events";
// "rt/maps/<name>", e.g. map_topic("vessel") = "rt/maps/vessel" (the WebSocket's /maps/vessel).
std::string map_topic(const std::string& name);

// Topic leaves per robot.
inline constexpr const char* kJointStates = "joint_states";        // sensor_msgs/JointState, kState
inline constexpr const char* kOperatingState = "operating_state";  // tendril_msgs OperatingState, kState
inline constexpr const char* kTipPose = "measured_cp";             // geometry_msgs/PoseStamped, kState
inline constexpr const char* kBackbone = "backbone";               // geometry_msgs/PoseArray, kState
inline constexpr const char* kServoJv = "servo_jv";                // tendril_msgs JointCommand, kCommand
inline constexpr const char* kMoveJp = "move_jp";                  // tendril_msgs JointCommand, kCommand
inline constexpr const char* kStateCommand = "state_command";      // tendril_msgs StateCommand, kCommand
inline constexpr const char* kCommandResult = "command_result";    // tendril_msgs CommandResult, kResult

// Writes one sensor_msgs/JointState sample (header stamp and frame, then the joints) to `writer` and
// returns dds_write's code. tendrild's bridge writes its joint states through this function and so
// does the latency bench's synthetic stream (tendril-dds-latency pub), so that the bench measures the
// bridge's own writer path. Not for the control thread: it allocates the array of name pointers.
dds_return_t write_joint_state(dds_entity_t writer, double stamp_unix_s, const std::string& frame_id,
                               const std::vector<std::string>& name, const std::vector<double>& position,
                               const std::vector<double>& velocity, const std::vector<double>& effort);

// builtin_interfaces/Time from unix seconds.
builtin_interfaces_msg_dds__Time_ to_time(double unix_seconds);
double to_seconds(const builtin_interfaces_msg_dds__Time_& t);

// A Cyclone DDS return code as text for a person, e.g. "DDS_RETCODE_BAD_PARAMETER".
std::string retcode_text(dds_return_t rc);

}  // namespace tendril::dds
