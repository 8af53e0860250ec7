#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <map>
#include <new>
#include <tuple>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/master.hpp"

// Counts heap allocations while armed, to check that poll()/handle() do not allocate.
namespace {
std::atomic<bool> g_count_allocations{false};
std::atomic<int> g_allocations{0};
}  // namespace

// GCC cannot see that this operator delete pairs with the operator new below.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(std::size_t size) {
  if (g_count_allocations.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  if (void* p = std::malloc(size ? size : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace tendril::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;

// A hand-written stand-in for a drive: answers NMT with boot-up, expedited SDO downloads (all it
// needs for the master's configuration; it records every write), and, when asked to, runs a
// minimal CiA 402 state machine on SYNC so closed-loop tests can follow the proxy.
struct FakeNode {
  struct Write {
    std::uint16_t index;
    std::uint8_t sub;
    std::uint32_t value;
    std::size_t size;
    bool operator==(const Write& o) const {
      return std::tie(index, sub, value, size) == std::tie(o.index, o.sub, o.value, o.size);
    }
  };

  FakeNode(can::VirtualBus& bus, std::uint8_t node_id)
      : ep(bus.attach("node" + std::to_string(node_id))), id(node_id) {}

  std::unique_ptr<can::VirtualBusEndpoint> ep;
  std::uint8_t id;
  bool boots = true;
  std::map<std::pair<std::uint16_t, std::uint8_t>, std::uint32_t> abort_on;  // object -> abort code
  std::vector<Write> writes;
  std::vector<Frame> nmt;  // NMT frames addressed to us
  bool run_cia402 = false;
  Cia402State state = Cia402State::switch_on_disabled;
  std::uint16_t controlword = 0;
  std::int32_t target = 0;
  std::int32_t position = 0;

  void step() {
    while (auto f = ep->receive(0ns)) on_frame(*f);
  }
  void send(const Frame& f) { ep->send(f); }

  void on_frame(const Frame& f) {
    if (f.id == cob::nmt && f.len == 2 && (f.data[1] == id || f.data[1] == 0)) {
      nmt.push_back(f);
      if (f.data[0] == static_cast<std::uint8_t>(NmtCommand::reset_communication) && boots)
        send(Frame::make(cob::heartbeat + id, {0x00}));
    } else if (f.id == cob::sdo_rx + id) {
      on_sdo(f);
    } else if (f.id == cob::rpdo1 + id && f.len == 6) {
      const std::uint16_t previous = controlword;
      controlword = get_u16(&f.data[0]);
      target = static_cast<std::int32_t>(get_u32(&f.data[2]));
      if (run_cia402 && state == Cia402State::fault && !(previous & 0x80) && (controlword & 0x80))
        state = Cia402State::switch_on_disabled;
    } else if (f.id == cob::sync && run_cia402) {
      apply_controlword();
      if (state == Cia402State::operation_enabled) position = target;
      Frame tpdo;
      tpdo.id = cob::tpdo1 + id;
      tpdo.len = 6;
      put_u16(&tpdo.data[0], encode_statusword(state));
      put_u32(&tpdo.data[2], static_cast<std::uint32_t>(position));
      send(tpdo);
    }
  }

  void apply_controlword() {
    if (state == Cia402State::fault) return;
    const std::uint16_t cw = controlword & 0x8F;
    if ((cw & 0x02) == 0) {
      state = Cia402State::switch_on_disabled;  // disable voltage
    } else if ((cw & 0x06) == 0x02) {
      state = state == Cia402State::operation_enabled ? Cia402State::quick_stop_active
                                                      : Cia402State::switch_on_disabled;
    } else if (cw == 0x06) {
      if (state != Cia402State::quick_stop_active) state = Cia402State::ready_to_switch_on;
    } else if (cw == 0x07) {
      if (state == Cia402State::ready_to_switch_on || state == Cia402State::operation_enabled)
        state = Cia402State::switched_on;
    } else if (cw == 0x0F) {
      if (state == Cia402State::switched_on) state = Cia402State::operation_enabled;
    }
  }

  void on_sdo(const Frame& f) {
    const std::uint16_t index = get_u16(&f.data[1]);
    const std::uint8_t sub = f.data[3];
    Frame r;
    r.id = cob::sdo_tx + id;
    r.len = 8;
    r.data[1] = f.data[1];
    r.data[2] = f.data[2];
    r.data[3] = sub;
    if (auto it = abort_on.find({index, sub}); it != abort_on.end()) {
      r.data[0] = 0x80;
      put_u32(&r.data[4], it->second);
    } else if ((f.data[0] & 0xE3) == 0x23) {  // expedited download, size indicated
      const std::size_t size = 4 - ((f.data[0] >> 2) & 0x03);
      std::uint32_t value = 0;
      for (std::size_t i = 0; i < size; ++i) value |= static_cast<std::uint32_t>(f.data[4 + i]) << (8 * i);
      writes.push_back({index, sub, value, size});
      r.data[0] = 0x60;
    } else {
      r.data[0] = 0x80;
      put_u32(&r.data[4], sdo_abort::invalid_command);
    }
    send(r);
  }
};

std::vector<FakeNode::Write> expected_configuration(std::uint8_t id, std::uint8_t master_id,
                                                    std::uint16_t producer_ms, std::uint16_t consumer_ms,
                                                    std::uint8_t interp_ms) {
  const std::uint32_t rpdo1 = 0x200 + id, tpdo1 = 0x180 + id, tpdo2 = 0x280 + id;
  return {
      {0x1017, 0, producer_ms, 2},
      {0x1016, 1, (std::uint32_t{master_id} << 16) | consumer_ms, 4},
      {0x6007, 0, 3, 2},
      {0x6060, 0, 8, 1},
      {0x60C2, 1, interp_ms, 1},
      {0x60C2, 2, 0xFD, 1},  // -3
      {0x1400, 1, 0x8000'0000u | rpdo1, 4},
      {0x1600, 0, 0, 1},
      {0x1600, 1, 0x6040'0010, 4},
      {0x1600, 2, 0x607A'0020, 4},
      {0x1600, 0, 2, 1},
      {0x1400, 2, 1, 1},
      {0x1400, 1, rpdo1, 4},
      {0x1800, 1, 0x8000'0000u | tpdo1, 4},
      {0x1A00, 0, 0, 1},
      {0x1A00, 1, 0x6041'0010, 4},
      {0x1A00, 2, 0x6064'0020, 4},
      {0x1A00, 0, 2, 1},
      {0x1800, 2, 1, 1},
      {0x1800, 1, tpdo1, 4},
      {0x1801, 1, 0x8000'0000u | tpdo2, 4},
      {0x1A01, 0, 0, 1},
      {0x1A01, 1, 0x606C'0020, 4},
      {0x1A01, 2, 0x6077'0010, 4},
      {0x1A01, 0, 2, 1},
      {0x1801, 2, 1, 1},
      {0x1801, 1, tpdo2, 4},
  };
}

class MasterTest : public ::testing::Test {
 protected:
  MasterTest() {
    setup_.node_id = 0x7F;
    setup_.sync_period = 1000us;
    setup_.heartbeat_period = 20ms;
    setup_.drive_heartbeat_timeout = 100ms;
    setup_.sdo_timeout = 50ms;
    setup_.sdo_retries = 1;
    setup_.boot_timeout = 200ms;
    DriveSetup a;
    a.name = "bend_a";
    a.node_id = 2;
    a.counts_per_unit = 1000.0;
    a.offset_counts = 100;
    a.heartbeat_producer_ms = 10;
    a.master_heartbeat_timeout_ms = 150;
    DriveSetup b = a;
    b.name = "bend_b";
    b.node_id = 3;
    b.offset_counts = 0;
    drives_ = {a, b};
  }

  void make_master() {
    master_ep_ = bus_.attach("master");
    nodes_.clear();
    for (const auto& d : drives_) nodes_.push_back(std::make_unique<FakeNode>(bus_, d.node_id));
    master_ = std::make_unique<CanopenMaster>(*master_ep_, setup_, drives_);
  }
  void step_nodes() {
    for (auto& n : nodes_) n->step();
  }
  void start() {
    make_master();
    master_->start([this] { step_nodes(); });
    step_nodes();  // deliver the NMT start
    t0_ = Clock::now();
    for (auto& n : nodes_) {
      n->writes.clear();
      n->nmt.clear();
    }
  }
  // Frames the master put on the bus, as node `n` saw them.
  std::vector<Frame> drain(std::size_t n) {
    std::vector<Frame> out;
    while (auto f = nodes_[n]->ep->receive(0ns)) out.push_back(*f);
    return out;
  }
  void feed(const Frame& f, Clock::time_point t) { master_->handle(f, t); }
  Frame tpdo1(std::uint8_t node, Cia402State s, std::int32_t position) {
    Frame f;
    f.id = cob::tpdo1 + node;
    f.len = 6;
    put_u16(&f.data[0], encode_statusword(s) | statusword_bit::remote);
    put_u32(&f.data[2], static_cast<std::uint32_t>(position));
    return f;
  }
  static std::vector<Frame> with_id(const std::vector<Frame>& frames, std::uint32_t id) {
    std::vector<Frame> out;
    for (const auto& f : frames)
      if (f.id == id) out.push_back(f);
    return out;
  }

  can::VirtualBus bus_{"can0"};
  MasterSetup setup_;
  std::vector<DriveSetup> drives_;
  std::unique_ptr<can::VirtualBusEndpoint> master_ep_;
  std::vector<std::unique_ptr<FakeNode>> nodes_;
  std::unique_ptr<CanopenMaster> master_;
  Clock::time_point t0_;
};

TEST_F(MasterTest, StartResetsConfiguresEveryDriveAndStartsThem) {
  make_master();
  master_->start([this] { step_nodes(); });
  step_nodes();
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    const auto& node = *nodes_[i];
    ASSERT_EQ(node.nmt.size(), 2u);
    EXPECT_EQ(node.nmt[0].data[0], 0x82);  // reset communication
    EXPECT_EQ(node.nmt[0].data[1], node.id);
    EXPECT_EQ(node.nmt[1].data[0], 0x01);  // start
    EXPECT_EQ(node.nmt[1].data[1], node.id);
    const auto expected = expected_configuration(node.id, 0x7F, 10, 150, 1);
    ASSERT_EQ(node.writes.size(), expected.size());
    for (std::size_t k = 0; k < expected.size(); ++k) {
      EXPECT_EQ(node.writes[k], expected[k])
          << "node " << int(node.id) << " write " << k << ": got " << std::hex << node.writes[k].index << ":"
          << int(node.writes[k].sub) << " = " << node.writes[k].value << " (" << node.writes[k].size
          << " bytes)";
    }
    const auto fb = master_->feedback(i).load();
    EXPECT_TRUE(fb.booted);
    EXPECT_TRUE(fb.heartbeat_alive);
  }
  EXPECT_EQ(master_->statistics().sdo_retries, 0u);
}

TEST_F(MasterTest, InterpolationPeriodUsesFinerUnitsBelowAMillisecond) {
  setup_.sync_period = 500us;
  make_master();
  master_->start([this] { step_nodes(); });
  const auto& w = nodes_[0]->writes;
  EXPECT_EQ(w[4], (FakeNode::Write{0x60C2, 1, 5, 1}));
  EXPECT_EQ(w[5], (FakeNode::Write{0x60C2, 2, 0xFC, 1}));  // 5 x 10^-4 s
}

TEST_F(MasterTest, MissingBootUpNamesTheNode) {
  make_master();
  nodes_[1]->boots = false;
  try {
    master_->start([this] { step_nodes(); });
    FAIL() << "start() succeeded without a boot-up from node 3";
  } catch (const CanopenError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("'bend_b' (node 3)"), std::string::npos) << msg;
    EXPECT_EQ(msg.find("node 2"), std::string::npos) << msg;
    EXPECT_NE(msg.find("boot-up"), std::string::npos) << msg;
  }
}

TEST_F(MasterTest, SdoAbortDuringConfigurationNamesNodeObjectAndReason) {
  make_master();
  nodes_[0]->abort_on[{0x6060, 0}] = sdo_abort::value_range;
  try {
    master_->start([this] { step_nodes(); });
    FAIL() << "start() succeeded although the drive refused the mode";
  } catch (const CanopenError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("node 2"), std::string::npos) << msg;
    EXPECT_NE(msg.find("0x6060"), std::string::npos) << msg;
    EXPECT_NE(msg.find("mode of operation"), std::string::npos) << msg;
    EXPECT_NE(msg.find("value range"), std::string::npos) << msg;
    // Each said once: the SDO client's own "SDO write to node 2 object 0x6060:0x00" is not repeated.
    EXPECT_EQ(msg.find("0x6060", msg.find("0x6060") + 1), std::string::npos) << msg;
    EXPECT_EQ(msg.find("node 2", msg.find("node 2") + 1), std::string::npos) << msg;
  }
}

TEST_F(MasterTest, SilentSdoServerTimesOutAfterRetries) {
  make_master();
  nodes_[0]->abort_on.clear();
  // Node 2 boots but never answers SDO: swallow its requests.
  auto idle = [this] {
    while (auto f = nodes_[0]->ep->receive(0ns)) {
      if (f->id != cob::sdo_rx + 2) nodes_[0]->on_frame(*f);
    }
    nodes_[1]->step();
  };
  try {
    master_->start(idle);
    FAIL() << "start() succeeded against a silent node";
  } catch (const CanopenError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("node 2"), std::string::npos) << msg;
    EXPECT_NE(msg.find("0x1017"), std::string::npos) << msg;
    EXPECT_NE(msg.find("no answer within 50 ms (2 attempts)"), std::string::npos) << msg;
  }
  EXPECT_EQ(master_->statistics().sdo_retries, 1u);
}

TEST_F(MasterTest, RejectsBadSetup) {
  master_ep_ = bus_.attach("master");
  auto dup = drives_;
  dup[1].node_id = dup[0].node_id;
  EXPECT_THROW(CanopenMaster(*master_ep_, setup_, dup), CanopenError);
  auto zero = drives_;
  zero[0].counts_per_unit = 0.0;
  EXPECT_THROW(CanopenMaster(*master_ep_, setup_, zero), CanopenError);
  auto clash = drives_;
  clash[0].node_id = 0x7F;
  EXPECT_THROW(CanopenMaster(*master_ep_, setup_, clash), CanopenError);
  auto odd = setup_;
  odd.sync_period = 333'333us;  // not expressible in 0x60C2
  EXPECT_THROW(CanopenMaster(*master_ep_, odd, drives_), CanopenError);
}

TEST_F(MasterTest, EachCycleSendsRpdosThenSyncAndTheMasterHeartbeat) {
  start();
  master_->command(0).store({DriveRequest::disable, 0.0, 7});
  master_->poll(t0_);
  auto frames = drain(0);
  ASSERT_EQ(frames.size(), 4u);
  EXPECT_EQ(frames[0].id, 0x202u);
  EXPECT_EQ(frames[0].len, 6);
  EXPECT_EQ(frames[1].id, 0x203u);
  EXPECT_EQ(frames[2].id, cob::sync);
  EXPECT_EQ(frames[2].len, 0);
  EXPECT_EQ(frames[3].id, 0x77Fu);
  ASSERT_EQ(frames[3].len, 1);
  EXPECT_EQ(frames[3].data[0], 0x05);  // operational
  EXPECT_EQ(master_->feedback(0).load().command_sequence, 7u);

  master_->poll(t0_ + 999us);
  EXPECT_TRUE(drain(0).empty());  // nothing due, nothing urgent
  master_->poll(t0_ + 1000us);
  frames = drain(0);
  ASSERT_EQ(frames.size(), 3u);  // RPDOs + SYNC, heartbeat not due
  EXPECT_EQ(frames[2].id, cob::sync);
  master_->poll(t0_ + 20ms);
  EXPECT_EQ(with_id(drain(0), 0x77F).size(), 1u);
  EXPECT_EQ(master_->statistics().sync_sent, 3u);
  EXPECT_EQ(master_->statistics().rpdo_sent, 6u);
  EXPECT_LE(master_->next_deadline(), t0_ + 21ms);
}

TEST_F(MasterTest, TpdosUpdateFeedbackInJointUnits) {
  start();
  feed(tpdo1(2, Cia402State::operation_enabled, 2600), t0_);
  Frame tpdo2;
  tpdo2.id = cob::tpdo2 + 2;
  tpdo2.len = 6;
  put_u32(&tpdo2.data[0], static_cast<std::uint32_t>(-1500));
  put_u16(&tpdo2.data[4], static_cast<std::uint16_t>(-250));
  feed(tpdo2, t0_);
  const auto fb = master_->feedback(0).load();
  EXPECT_EQ(fb.state, Cia402State::operation_enabled);
  EXPECT_EQ(fb.statusword & statusword_bit::remote, statusword_bit::remote);
  EXPECT_DOUBLE_EQ(fb.position, 2.5);  // (2600 - 100) / 1000
  EXPECT_DOUBLE_EQ(fb.velocity, -1.5);
  EXPECT_DOUBLE_EQ(fb.effort, -250.0);
  EXPECT_EQ(master_->feedback(1).load().state, Cia402State::not_ready_to_switch_on);  // untouched
}

TEST_F(MasterTest, EnablingStepsThroughTheStateMachineHoldingTheActualPosition) {
  start();
  master_->command(0).store({DriveRequest::enable, 10.0, 1});  // far from the actual position
  const struct {
    Cia402State reported;
    std::uint16_t controlword;
    std::int32_t target;
  } steps[] = {
      {Cia402State::switch_on_disabled, controlword::shutdown, 5000},
      {Cia402State::ready_to_switch_on, controlword::switch_on, 5000},
      {Cia402State::switched_on, controlword::enable_operation, 5000},
      {Cia402State::operation_enabled, controlword::enable_operation, 10'100},  // 10 * 1000 + 100
  };
  auto t = t0_;
  for (const auto& s : steps) {
    feed(tpdo1(2, s.reported, 5000), t);
    master_->poll(t);
    const auto rpdo = with_id(drain(0), 0x202);
    ASSERT_EQ(rpdo.size(), 1u) << to_string(s.reported);
    EXPECT_EQ(get_u16(&rpdo[0].data[0]), s.controlword) << to_string(s.reported);
    EXPECT_EQ(static_cast<std::int32_t>(get_u32(&rpdo[0].data[2])), s.target) << to_string(s.reported);
    t += 1ms;
  }
}

TEST_F(MasterTest, ClosedLoopEnableReachesOperationEnabledWithoutAJump) {
  start();
  for (auto& n : nodes_) {
    n->run_cia402 = true;
    n->position = 4200;
  }
  // One cycle so the drives report their position before the enable request.
  master_->poll(t0_);
  step_nodes();
  while (auto f = master_ep_->receive(0ns)) master_->handle(*f, t0_);
  master_->command(0).store({DriveRequest::enable, 7.0, 1});  // 7100 counts: 2.9 units away
  auto t = t0_;
  bool jumped_while_enabling = false;
  for (int cycle = 1; cycle <= 8; ++cycle) {
    t += 1ms;
    master_->poll(t);
    step_nodes();
    if (nodes_[0]->state != Cia402State::operation_enabled && nodes_[0]->target != 4200)
      jumped_while_enabling = true;
    while (auto f = master_ep_->receive(0ns)) master_->handle(*f, t);
  }
  EXPECT_FALSE(jumped_while_enabling);
  const auto fb = master_->feedback(0).load();
  EXPECT_EQ(fb.state, Cia402State::operation_enabled);
  EXPECT_NEAR(fb.position, 7.0, 1e-9);  // (7100 - 100) / 1000 once enabled and following
  EXPECT_EQ(master_->feedback(1).load().state, Cia402State::switch_on_disabled);  // still disabled
}

TEST_F(MasterTest, FaultResetIsARisingEdgeThenFollowsAsDisable) {
  start();
  feed(tpdo1(2, Cia402State::fault, 0), t0_);
  master_->command(0).store({DriveRequest::disable, 0.0, 1});
  master_->poll(t0_);
  auto rpdo = with_id(drain(0), 0x202);
  ASSERT_EQ(rpdo.size(), 1u);
  EXPECT_EQ(get_u16(&rpdo[0].data[0]), controlword::disable_voltage);

  master_->command(0).store({DriveRequest::fault_reset, 0.0, 2});
  master_->poll(t0_ + 1ms);
  rpdo = with_id(drain(0), 0x202);
  ASSERT_EQ(rpdo.size(), 1u);
  EXPECT_EQ(get_u16(&rpdo[0].data[0]), 0x0000);  // bit 7 low first
  master_->poll(t0_ + 2ms);
  rpdo = with_id(drain(0), 0x202);
  ASSERT_EQ(rpdo.size(), 1u);
  EXPECT_EQ(get_u16(&rpdo[0].data[0]), controlword::fault_reset_bit);  // then high: the edge

  feed(tpdo1(2, Cia402State::switch_on_disabled, 0), t0_ + 2ms);
  master_->poll(t0_ + 3ms);
  rpdo = with_id(drain(0), 0x202);
  ASSERT_EQ(rpdo.size(), 1u);
  EXPECT_EQ(get_u16(&rpdo[0].data[0]), controlword::disable_voltage);  // follows as disable
}

TEST_F(MasterTest, QuickStopIsSentAtTheNextPollNotTheNextSync) {
  start();
  feed(tpdo1(2, Cia402State::operation_enabled, 1100), t0_);
  master_->command(0).store({DriveRequest::enable, 1.0, 1});
  master_->poll(t0_);
  drain(0);
  master_->command(0).store({DriveRequest::quick_stop, 1.0, 2});
  master_->poll(t0_ + 100us);  // SYNC not due for another 900 us
  auto frames = drain(0);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].id, 0x202u);
  EXPECT_EQ(get_u16(&frames[0].data[0]), controlword::quick_stop);
  EXPECT_EQ(static_cast<std::int32_t>(get_u32(&frames[0].data[2])), 1100);  // hold where it is
  EXPECT_EQ(master_->feedback(0).load().command_sequence, 2u);
  master_->poll(t0_ + 200us);
  EXPECT_TRUE(drain(0).empty());  // sent once, not every poll
  master_->poll(t0_ + 1ms);
  const auto rpdo = with_id(drain(0), 0x202);
  ASSERT_EQ(rpdo.size(), 1u);
  EXPECT_EQ(get_u16(&rpdo[0].data[0]), controlword::quick_stop);
}

TEST_F(MasterTest, DisableIsUrgentToo) {
  start();
  feed(tpdo1(3, Cia402State::operation_enabled, 0), t0_);
  master_->command(1).store({DriveRequest::enable, 0.0, 1});
  master_->poll(t0_);
  drain(1);
  master_->command(1).store({DriveRequest::disable, 0.0, 2});
  master_->poll(t0_ + 10us);
  const auto frames = drain(1);
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].id, 0x203u);
  EXPECT_EQ(get_u16(&frames[0].data[0]), controlword::shutdown);
}

TEST_F(MasterTest, MissingDriveHeartbeatMarksItDead) {
  start();
  EXPECT_TRUE(master_->feedback(0).load().heartbeat_alive);
  master_->poll(t0_);  // the bus thread's first poll starts the consumer clocks
  master_->poll(t0_ + 100ms);
  EXPECT_TRUE(master_->feedback(0).load().heartbeat_alive);
  const auto t = t0_ + 50ms;
  feed(Frame::make(cob::heartbeat + 2, {0x05}), t);
  feed(Frame::make(cob::heartbeat + 3, {0x05}), t);
  master_->poll(t + 100ms);  // exactly the consumer time: still alive
  EXPECT_TRUE(master_->feedback(0).load().heartbeat_alive);
  feed(Frame::make(cob::heartbeat + 3, {0x05}), t + 100ms);
  master_->poll(t + 101ms);
  const auto fb0 = master_->feedback(0).load();
  EXPECT_FALSE(fb0.heartbeat_alive);
  EXPECT_EQ(fb0.nmt, NmtState::operational);
  EXPECT_TRUE(master_->feedback(1).load().heartbeat_alive);  // node 3 kept talking
  feed(Frame::make(cob::heartbeat + 2, {0x05}), t + 150ms);
  EXPECT_TRUE(master_->feedback(0).load().heartbeat_alive);
  EXPECT_EQ(master_->next_deadline() <= t + 250ms, true);
}

TEST_F(MasterTest, EmergencyMessagesAreRecorded) {
  start();
  feed(Frame::make(cob::emcy + 3, {0x10, 0x23, 0x04, 0, 0, 0, 0, 0}), t0_);  // over-current
  feed(Frame::make(cob::emcy + 3, {0x11, 0x86, 0x80, 0, 0, 0, 0, 0}), t0_);  // following error
  const auto fb = master_->feedback(1).load();
  EXPECT_EQ(fb.emcy_count, 2u);
  EXPECT_EQ(fb.last_emcy_code, emcy_code::following_error);
  EXPECT_EQ(fb.last_emcy_register, 0x80);
  EXPECT_EQ(master_->feedback(0).load().emcy_count, 0u);
  EXPECT_EQ(master_->statistics().emcy_received, 2u);
}

TEST_F(MasterTest, ShutdownDisablesDrivesThenEntersPreOperational) {
  start();
  for (auto& n : nodes_) {
    n->run_cia402 = true;
    n->state = Cia402State::operation_enabled;
  }
  master_->command(0).store({DriveRequest::enable, 0.0, 1});
  master_->command(1).store({DriveRequest::enable, 0.0, 1});
  // The bus thread runs a stepped clock 10 s ahead of the real one: shutdown() must carry on
  // from the bus thread's time, or no SYNC would be due for 10 s.
  const auto stepped = t0_ + 10s;
  feed(tpdo1(2, Cia402State::operation_enabled, 0), stepped);  // what the drives last reported
  feed(tpdo1(3, Cia402State::operation_enabled, 0), stepped);
  master_->poll(stepped);
  step_nodes();
  while (auto f = master_ep_->receive(0ns)) master_->handle(*f, stepped);
  ASSERT_EQ(master_->feedback(0).load().state, Cia402State::operation_enabled);
  master_->shutdown(500ms, [this] { step_nodes(); });
  step_nodes();
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    EXPECT_EQ(nodes_[i]->state, Cia402State::ready_to_switch_on);
    const auto fb = master_->feedback(i).load();
    EXPECT_EQ(fb.state, Cia402State::ready_to_switch_on);
    ASSERT_FALSE(nodes_[i]->nmt.empty());
    EXPECT_EQ(nodes_[i]->nmt.back().data[0], 0x80);  // enter pre-operational
  }
  EXPECT_TRUE(master_->feedback(0).load().heartbeat_alive);  // no false heartbeat loss either
  const auto syncs = master_->statistics().sync_sent;
  master_->poll(Clock::now() + 1s);
  EXPECT_EQ(master_->statistics().sync_sent, syncs);  // stopped cycling
}

TEST_F(MasterTest, PollAndHandleDoNotAllocate) {
  start();
  for (auto& n : nodes_) n->run_cia402 = true;
  master_->command(0).store({DriveRequest::enable, 1.0, 1});
  master_->command(1).store({DriveRequest::quick_stop, 0.0, 1});
  std::vector<Frame> received;
  received.reserve(64);
  auto t = t0_;
  g_allocations = 0;
  for (int cycle = 0; cycle < 50; ++cycle) {
    g_count_allocations = true;
    master_->poll(t);
    for (const auto& f : received) master_->handle(f, t);
    master_->handle(Frame::make(cob::emcy + 2, {0x00, 0x10, 0x01, 0, 0, 0, 0, 0}), t);
    master_->handle(Frame::make(cob::heartbeat + 3, {0x05}), t);
    g_count_allocations = false;
    received.clear();
    step_nodes();
    while (auto f = master_ep_->receive(0ns)) received.push_back(*f);
    t += 1ms;
  }
  EXPECT_EQ(g_allocations.load(), 0);
  EXPECT_EQ(master_->feedback(0).load().state, Cia402State::operation_enabled);  // the loop did run
}

}  // namespace
}  // namespace tendril::canopen
