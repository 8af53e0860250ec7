// CanopenMaster: NMT master, SYNC and heartbeat producer, heartbeat and EMCY consumer, SDO client
// for start-up configuration, and one CiA 402 drive proxy per configured node.
//
// Threads: the bus thread owns the master (handle/poll). The real-time thread talks to each drive
// only through its DriveCommand / DriveFeedback LatestValue slots (set_command, feedback), so it never
// locks or blocks.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/hardware/latest_value.hpp"

namespace tendril::canopen {

using Clock = can::Clock;

// Thrown at set-up (a node that does not boot, an SDO abort, a PDO it refuses); the message names
// the node, the object and what went wrong.
class CanopenError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct DriveSetup {
  std::string name;                          // joint name, used in messages
  std::uint8_t node_id = 1;                  // 1..127
  double counts_per_unit = 1000.0;           // encoder counts per joint unit (mm or rad) at the load
  std::int32_t offset_counts = 0;            // counts at joint zero
  std::uint16_t heartbeat_producer_ms = 20;  // the drive's own heartbeat period (0x1017)
  // How long the drive tolerates silence from the master before quick-stopping (0x1016 / 0x6007).
  std::uint16_t master_heartbeat_timeout_ms = 100;
  OperationMode mode = OperationMode::cyclic_synchronous_position;
};

struct MasterSetup {
  std::uint8_t node_id = 0x7F;                             // the master's own heartbeat id
  std::chrono::microseconds sync_period{1000};             // SYNC / PDO cycle
  std::chrono::milliseconds heartbeat_period{20};          // master heartbeat
  std::chrono::milliseconds drive_heartbeat_timeout{100};  // consumer time for drive heartbeats
  std::chrono::milliseconds sdo_timeout{100};
  int sdo_retries = 2;
  std::chrono::milliseconds boot_timeout{2000};
};

// What the real-time thread asks of a drive. `request` is level-triggered: the proxy steps the
// CiA 402 state machine toward it every cycle (fault reset is sent as a rising edge).
enum class DriveRequest : std::uint8_t { disable, enable, quick_stop, fault_reset };

struct DriveCommand {
  DriveRequest request = DriveRequest::disable;
  double target_position = 0.0;  // joint units; CSP target
  std::uint64_t sequence = 0;    // echoed into DriveFeedback::command_sequence when sent
};

struct DriveFeedback {
  Cia402State state = Cia402State::not_ready_to_switch_on;
  NmtState nmt = NmtState::boot_up;
  std::uint16_t statusword = 0;
  double position = 0.0;         // joint units
  double velocity = 0.0;         // joint units / s
  double effort = 0.0;           // torque actual, per mille of rated torque
  bool heartbeat_alive = false;  // false once the consumer time ran out
  bool booted = false;
  std::uint16_t last_emcy_code = 0;  // 0 = none since start
  std::uint8_t last_emcy_register = 0;
  std::uint32_t emcy_count = 0;
  std::uint64_t command_sequence = 0;  // last DriveCommand::sequence put on the bus
  Clock::time_point command_sent_at{};
  Clock::time_point updated_at{};
};

struct MasterStatistics {
  std::uint64_t sync_sent = 0;
  std::uint64_t rpdo_sent = 0;
  std::uint64_t tpdo_received = 0;
  std::uint64_t heartbeats_received = 0;
  std::uint64_t emcy_received = 0;
  std::uint64_t sdo_retries = 0;
  std::uint64_t send_failures = 0;
};

class CanopenMaster {
 public:
  CanopenMaster(can::Bus& bus, MasterSetup setup, std::vector<DriveSetup> drives);
  ~CanopenMaster();
  CanopenMaster(const CanopenMaster&) = delete;
  CanopenMaster& operator=(const CanopenMaster&) = delete;

  // Set-up (blocking; never from the real-time thread): NMT reset communication, wait for every
  // boot-up, configure heartbeats, PDO mapping, mode and interpolation period by SDO, NMT start.
  // `idle` runs while waiting for the bus (stepped simulation advances the simulated nodes there).
  void start(const std::function<void()>& idle = {});
  // Orderly shutdown: disable every drive (waits up to `timeout` for them to report it), then NMT
  // enter pre-operational. Blocking.
  void shutdown(std::chrono::milliseconds timeout, const std::function<void()>& idle = {});

  // The bus thread's work: feed every received frame, then poll on each wake-up. poll() sends
  // RPDOs + SYNC when the cycle is due, the master heartbeat, and runs the watchdogs.
  void handle(const can::Frame& frame, Clock::time_point now) noexcept;
  void poll(Clock::time_point now) noexcept;
  // Next time poll() has work to do (the bus thread sleeps on receive() until then).
  Clock::time_point next_deadline() const noexcept;

  std::size_t drive_count() const noexcept;
  const DriveSetup& drive_setup(std::size_t i) const;
  hardware::LatestValue<DriveCommand>& command(std::size_t i) noexcept;
  // Real-time thread: stores drive i's command. A request that must not wait for the next SYNC
  // (quick stop or disable, when it differs from the request stored before) also wakes the bus
  // thread through Bus::wake(), so it leaves within microseconds while the bus thread otherwise
  // sleeps until its next SYNC or heartbeat. Lock-free, allocation-free.
  void set_command(std::size_t i, const DriveCommand& command) noexcept;
  const hardware::LatestValue<DriveFeedback>& feedback(std::size_t i) const noexcept;
  MasterStatistics statistics() const noexcept;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tendril::canopen
