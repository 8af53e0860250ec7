// SimulatedCia402Drive: a SIMULATION of a CiA 402 servo drive that is a CANopen node on a CAN bus.
// It speaks the same frames as a real drive (NMT slave, heartbeat producer and consumer, SDO server,
// PDOs configured through its object dictionary, SYNC, EMCY) and moves a simulated motor + gearbox
// + load with a torque-limited position servo loop. Nothing here touches hardware.
//
// Threads: one owner thread calls handle()/step()/pump(); those are noexcept, do not allocate,
// lock or block. Failure injection and inspection calls are for the same thread (tests, the
// Simulation host); other threads read the published DriveTruth through Simulation.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <random>
#include <stdexcept>
#include <string>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/object_dictionary.hpp"
#include "tendril/teleop/pid.hpp"

namespace tendril::sim {

using Clock = can::Clock;

// Thrown at construction for parameters that cannot describe a drive; the message names the field.
class SimulationSetupError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Motor, transmission, encoder and servo model. Positions on the wire are encoder increments
// (CiA 402 position units with unit factors 1:1); joint units are mm or rad at the load.
struct DriveParameters {
  std::string name = "drive";
  // Transmission: motor revolutions per output revolution, joint units per output revolution
  // (lead-screw lead in mm, or 2*pi rad for a rotary output).
  double gear_ratio = 1.0;
  double units_per_output_rev = 1.27;  // Velmex A1506B-S1.5: 20 turns/inch = 1.27 mm/rev
  // One joint unit expressed in SI (1e-3 for mm, 1 for rad); scales external load forces.
  double unit_in_si = 1e-3;
  // Encoder on the motor shaft.
  std::uint32_t encoder_counts_per_motor_rev = 8192;  // 2048 lines, quadrature
  double encoder_noise_counts = 0.0;                  // Gaussian sigma
  bool absolute_encoder = true;                       // false: the count restarts at zero after power_cycle()
  std::uint64_t noise_seed = 1;
  // Mechanics at the motor shaft (SI).
  double motor_inertia = 1.2e-6;     // kg m^2
  double load_inertia = 0.8e-6;      // kg m^2, reflected to the motor
  double viscous_friction = 2e-6;    // N m s/rad
  double coulomb_friction = 1.5e-3;  // N m
  double rated_torque = 0.03;        // N m; 0x6077 is per mille of this
  double max_torque = 0.09;          // N m; servo output saturates here
  // Physical end stops of travel in joint units (the carriage hits the end of the screw).
  double hard_stop_min = -1e9;
  double hard_stop_max = 1e9;
  double initial_position = 0.0;  // joint units at power-on
  // Servo loop: bandwidth sets PID gains from the total inertia (critically damped + slow I).
  double servo_bandwidth_hz = 40.0;
  double velocity_filter_hz = 400.0;
  double max_physics_dt = 0.0005;  // s; step() subdivides longer steps
  // Defaults for the dictionary (all in joint units; converted to counts).
  double following_error_window = 0.5;            // 0x6065
  std::uint16_t following_error_timeout_ms = 10;  // 0x6066
  double position_limit_min = -1e6;               // 0x607D sub1
  double position_limit_max = 1e6;                // 0x607D sub2
  double quick_stop_deceleration = 200.0;         // 0x6085, units/s^2
  double max_velocity = 50.0;                     // 0x607F, units/s
  double target_reached_window = 0.01;            // statusword bit 10
  std::uint32_t vendor_id = 0x00000000;           // 0x1018 sub1 (none assigned: simulation)
  std::uint32_t product_code = 0x54534431;        // "TSD1"

  double motor_rad_per_unit() const noexcept;
  // Encoder counts per joint unit: what the master's DriveSetup::counts_per_unit must be.
  double counts_per_unit() const noexcept;
  void validate() const;  // throws SimulationSetupError

  // A bend drive of the SRMC: DC motor on a Velmex 1.27 mm/rev lead screw, 4.5" travel.
  static DriveParameters srmc_bend(std::string name);
  // The insertion stage (linear, mm) and the roll axis (rad) of the SRMC actuation unit.
  static DriveParameters srmc_insertion(std::string name);
  static DriveParameters srmc_roll(std::string name);
};

// The simulated physical truth, for plants and tests (not what the master sees).
struct DriveTruth {
  double position = 0.0;      // joint units at the load
  double velocity = 0.0;      // units/s
  double motor_torque = 0.0;  // N m
  canopen::Cia402State state = canopen::Cia402State::not_ready_to_switch_on;
  canopen::NmtState nmt = canopen::NmtState::boot_up;
  bool powered = true;
};

struct DriveCounters {
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_suppressed = 0;  // not sent while silent
  std::uint64_t send_failures = 0;
  std::uint64_t frames_handled = 0;
  std::uint64_t syncs = 0;
  std::uint64_t rpdos = 0;
  std::uint64_t sdo_requests = 0;
  std::uint64_t sdo_aborts_sent = 0;
  std::uint64_t emcy_sent = 0;
};

class SimulatedCia402Drive {
 public:
  // `endpoint` must outlive the drive. The drive is powered on; it sends its boot-up message on
  // the first step()/pump().
  SimulatedCia402Drive(std::uint8_t node_id, can::Bus& endpoint, DriveParameters params);
  SimulatedCia402Drive(const SimulatedCia402Drive&) = delete;
  SimulatedCia402Drive& operator=(const SimulatedCia402Drive&) = delete;

  // Protocol: one received frame. SYNC is answered here (TPDOs go out before handle() returns).
  void handle(const can::Frame& frame, Clock::time_point now) noexcept;
  // Physics + timers (heartbeat producer/consumer, following error, SDO timeout) over dt seconds.
  void step(Clock::time_point now, double dt) noexcept;
  // Drains the endpoint (every pending frame through handle()), then step().
  void pump(Clock::time_point now, double dt) noexcept;

  // Failure injection.
  void set_silent(bool silent) noexcept { silent_ = silent; }
  bool silent() const noexcept { return silent_; }
  void inject_fault(std::uint16_t emcy_code) noexcept;
  void power_cycle() noexcept;
  // Power off (no frames, motor coasts) until powered again; power on boots like power_cycle().
  void set_powered(bool on) noexcept;
  bool powered() const noexcept { return powered_; }
  // Generalised external force on the load (N for linear joints, N m for rotary), e.g. a spring.
  void set_external_load(double force) noexcept { external_load_ = force; }

  // Inspection.
  std::uint8_t node_id() const noexcept { return node_id_; }
  const DriveParameters& parameters() const noexcept { return params_; }
  canopen::Cia402State state() const noexcept { return state_; }
  canopen::NmtState nmt_state() const noexcept { return nmt_; }
  std::uint16_t statusword() const noexcept;
  std::int32_t position_counts() const noexcept { return position_counts_; }
  double demand_position_counts() const noexcept { return demand_pos_; }
  DriveTruth truth() const noexcept;
  const DriveCounters& counters() const noexcept { return counters_; }
  const ObjectDictionary& dictionary() const noexcept { return od_; }

 private:
  struct PdoMapEntry {
    OdEntry* entry = nullptr;
    std::uint8_t bits = 0;
  };
  struct Pdo {
    std::uint16_t comm_index = 0;
    std::uint16_t map_index = 0;
    std::array<PdoMapEntry, 8> map{};
    std::uint8_t count = 0;
    std::uint8_t bytes = 0;
    std::uint32_t sync_counter = 0;
    std::array<std::uint8_t, 8> last_sent{};
    bool sent_once = false;
    bool pending = false;  // RPDO: received, waiting for SYNC
    std::array<std::uint8_t, 8> pending_data{};
    std::uint8_t pending_len = 0;
  };
  struct SdoTransfer {
    enum class Kind : std::uint8_t { none, upload, download } kind = Kind::none;
    std::uint16_t index = 0;
    std::uint8_t sub = 0;
    bool toggle = false;
    std::size_t size = 0;    // declared size (download) or total (upload)
    std::size_t offset = 0;  // bytes transferred so far
    std::array<std::uint8_t, 256> buffer{};
    Clock::time_point last_activity{};
  };

  void build_dictionary();
  std::uint32_t check_write(std::uint16_t index, std::uint8_t sub, std::int64_t value) noexcept;
  void after_write(std::uint16_t index, std::uint8_t sub) noexcept;
  void rebuild_pdo(Pdo& pdo) noexcept;
  void rebuild_all_pdos() noexcept;
  void reset_communication(bool full) noexcept;
  void send(const can::Frame& f) noexcept;
  void send_emcy(std::uint16_t code) noexcept;
  void send_heartbeat(Clock::time_point now) noexcept;

  void handle_nmt(const can::Frame& f, Clock::time_point now) noexcept;
  void handle_sync(Clock::time_point now) noexcept;
  void handle_sdo(const can::Frame& f, Clock::time_point now) noexcept;
  void handle_heartbeat(std::uint8_t producer, Clock::time_point now) noexcept;
  void sdo_abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code) noexcept;
  void apply_rpdo(Pdo& pdo, const std::uint8_t* data, std::uint8_t len) noexcept;
  void send_tpdo(Pdo& pdo, Clock::time_point now) noexcept;

  void apply_controlword(std::uint16_t cw) noexcept;
  void enter_state(canopen::Cia402State s) noexcept;
  void raise_fault(std::uint16_t emcy_code, std::uint8_t error_register_bits) noexcept;
  void latch_targets() noexcept;
  void on_comm_loss() noexcept;
  bool servo_active() const noexcept;
  void physics_substep(double dt) noexcept;
  void update_demand(double dt) noexcept;
  void publish_actuals() noexcept;
  void compute_gains() noexcept;

  const std::uint8_t node_id_;
  can::Bus& bus_;
  DriveParameters params_;
  ObjectDictionary od_;

  // Cached dictionary entries (the table owns them; the vector never reallocates after freeze()).
  OdEntry *controlword_ = nullptr, *statusword_ = nullptr, *position_actual_ = nullptr,
          *velocity_actual_ = nullptr, *torque_actual_ = nullptr, *target_position_ = nullptr,
          *target_velocity_ = nullptr, *mode_ = nullptr, *mode_display_ = nullptr, *error_code_ = nullptr,
          *error_register_ = nullptr, *heartbeat_time_ = nullptr, *consumer_hb_ = nullptr,
          *abort_option_ = nullptr, *quick_stop_option_ = nullptr, *following_window_ = nullptr,
          *following_timeout_ = nullptr, *limit_min_ = nullptr, *limit_max_ = nullptr,
          *quick_stop_decel_ = nullptr, *max_velocity_ = nullptr, *interp_value_ = nullptr,
          *interp_index_ = nullptr;
  std::array<Pdo, 2> rpdos_{};
  std::array<Pdo, 2> tpdos_{};

  // CANopen
  canopen::NmtState nmt_ = canopen::NmtState::boot_up;
  bool boot_pending_ = true;
  std::atomic<bool> silent_{false};  // may be set from another thread while the simulation runs
  bool powered_ = true;
  Clock::time_point last_heartbeat_sent_{};
  bool heartbeat_started_ = false;
  Clock::time_point consumer_last_seen_{};
  bool consumer_armed_ = false;  // monitoring starts with the first heartbeat seen
  bool consumer_tripped_ = false;
  SdoTransfer sdo_{};
  DriveCounters counters_{};

  // CiA 402
  canopen::Cia402State state_ = canopen::Cia402State::not_ready_to_switch_on;
  std::uint16_t last_controlword_ = 0;
  bool limit_warning_ = false;
  bool limit_emcy_sent_ = false;
  bool following_error_flag_ = false;
  double following_error_time_ = 0.0;

  // Trajectory (counts, counts/s)
  double latched_target_ = 0.0;
  double interp_start_ = 0.0;
  double interp_elapsed_ = 0.0;
  double demand_pos_ = 0.0;
  double demand_vel_ = 0.0;
  double latched_velocity_ = 0.0;
  bool ramping_ = false;

  // Physics (motor shaft, SI) and encoder
  double motor_angle_ = 0.0;
  double motor_speed_ = 0.0;
  double motor_torque_ = 0.0;
  double external_load_ = 0.0;
  double encoder_offset_counts_ = 0.0;
  std::int32_t position_counts_ = 0;
  double measured_counts_prev_ = 0.0;
  double velocity_estimate_ = 0.0;  // counts/s, filtered
  teleop::Pid servo_;               // the drive's position loop (motor rad -> N m)
  std::mt19937_64 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};
};

}  // namespace tendril::sim
