#include "tendril/safety/safety_types.hpp"

namespace tendril::safety {

const char* to_string(OperatingState state) noexcept {
  switch (state) {
    case OperatingState::kDisabled:
      return "DISABLED";
    case OperatingState::kEnabled:
      return "ENABLED";
    case OperatingState::kPaused:
      return "PAUSED";
    case OperatingState::kFault:
      return "FAULT";
  }
  return "UNKNOWN";
}

const char* to_string(StateCommand command) noexcept {
  switch (command) {
    case StateCommand::kEnable:
      return "enable";
    case StateCommand::kDisable:
      return "disable";
    case StateCommand::kPause:
      return "pause";
    case StateCommand::kResume:
      return "resume";
  }
  return "unknown";
}

const char* to_string(CommandResult result) noexcept {
  switch (result) {
    case CommandResult::kAccepted:
      return "accepted";
    case CommandResult::kAlreadyInState:
      return "already in the requested state";
    case CommandResult::kRefusedEstopLatched:
      return "refused: the e-stop is latched; reset it first";
    case CommandResult::kRefusedInFault:
      return "refused: the robot is in FAULT; disable to acknowledge it first";
    case CommandResult::kRefusedInvalidTransition:
      return "refused: not allowed from the current state";
  }
  return "unknown";
}

const char* to_string(FaultCode code) noexcept {
  switch (code) {
    case FaultCode::kNone:
      return "no fault";
    case FaultCode::kEstop:
      return "e-stop";
    case FaultCode::kTrackingError:
      return "tracking error beyond limit";
    case FaultCode::kLostControlTime:
      return "control time lost while moving";
    case FaultCode::kDriveHeartbeatLost:
      return "drive heartbeat lost";
    case FaultCode::kDriveEmergency:
      return "drive emergency (EMCY)";
    case FaultCode::kBusOff:
      return "CAN bus-off";
    case FaultCode::kSensorStale:
      return "sensor stream stale";
    case FaultCode::kInvalidMeasurement:
      return "invalid measurement";
    case FaultCode::kInvalidSetpoint:
      return "invalid setpoint";
    case FaultCode::kCommandTimeout:
      return "servo command timeout";
    case FaultCode::kSpringDeflection:
      return "spring deflection over its bound";
    case FaultCode::kExternal:
      return "external fault";
  }
  return "unknown fault";
}

const char* to_string(EventKind kind) noexcept {
  switch (kind) {
    case EventKind::kTransition:
      return "transition";
    case EventKind::kRefused:
      return "refused";
    case EventKind::kFault:
      return "fault";
    case EventKind::kHold:
      return "hold";
    case EventKind::kEstop:
      return "estop";
    case EventKind::kEstopReset:
      return "estop_reset";
    case EventKind::kRecovery:
      return "recovery";
    case EventKind::kWarning:
      return "warning";
  }
  return "unknown";
}

const char* to_string(ViolationKind kind) noexcept {
  switch (kind) {
    case ViolationKind::kNone:
      return "no violation";
    case ViolationKind::kWrongSize:
      return "wrong number of values";
    case ViolationKind::kNotFinite:
      return "value is not a finite number";
    case ViolationKind::kBelowLower:
      return "below the lower limit";
    case ViolationKind::kAboveUpper:
      return "above the upper limit";
    case ViolationKind::kAboveMaxVelocity:
      return "above the velocity limit";
  }
  return "unknown";
}

}  // namespace tendril::safety
