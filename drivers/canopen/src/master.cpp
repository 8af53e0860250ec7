#include "tendril/drivers/canopen/master.hpp"

#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>

#include "tendril/drivers/canopen/sdo_client.hpp"

namespace tendril::canopen {
namespace {

using namespace std::chrono_literals;

std::string hex(std::uint32_t v, int width) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%0*X", width, static_cast<unsigned>(v));
  return buf;
}

std::vector<std::uint8_t> le_bytes(std::uint32_t value, std::size_t size) {
  std::vector<std::uint8_t> out(size);
  for (std::size_t i = 0; i < size; ++i) out[i] = static_cast<std::uint8_t>(value >> (8 * i));
  return out;
}

// 0x60C2 expresses the interpolation period as value · 10^exponent s. Prefer milliseconds
// (exponent −3, what drives commonly expect); fall back to finer units for sub-ms periods.
bool interpolation_period(std::chrono::microseconds period, std::uint8_t& value, std::int8_t& exponent) {
  std::int64_t us = period.count();
  std::int64_t divisor = 1000;
  for (int e = -3; e >= -6; --e, divisor /= 10) {
    if (us % divisor == 0 && us / divisor <= 255 && us / divisor > 0) {
      value = static_cast<std::uint8_t>(us / divisor);
      exponent = static_cast<std::int8_t>(e);
      return true;
    }
  }
  return false;
}

bool is_disabled(Cia402State s) {
  return s == Cia402State::switch_on_disabled || s == Cia402State::ready_to_switch_on ||
         s == Cia402State::fault;
}

}  // namespace

struct CanopenMaster::Impl {
  struct Slots {
    hardware::LatestValue<DriveCommand> command;
    hardware::LatestValue<DriveFeedback> feedback;
  };
  // Bus-thread-only state of one drive.
  struct Runtime {
    DriveFeedback fb;
    DriveCommand cmd;  // last command read from the slot
    Clock::time_point last_heartbeat{};
    std::int32_t actual_counts = 0;
    bool have_actual = false;
    DriveRequest last_request = DriveRequest::disable;
    bool request_sent = false;  // last_request has been put on the bus at least once
    std::uint16_t last_controlword = 0;
    std::uint32_t fault_reset_phase = 0;
  };

  Impl(can::Bus& b, MasterSetup s, std::vector<DriveSetup> d) : bus(b), setup(s), drives(std::move(d)) {}

  can::Bus& bus;
  MasterSetup setup;
  std::vector<DriveSetup> drives;
  std::unique_ptr<Slots[]> slots;
  std::vector<Runtime> rt;
  std::array<std::int16_t, 128> index_of_node{};
  std::uint8_t interp_value = 1;
  std::int8_t interp_exponent = -3;
  bool started = false;
  bool force_disable = false;  // shutdown in progress: ignore commands
  bool cycle_phase_set = false;
  Clock::time_point last_poll{};  // the bus thread's clock as last seen by poll()
  // Added to Clock::now() while start()/shutdown() pump the bus themselves, so that their poll()
  // and handle() calls continue the bus thread's timeline (which may be a stepped clock).
  Clock::duration pump_offset{};
  Clock::time_point next_sync{};
  Clock::time_point next_heartbeat{};

  std::atomic<std::uint64_t> sync_sent{0}, rpdo_sent{0}, tpdo_received{0}, heartbeats_received{0},
      emcy_received{0}, sdo_retries{0}, send_failures{0};

  void send(const can::Frame& f) noexcept {
    if (bus.send(f) != can::SendResult::ok) send_failures.fetch_add(1, std::memory_order_relaxed);
  }

  void send_nmt(NmtCommand command, std::uint8_t node) noexcept {
    can::Frame f;
    f.id = cob::nmt;
    f.len = 2;
    f.data[0] = static_cast<std::uint8_t>(command);
    f.data[1] = node;
    send(f);
  }

  void publish(std::size_t i) noexcept { slots[i].feedback.store(rt[i].fb); }

  // The CiA 402 proxy: the controlword that moves the drive one step from its reported state
  // toward `request`. Sets `hold` when the target must follow the actual position.
  std::uint16_t controlword_for(Runtime& r, DriveRequest request, bool& hold) noexcept {
    const Cia402State s = r.fb.state;
    hold = true;
    if (request != DriveRequest::fault_reset) r.fault_reset_phase = 0;
    switch (request) {
      case DriveRequest::enable:
        switch (s) {
          case Cia402State::switch_on_disabled:
            return controlword::shutdown;
          case Cia402State::ready_to_switch_on:
            return controlword::switch_on;
          case Cia402State::switched_on:
            return controlword::enable_operation;
          case Cia402State::operation_enabled:
            hold = false;
            return controlword::enable_operation;
          default:
            // Quick stop active leaves through switch on disabled; fault needs an explicit reset.
            return controlword::disable_voltage;
        }
      case DriveRequest::quick_stop:
        if (s == Cia402State::operation_enabled || s == Cia402State::quick_stop_active ||
            s == Cia402State::switched_on || s == Cia402State::ready_to_switch_on)
          return controlword::quick_stop;
        return controlword::disable_voltage;
      case DriveRequest::fault_reset:
        if (s == Cia402State::fault || s == Cia402State::fault_reaction_active) {
          // Bit 7 low, then high: a rising edge. Repeated every 8 cycles while the fault stays.
          const std::uint32_t phase = r.fault_reset_phase++;
          return (phase % 8 == 0) ? controlword::disable_voltage : controlword::fault_reset_bit;
        }
        r.fault_reset_phase = 0;
        [[fallthrough]];
      case DriveRequest::disable:
        if (s == Cia402State::operation_enabled || s == Cia402State::switched_on ||
            s == Cia402State::ready_to_switch_on)
          return controlword::shutdown;  // power stage off, stays ready to switch on
        return controlword::disable_voltage;
    }
    return controlword::disable_voltage;
  }

  std::int32_t target_counts(std::size_t i, double target) const noexcept {
    const auto& d = drives[i];
    const double counts = std::round(target * d.counts_per_unit) + static_cast<double>(d.offset_counts);
    if (!std::isfinite(counts)) return rt[i].actual_counts;  // a NaN target holds position
    if (counts > std::numeric_limits<std::int32_t>::max()) return std::numeric_limits<std::int32_t>::max();
    if (counts < std::numeric_limits<std::int32_t>::min()) return std::numeric_limits<std::int32_t>::min();
    return static_cast<std::int32_t>(counts);
  }

  void send_rpdo(std::size_t i, Clock::time_point now) noexcept {
    Runtime& r = rt[i];
    const DriveRequest request = force_disable ? DriveRequest::disable : r.cmd.request;
    bool hold = true;
    const std::uint16_t cw = controlword_for(r, request, hold);
    const std::int32_t target = hold ? r.actual_counts : target_counts(i, r.cmd.target_position);
    can::Frame f;
    f.id = cob::rpdo1 + drives[i].node_id;
    f.len = 6;
    put_u16(&f.data[0], cw);
    put_u32(&f.data[2], static_cast<std::uint32_t>(target));
    send(f);
    rpdo_sent.fetch_add(1, std::memory_order_relaxed);
    r.last_request = request;
    r.request_sent = true;
    r.last_controlword = cw;
    r.fb.command_sequence = r.cmd.sequence;
    r.fb.command_sent_at = now;
    publish(i);
  }

  void poll(Clock::time_point now) noexcept {
    if (!started) return;
    last_poll = now;
    if (!cycle_phase_set) {
      // The first poll after start() sets the SYNC phase: the bus thread's clock, not start()'s.
      next_sync = now;
      next_heartbeat = now;
      // The consumer clocks restart on the bus thread's timeline too.
      for (auto& r : rt) r.last_heartbeat = now;
      cycle_phase_set = true;
    }
    const bool sync_due = now >= next_sync;
    for (std::size_t i = 0; i < rt.size(); ++i) {
      Runtime& r = rt[i];
      r.cmd = slots[i].command.load();
      const DriveRequest request = force_disable ? DriveRequest::disable : r.cmd.request;
      // Stopping must not wait for the next SYNC.
      const bool urgent = (request == DriveRequest::quick_stop || request == DriveRequest::disable) &&
                          (!r.request_sent || request != r.last_request);
      if (urgent && !sync_due) send_rpdo(i, now);
    }
    if (sync_due) {
      for (std::size_t i = 0; i < rt.size(); ++i) send_rpdo(i, now);
      can::Frame sync;
      sync.id = cob::sync;
      sync.len = 0;
      send(sync);
      sync_sent.fetch_add(1, std::memory_order_relaxed);
      next_sync += setup.sync_period;
      if (next_sync <= now) next_sync = now + setup.sync_period;  // fell behind: do not burst
    }
    if (now >= next_heartbeat) {
      can::Frame hb;
      hb.id = cob::heartbeat + setup.node_id;
      hb.len = 1;
      hb.data[0] = static_cast<std::uint8_t>(NmtState::operational);
      send(hb);
      next_heartbeat += setup.heartbeat_period;
      if (next_heartbeat <= now) next_heartbeat = now + setup.heartbeat_period;
    }
    for (std::size_t i = 0; i < rt.size(); ++i) {
      Runtime& r = rt[i];
      if (r.fb.heartbeat_alive && now - r.last_heartbeat > setup.drive_heartbeat_timeout) {
        r.fb.heartbeat_alive = false;
        publish(i);
      }
    }
  }

  void handle(const can::Frame& f, Clock::time_point now) noexcept {
    if (f.error || f.rtr || f.extended) return;
    const std::uint32_t node = f.id & 0x7F;
    const std::uint32_t function = f.id & 0x780;
    if (node == 0) return;  // NMT, SYNC
    const int idx = index_of_node[node];
    if (idx < 0) return;
    const auto i = static_cast<std::size_t>(idx);
    Runtime& r = rt[i];
    const DriveSetup& d = drives[i];
    switch (function) {
      case cob::heartbeat: {
        if (f.len < 1) return;
        const auto state = static_cast<NmtState>(f.data[0] & 0x7F);
        r.fb.nmt = state;
        if (state == NmtState::boot_up) r.fb.booted = true;
        r.fb.heartbeat_alive = true;
        r.last_heartbeat = now;
        r.fb.updated_at = now;
        heartbeats_received.fetch_add(1, std::memory_order_relaxed);
        publish(i);
        return;
      }
      case cob::tpdo1: {
        if (f.len < 6) return;
        r.fb.statusword = get_u16(&f.data[0]);
        r.fb.state = decode_statusword(r.fb.statusword);
        r.actual_counts = static_cast<std::int32_t>(get_u32(&f.data[2]));
        r.have_actual = true;
        r.fb.position = static_cast<double>(static_cast<std::int64_t>(r.actual_counts) - d.offset_counts) /
                        d.counts_per_unit;
        r.fb.updated_at = now;
        tpdo_received.fetch_add(1, std::memory_order_relaxed);
        publish(i);
        return;
      }
      case cob::tpdo2: {
        if (f.len < 6) return;
        const auto velocity = static_cast<std::int32_t>(get_u32(&f.data[0]));
        const auto torque = static_cast<std::int16_t>(get_u16(&f.data[4]));
        r.fb.velocity = static_cast<double>(velocity) / d.counts_per_unit;
        r.fb.effort = static_cast<double>(torque);
        r.fb.updated_at = now;
        tpdo_received.fetch_add(1, std::memory_order_relaxed);
        publish(i);
        return;
      }
      case cob::emcy: {
        if (f.len < 3) return;
        r.fb.last_emcy_code = get_u16(&f.data[0]);
        r.fb.last_emcy_register = f.data[2];
        ++r.fb.emcy_count;
        r.fb.updated_at = now;
        emcy_received.fetch_add(1, std::memory_order_relaxed);
        publish(i);
        return;
      }
      default:
        return;
    }
  }

  // Set-up helper: receive and dispatch frames (to `sdo` too) until `done` or `deadline`.
  template <typename Pred>
  bool pump_until(Pred done, Clock::time_point deadline, const std::function<void()>& idle, SdoClient* sdo) {
    for (;;) {
      auto now = Clock::now();
      if (sdo) sdo->poll(now);
      if (started) poll(now + pump_offset);
      if (done()) return true;
      if (now >= deadline) return false;
      if (idle) idle();
      bool any = false;
      for (;;) {
        std::chrono::nanoseconds wait = 0ns;
        if (!any) wait = idle ? std::chrono::nanoseconds(100us) : std::chrono::nanoseconds(1ms);
        auto f = bus.receive(wait);
        if (!f) break;
        any = true;
        now = Clock::now();
        if (sdo) sdo->handle(*f, now);
        handle(*f, now + pump_offset);
      }
    }
  }

  void sdo_write(std::size_t i, std::uint16_t index, std::uint8_t sub, std::uint32_t value, std::size_t size,
                 const char* what, const std::function<void()>& idle) {
    SdoClient sdo(bus, drives[i].node_id, setup.sdo_timeout, setup.sdo_retries);
    sdo.start_download(index, sub, le_bytes(value, size), Clock::now());
    // The client times out by itself; the outer deadline only guards against a stuck clock.
    const auto limit = Clock::now() + (setup.sdo_timeout + 50ms) * (setup.sdo_retries + 2);
    const bool finished = pump_until([&] { return !sdo.busy(); }, limit, idle, &sdo);
    sdo_retries.fetch_add(sdo.retries_used(), std::memory_order_relaxed);
    if (!finished || sdo.status() != SdoClient::Status::done) {
      // The SDO client's error() names the node and object again; this message already does.
      const std::string reason = finished ? sdo.reason() : "SDO transfer did not finish";
      throw CanopenError("CANopen start: drive '" + drives[i].name + "' (node " +
                         std::to_string(drives[i].node_id) + "): cannot set " + what + " (" + hex(index, 4) +
                         ":" + hex(sub, 2) + " = " + hex(value, 1) + "): " + reason);
    }
  }

  void configure_pdo(std::size_t i, std::uint16_t comm_index, std::uint16_t map_index, std::uint32_t cob_id,
                     std::initializer_list<std::uint32_t> entries, const char* name,
                     const std::function<void()>& idle) {
    const std::string n(name);
    sdo_write(i, comm_index, 1, cob_id | cob::pdo_invalid_bit, 4, (n + " COB-ID (disable)").c_str(), idle);
    sdo_write(i, map_index, 0, 0, 1, (n + " mapping count (clear)").c_str(), idle);
    std::uint8_t sub = 1;
    for (std::uint32_t e : entries) {
      sdo_write(i, map_index, sub, e, 4, (n + " mapping entry " + std::to_string(sub)).c_str(), idle);
      ++sub;
    }
    sdo_write(i, map_index, 0, static_cast<std::uint32_t>(entries.size()), 1, (n + " mapping count").c_str(),
              idle);
    sdo_write(i, comm_index, 2, 1, 1, (n + " transmission type (synchronous, every SYNC)").c_str(), idle);
    sdo_write(i, comm_index, 1, cob_id, 4, (n + " COB-ID (enable)").c_str(), idle);
  }
};

CanopenMaster::CanopenMaster(can::Bus& bus, MasterSetup setup, std::vector<DriveSetup> drives)
    : impl_(std::make_unique<Impl>(bus, setup, std::move(drives))) {
  auto& m = *impl_;
  if (m.setup.node_id < 1 || m.setup.node_id > 127)
    throw CanopenError("CANopen master: node id " + std::to_string(m.setup.node_id) + " is outside 1..127");
  if (m.setup.sync_period.count() <= 0) throw CanopenError("CANopen master: SYNC period must be > 0");
  if (m.setup.heartbeat_period.count() <= 0)
    throw CanopenError("CANopen master: heartbeat period must be > 0");
  if (m.setup.drive_heartbeat_timeout.count() <= 0)
    throw CanopenError("CANopen master: drive heartbeat timeout must be > 0");
  if (m.setup.sdo_timeout.count() <= 0) throw CanopenError("CANopen master: SDO timeout must be > 0");
  if (m.setup.sdo_retries < 0) throw CanopenError("CANopen master: SDO retries must be >= 0");
  if (!interpolation_period(m.setup.sync_period, m.interp_value, m.interp_exponent))
    throw CanopenError("CANopen master: SYNC period of " + std::to_string(m.setup.sync_period.count()) +
                       " us cannot be expressed as an interpolation period (0x60C2: 1..255 x 10^-3..-6 s)");
  m.index_of_node.fill(-1);
  for (std::size_t i = 0; i < m.drives.size(); ++i) {
    const auto& d = m.drives[i];
    const std::string who = "CANopen master: drive '" + d.name + "' (node " + std::to_string(d.node_id) + ")";
    if (d.node_id < 1 || d.node_id > 127) throw CanopenError(who + ": node id is outside 1..127");
    if (d.node_id == m.setup.node_id) throw CanopenError(who + ": node id is the master's own id");
    if (m.index_of_node[d.node_id] >= 0)
      throw CanopenError(who + ": node id is already used by drive '" +
                         m.drives[static_cast<std::size_t>(m.index_of_node[d.node_id])].name + "'");
    if (!std::isfinite(d.counts_per_unit) || d.counts_per_unit == 0.0)
      throw CanopenError(who + ": counts_per_unit must be finite and non-zero");
    m.index_of_node[d.node_id] = static_cast<std::int16_t>(i);
  }
  m.slots = std::make_unique<Impl::Slots[]>(m.drives.size());
  m.rt.resize(m.drives.size());
}

CanopenMaster::~CanopenMaster() = default;

void CanopenMaster::start(const std::function<void()>& idle) {
  auto& m = *impl_;
  if (m.started) throw CanopenError("CANopen master: start() called twice");
  m.pump_offset = Clock::duration::zero();
  // Forget frames from before the reset so an old boot-up cannot count as a new one.
  while (m.bus.receive(std::chrono::nanoseconds::zero())) {
  }
  for (std::size_t i = 0; i < m.drives.size(); ++i) {
    m.rt[i] = Impl::Runtime{};
    m.publish(i);
  }
  for (const auto& d : m.drives) m.send_nmt(NmtCommand::reset_communication, d.node_id);

  const auto boot_deadline = Clock::now() + m.setup.boot_timeout;
  const bool all_booted = m.pump_until(
      [&] {
        for (const auto& r : m.rt)
          if (!r.fb.booted) return false;
        return true;
      },
      boot_deadline, idle, nullptr);
  if (!all_booted) {
    std::string missing;
    for (std::size_t i = 0; i < m.drives.size(); ++i) {
      if (m.rt[i].fb.booted) continue;
      if (!missing.empty()) missing += ", ";
      missing += "'" + m.drives[i].name + "' (node " + std::to_string(m.drives[i].node_id) + ")";
    }
    throw CanopenError("CANopen start on " + m.bus.name() + ": no boot-up from " + missing + " within " +
                       std::to_string(m.setup.boot_timeout.count()) +
                       " ms of NMT reset communication; check power, wiring, node ids and bitrate");
  }

  for (std::size_t i = 0; i < m.drives.size(); ++i) {
    const auto& d = m.drives[i];
    const std::uint8_t id = d.node_id;
    m.sdo_write(i, od::producer_heartbeat_time, 0, d.heartbeat_producer_ms, 2, "producer heartbeat time",
                idle);
    m.sdo_write(i, od::consumer_heartbeat_time, 1,
                (static_cast<std::uint32_t>(m.setup.node_id) << 16) | d.master_heartbeat_timeout_ms, 4,
                "consumer heartbeat time (master)", idle);
    m.sdo_write(i, od::abort_connection_option, 0, 3, 2, "abort connection option (quick stop)", idle);
    m.sdo_write(i, od::modes_of_operation, 0, static_cast<std::uint8_t>(d.mode), 1, "mode of operation",
                idle);
    m.sdo_write(i, od::interpolation_time_period, 1, m.interp_value, 1, "interpolation period value", idle);
    m.sdo_write(i, od::interpolation_time_period, 2, static_cast<std::uint8_t>(m.interp_exponent), 1,
                "interpolation period exponent", idle);
    // Mapping entries: index << 16 | sub << 8 | bit length.
    m.configure_pdo(i, od::rpdo_communication + 0, od::rpdo_mapping + 0, cob::rpdo1 + id,
                    {0x6040'0010u, 0x607A'0020u}, "RPDO1", idle);
    m.configure_pdo(i, od::tpdo_communication + 0, od::tpdo_mapping + 0, cob::tpdo1 + id,
                    {0x6041'0010u, 0x6064'0020u}, "TPDO1", idle);
    m.configure_pdo(i, od::tpdo_communication + 1, od::tpdo_mapping + 1, cob::tpdo2 + id,
                    {0x606C'0020u, 0x6077'0010u}, "TPDO2", idle);
  }

  for (const auto& d : m.drives) m.send_nmt(NmtCommand::start, d.node_id);
  const auto now = Clock::now();
  for (std::size_t i = 0; i < m.drives.size(); ++i) {
    // The consumer clock starts now: drives only produce heartbeats once configured.
    m.rt[i].last_heartbeat = now;
    m.rt[i].fb.heartbeat_alive = true;
    m.publish(i);
  }
  m.cycle_phase_set = false;
  m.force_disable = false;
  m.started = true;
}

void CanopenMaster::shutdown(std::chrono::milliseconds timeout, const std::function<void()>& idle) {
  auto& m = *impl_;
  if (!m.started) return;
  m.force_disable = true;
  m.pump_offset = m.cycle_phase_set ? m.last_poll - Clock::now() : Clock::duration::zero();
  m.pump_until(
      [&] {
        for (const auto& r : m.rt)
          if (r.fb.heartbeat_alive && !is_disabled(r.fb.state)) return false;
        return true;
      },
      Clock::now() + timeout, idle, nullptr);
  for (const auto& d : m.drives) m.send_nmt(NmtCommand::enter_pre_operational, d.node_id);
  m.pump_offset = Clock::duration::zero();
  m.started = false;
}

void CanopenMaster::handle(const can::Frame& frame, Clock::time_point now) noexcept {
  impl_->handle(frame, now);
}

void CanopenMaster::poll(Clock::time_point now) noexcept { impl_->poll(now); }

Clock::time_point CanopenMaster::next_deadline() const noexcept {
  const auto& m = *impl_;
  // Finite values only, so that callers can subtract `now` without overflow.
  if (!m.started) return Clock::now() + std::chrono::hours(1);
  if (!m.cycle_phase_set) return Clock::now();  // the first poll is due at once
  auto t = std::min(m.next_sync, m.next_heartbeat);
  for (const auto& r : m.rt) {
    if (r.fb.heartbeat_alive) t = std::min(t, r.last_heartbeat + m.setup.drive_heartbeat_timeout);
  }
  return t;
}

std::size_t CanopenMaster::drive_count() const noexcept { return impl_->drives.size(); }

const DriveSetup& CanopenMaster::drive_setup(std::size_t i) const { return impl_->drives.at(i); }

hardware::LatestValue<DriveCommand>& CanopenMaster::command(std::size_t i) noexcept {
  return impl_->slots[i].command;
}

void CanopenMaster::set_command(std::size_t i, const DriveCommand& command) noexcept {
  auto& slot = impl_->slots[i].command;
  const DriveRequest before = slot.load().request;
  slot.store(command);
  const bool stopping =
      command.request == DriveRequest::quick_stop || command.request == DriveRequest::disable;
  if (stopping && command.request != before) impl_->bus.wake();
}

const hardware::LatestValue<DriveFeedback>& CanopenMaster::feedback(std::size_t i) const noexcept {
  return impl_->slots[i].feedback;
}

MasterStatistics CanopenMaster::statistics() const noexcept {
  const auto& m = *impl_;
  MasterStatistics s;
  s.sync_sent = m.sync_sent.load(std::memory_order_relaxed);
  s.rpdo_sent = m.rpdo_sent.load(std::memory_order_relaxed);
  s.tpdo_received = m.tpdo_received.load(std::memory_order_relaxed);
  s.heartbeats_received = m.heartbeats_received.load(std::memory_order_relaxed);
  s.emcy_received = m.emcy_received.load(std::memory_order_relaxed);
  s.sdo_retries = m.sdo_retries.load(std::memory_order_relaxed);
  s.send_failures = m.send_failures.load(std::memory_order_relaxed);
  return s;
}

}  // namespace tendril::canopen
