// Safety vocabulary shared by the supervisor, its event log and the server: operating states
// (CRTK operating_state names), state commands, command results, fault codes, event kinds and
// limit-violation kinds, each with to_string() for messages meant for a person.
#pragma once

#include <cstddef>
#include <cstdint>

namespace tendril::safety {

// Upper bound on joints per supervised robot; each robot declares its own count in its LimitSet.
inline constexpr std::size_t kMaxJoints = 16;

enum class OperatingState : std::uint8_t { kDisabled, kEnabled, kPaused, kFault };

enum class StateCommand : std::uint8_t { kEnable, kDisable, kPause, kResume };

enum class CommandResult : std::uint8_t {
  kAccepted,                  // transition made
  kAlreadyInState,            // nothing to do (e.g. enable while ENABLED)
  kRefusedEstopLatched,       // e-stop latched: only reset_estop() helps
  kRefusedInFault,            // in FAULT: acknowledge with disable first
  kRefusedInvalidTransition,  // e.g. resume from DISABLED, enable from PAUSED
};

// Room for a safety event's or a fault's text (NUL included): enough to say what measured the cause
// (the control loop's own clock, or which device went silent for how long).
inline constexpr std::size_t kSafetyTextSize = 256;

enum class FaultCode : std::uint8_t {
  kNone,
  kEstop,
  kTrackingError,
  kLostControlTime,  // the control loop did not run for longer than its bound while the robot moved
  kDriveHeartbeatLost,
  kDriveEmergency,  // CANopen EMCY from a drive
  kBusOff,
  kSensorStale,
  kInvalidMeasurement,  // wrong size or non-finite measured joint state
  kInvalidSetpoint,     // controller produced a non-finite or wrong-size setpoint
  kCommandTimeout,      // servo stream not refreshed (a hold, not a fault)
  kSpringDeflection,    // a series-elastic spring deflected beyond its bound (a hold)
  kExternal,            // any other cause reported from outside
};

enum class EventKind : std::uint8_t {
  kTransition,  // operating state changed on request
  kRefused,     // a state command was refused
  kFault,       // a fault was raised (with or without a state change)
  kHold,        // motion held, e.g. servo command timeout
  kEstop,       // e-stop latched
  kEstopReset,  // e-stop latch cleared
  kRecovery,    // a way out of a hold ran (e.g. the catheter's springs relaxed): no state change
  kWarning,     // a condition the operator must see, reported from outside the loop (e.g. images
                // stopped coming): no state change
};

enum class ViolationKind : std::uint8_t {
  kNone,
  kWrongSize,
  kNotFinite,
  kBelowLower,
  kAboveUpper,
  kAboveMaxVelocity,
};

const char* to_string(OperatingState state) noexcept;
const char* to_string(StateCommand command) noexcept;
const char* to_string(CommandResult result) noexcept;
const char* to_string(FaultCode code) noexcept;
const char* to_string(EventKind kind) noexcept;
const char* to_string(ViolationKind kind) noexcept;

}  // namespace tendril::safety
