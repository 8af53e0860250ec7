// Test harness: one simulated drive and a hand-driven "master" endpoint on a VirtualBus, stepped
// in simulated time. Frames the master sends are built by hand here, not by the CANopen master.
#pragma once

#include <gtest/gtest.h>

#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"

namespace tendril::sim::test {

namespace co = canopen;

struct SdoResult {
  bool aborted = false;
  std::uint32_t abort_code = 0;
  std::int64_t value = 0;  // expedited upload, little-endian, zero-extended
  std::vector<std::uint8_t> bytes;
};

class DriveHarness {
 public:
  static constexpr std::uint8_t kNode = 5;

  explicit DriveHarness(DriveParameters params = DriveParameters::srmc_bend("bend"))
      : bus_("test-bus"),
        master_(bus_.attach("master")),
        node_endpoint_(bus_.attach("node")),
        drive(kNode, *node_endpoint_, std::move(params)) {}

  // Advance simulated time in `dt` steps for `duration` seconds; collects everything the drive sends.
  void run(double duration, double dt = 0.001) {
    const int steps = static_cast<int>(duration / dt + 0.5);
    for (int i = 0; i < steps; ++i) tick(dt);
  }
  void tick(double dt = 0.001) {
    now += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(dt));
    drive.pump(now, dt);
    collect();
  }
  void collect() {
    while (auto f = master_->receive(std::chrono::nanoseconds::zero())) received.push_back(*f);
  }
  void send(const can::Frame& f) { ASSERT_EQ(master_->send(f), can::SendResult::ok); }
  // Sends and lets the drive process the frame (no time passes for the physics).
  void deliver(const can::Frame& f) {
    send(f);
    drive.pump(now, 0.0);
    collect();
  }
  std::vector<can::Frame> take() {
    std::vector<can::Frame> out;
    out.swap(received);
    return out;
  }
  std::vector<can::Frame> take_id(std::uint32_t id) {
    std::vector<can::Frame> out, rest;
    for (auto& f : received) (f.id == id ? out : rest).push_back(f);
    received.swap(rest);
    return out;
  }

  void nmt(co::NmtCommand cmd, std::uint8_t node = kNode) {
    deliver(can::Frame::make(co::cob::nmt, {static_cast<std::uint8_t>(cmd), node}));
  }
  void sync() { deliver(can::Frame::make(co::cob::sync, {})); }

  // One SDO request frame -> the single answer.
  can::Frame sdo_exchange(const std::array<std::uint8_t, 8>& request) {
    can::Frame f;
    f.id = co::cob::sdo_rx + kNode;
    f.len = 8;
    f.data = request;
    take_id(co::cob::sdo_tx + kNode);
    deliver(f);
    auto answers = take_id(co::cob::sdo_tx + kNode);
    EXPECT_EQ(answers.size(), 1u) << "expected exactly one SDO answer";
    if (answers.empty()) return {};
    return answers.front();
  }

  static SdoResult decode_abort(const can::Frame& r) {
    SdoResult out;
    if (r.data[0] == 0x80) {
      out.aborted = true;
      out.abort_code = co::get_u32(&r.data[4]);
    }
    return out;
  }

  SdoResult write(std::uint16_t index, std::uint8_t sub, std::uint32_t value, std::size_t size) {
    std::array<std::uint8_t, 8> req{};
    req[0] = static_cast<std::uint8_t>(0x23 | ((4 - size) << 2));
    co::put_u16(&req[1], index);
    req[3] = sub;
    co::put_u32(&req[4], value);
    const auto r = sdo_exchange(req);
    auto out = decode_abort(r);
    if (!out.aborted) {
      EXPECT_EQ(r.data[0], 0x60);
      EXPECT_EQ(co::get_u16(&r.data[1]), index);
      EXPECT_EQ(r.data[3], sub);
    }
    return out;
  }

  SdoResult read(std::uint16_t index, std::uint8_t sub) {
    std::array<std::uint8_t, 8> req{};
    req[0] = 0x40;
    co::put_u16(&req[1], index);
    req[3] = sub;
    const auto r = sdo_exchange(req);
    auto out = decode_abort(r);
    if (out.aborted) return out;
    if ((r.data[0] & 0xE3) == 0x43) {  // expedited, size indicated
      const std::size_t n = 4 - ((r.data[0] >> 2) & 3);
      out.bytes.assign(r.data.begin() + 4, r.data.begin() + 4 + static_cast<std::ptrdiff_t>(n));
      for (std::size_t i = 0; i < n; ++i) out.value |= std::int64_t{r.data[4 + i]} << (8 * i);
      return out;
    }
    EXPECT_EQ(r.data[0], 0x41) << "segmented upload initiate";
    const std::uint32_t size = co::get_u32(&r.data[4]);
    bool toggle = false;
    for (int guard = 0; guard < 100; ++guard) {
      std::array<std::uint8_t, 8> seg{};
      seg[0] = static_cast<std::uint8_t>(0x60 | (toggle ? 0x10 : 0));
      const auto s = sdo_exchange(seg);
      auto a = decode_abort(s);
      if (a.aborted) return a;
      EXPECT_EQ(s.data[0] & 0x10, toggle ? 0x10 : 0) << "server must echo the toggle bit";
      const std::size_t n = 7 - ((s.data[0] >> 1) & 7);
      out.bytes.insert(out.bytes.end(), s.data.begin() + 1,
                       s.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
      toggle = !toggle;
      if (s.data[0] & 1) break;
    }
    EXPECT_EQ(out.bytes.size(), size);
    return out;
  }

  SdoResult write_segmented(std::uint16_t index, std::uint8_t sub, const std::string& text) {
    std::array<std::uint8_t, 8> req{};
    req[0] = 0x21;  // initiate download, segmented, size indicated
    co::put_u16(&req[1], index);
    req[3] = sub;
    co::put_u32(&req[4], static_cast<std::uint32_t>(text.size()));
    auto r = sdo_exchange(req);
    auto out = decode_abort(r);
    if (out.aborted) return out;
    EXPECT_EQ(r.data[0], 0x60);
    bool toggle = false;
    std::size_t offset = 0;
    do {
      const std::size_t n = std::min<std::size_t>(7, text.size() - offset);
      const bool last = offset + n == text.size();
      std::array<std::uint8_t, 8> seg{};
      seg[0] = static_cast<std::uint8_t>((toggle ? 0x10 : 0) | ((7 - n) << 1) | (last ? 1 : 0));
      std::memcpy(&seg[1], text.data() + offset, n);
      const auto s = sdo_exchange(seg);
      out = decode_abort(s);
      if (out.aborted) return out;
      EXPECT_EQ(s.data[0], 0x20 | (toggle ? 0x10 : 0));
      offset += n;
      toggle = !toggle;
    } while (offset < text.size());
    return out;
  }

  // RPDO1 with the default mapping: controlword u16 + target position i32.
  void rpdo1(std::uint16_t controlword, std::int32_t target) {
    can::Frame f;
    f.id = co::cob::rpdo1 + kNode;
    f.len = 6;
    co::put_u16(&f.data[0], controlword);
    co::put_u32(&f.data[2], static_cast<std::uint32_t>(target));
    send(f);
  }
  // One master cycle: RPDO1 then SYNC, then dt of simulated time.
  void cycle(std::uint16_t controlword, std::int32_t target, double dt = 0.001) {
    rpdo1(controlword, target);
    send(can::Frame::make(co::cob::sync, {}));
    tick(dt);
  }
  // Latest TPDO1 (statusword, position) seen, if any.
  std::optional<std::pair<std::uint16_t, std::int32_t>> last_tpdo1() {
    std::optional<std::pair<std::uint16_t, std::int32_t>> out;
    for (const auto& f : received) {
      if (f.id == co::cob::tpdo1 + kNode && f.len == 6)
        out = {co::get_u16(&f.data[0]), static_cast<std::int32_t>(co::get_u32(&f.data[2]))};
    }
    return out;
  }

  // Brings the drive to OPERATION ENABLED in CSP through NMT start and RPDO controlwords.
  void enable() {
    run(0.01);
    nmt(co::NmtCommand::start);
    const auto hold = drive.position_counts();
    for (std::uint16_t cw : {0x0006, 0x0007, 0x000F}) cycle(cw, hold);
    ASSERT_EQ(drive.state(), co::Cia402State::operation_enabled);
  }

  can::VirtualBus bus_;
  std::unique_ptr<can::VirtualBusEndpoint> master_;
  std::unique_ptr<can::VirtualBusEndpoint> node_endpoint_;
  SimulatedCia402Drive drive;
  Clock::time_point now = Clock::time_point{} + std::chrono::hours(1);
  std::vector<can::Frame> received;
};

inline std::vector<std::uint16_t> emcy_codes(const std::vector<can::Frame>& frames) {
  std::vector<std::uint16_t> out;
  for (const auto& f : frames) {
    if (f.id == co::cob::emcy + DriveHarness::kNode) out.push_back(co::get_u16(&f.data[0]));
  }
  return out;
}

}  // namespace tendril::sim::test
