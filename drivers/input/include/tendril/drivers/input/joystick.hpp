// Operator input devices, reduced to what the mid-level controller needs: a few normalised axes
// (−1..1), a button mask and whether the operator-presence (deadman) input is held.
//
// Mapping from a device's raw axes to the controller's named outputs (roll, proximal, distal, …) is
// configuration: which axis code feeds which output, its deadband, scale and inversion. The same
// mapping serves evdev gamepads and the dissertation's analog joystick (after its ADC).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace tendril::input {

inline constexpr std::size_t kMaxJoystickOutputs = 8;

// Trivially copyable so it can travel through a hardware::LatestValue slot to the control thread.
struct JoystickState {
  std::array<double, kMaxJoystickOutputs> outputs{};  // normalised −1..1, in mapping order
  std::uint32_t buttons = 0;                          // bit i: mapped button i is pressed
  bool connected = false;                             // false: outputs are zero, deadman released
  bool deadman = false;                               // operator-presence input held
  std::uint64_t reports = 0;                          // complete reports seen since start
  std::int64_t stamp_ns = 0;                          // CLOCK_MONOTONIC time of the last report
};

// A setting that cannot work (unknown output, deadband ≥ 1, a range of zero width, …).
class JoystickConfigError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

struct AxisMapping {
  std::string output;     // controller output fed by this axis, e.g. "roll"
  int code = 0;           // device axis: evdev ABS_* code, or ADC channel index
  double minimum = -1.0;  // raw range; for evdev replaced by the device's own absinfo when known
  double maximum = 1.0;
  double deadband = 0.05;  // fraction of half the range around the centre that reads as 0
  double scale = 1.0;      // output = scale · normalised value (then clamped to −1..1)
  bool invert = false;
};

struct ButtonMapping {
  int code = 0;  // evdev KEY_*/BTN_* code
  std::string name;
};

struct JoystickMapping {
  std::vector<AxisMapping> axes;       // at most kMaxJoystickOutputs
  std::vector<ButtonMapping> buttons;  // at most 32
  int deadman_code = -1;               // KEY_*/BTN_* that must be held for motion; −1 = none required

  // Throws JoystickConfigError with the offending entry when the mapping cannot work.
  void validate() const;
  // Index of `output` in `axes`, or −1.
  int output_index(const std::string& output) const noexcept;
};

// Raw reading → −1..1: centre of [minimum, maximum] is 0, the deadband is cut out so the output
// still starts at 0 at its edge (no step), then scale, inversion and a clamp to −1..1.
double normalise_axis(const AxisMapping& axis, double raw) noexcept;

}  // namespace tendril::input
