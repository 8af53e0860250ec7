// The hardware seam for sensors: small read-only interfaces, one per kind of measurement, so a robot
// type asks for "a force sensor" or "analogue inputs" and does not care whether a CAN node, a serial
// device or a simulator answers. Every reading is trivially copyable and carries its own timestamp
// (steady clock, ns) and validity, so the control thread judges staleness itself.
//
// Real-time contract: read() is called from the control thread; it never allocates, locks or blocks.
#pragma once

#include <array>
#include <cstdint>

namespace tendril::hardware {

inline constexpr std::size_t kMaxAnalogChannels = 8;
inline constexpr std::size_t kMaxArrayElements = 16;

// Analogue inputs (CiA 401 ADC nodes: potentiometers, an analogue joystick) and a digital input byte.
struct AnalogReading {
  std::array<double, kMaxAnalogChannels> volts{};
  std::array<bool, kMaxAnalogChannels> channel_fault{};  // wiring fault (out of range) per channel
  std::uint8_t channels = 0;
  std::uint8_t digital_inputs = 0;
  std::int64_t stamp_ns = 0;  // when it arrived; 0 = never
  bool valid = false;
};
class AnalogInputs {
 public:
  virtual ~AnalogInputs() = default;
  virtual AnalogReading read() const noexcept = 0;
};

// A 3-axis force sensor (N, in the sensor frame).
struct ForceReading {
  std::array<double, 3> force_n{};
  std::int64_t stamp_ns = 0;
  bool valid = false;
};
class ForceSensor {
 public:
  virtual ~ForceSensor() = default;
  virtual ForceReading read() const noexcept = 0;
};

// A 6-DOF pose tracker (electromagnetic or optical): position mm, orientation quaternion x, y, z, w.
struct PoseReading {
  std::array<double, 3> position_mm{};
  std::array<double, 4> orientation{0.0, 0.0, 0.0, 1.0};
  std::int64_t stamp_ns = 0;
  bool valid = false;
};
class PoseTracker {
 public:
  virtual ~PoseTracker() = default;
  virtual PoseReading read() const noexcept = 0;
};

// An array of range sensors (e.g. time-of-flight, mm) or of 3-axis field sensors (e.g. Hall, mT).
struct RangeArrayReading {
  std::array<double, kMaxArrayElements> range_mm{};
  std::array<bool, kMaxArrayElements> element_valid{};
  std::uint8_t elements = 0;
  std::int64_t stamp_ns = 0;
};
class RangeArray {
 public:
  virtual ~RangeArray() = default;
  virtual RangeArrayReading read() const noexcept = 0;
};
struct FieldArrayReading {
  std::array<std::array<double, 3>, kMaxArrayElements> field{};
  std::array<bool, kMaxArrayElements> element_valid{};
  std::uint8_t elements = 0;
  std::int64_t stamp_ns = 0;
};
class FieldArray {
 public:
  virtual ~FieldArray() = default;
  virtual FieldArrayReading read() const noexcept = 0;
};

// A pressure sensor (kPa, gauge).
struct PressureReading {
  double pressure_kpa = 0.0;
  std::int64_t stamp_ns = 0;
  bool valid = false;
};
class PressureSensor {
 public:
  virtual ~PressureSensor() = default;
  virtual PressureReading read() const noexcept = 0;
};

}  // namespace tendril::hardware
