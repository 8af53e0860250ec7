// What the drives do when tendrild dies: SIGKILL while the robot moves, measured at the drives.
//
// The SIMULATED CiA 402 drives of config/robots/srmc.json run here, in this test's process, each on
// its own SocketCAN socket on vcan0; tendrild runs in a process of its own as their CANopen master over
// SocketCAN (the robot file as shipped, its bus moved from "virtual" to vcan0). At start-up tendrild
// configures every drive to consume its heartbeat (0x1016: master node id, consumer time) and to
// quick-stop when that heartbeat ends (0x6007 = 3). The test enables the robot and starts a move over
// REST, kills tendrild with SIGKILL while the insertion drive moves, and measures on this process's
// steady clock, per drive, the time from the kill until the drive's statusword leaves "operation
// enabled" for its quick-stop reaction (fault reaction active, ramping at the quick-stop deceleration
// 0x6085, then fault with EMCY 0x8130).
//
// The bound asserted is the configured one, in the drive's own time: the consumer time after the last
// heartbeat the drive received (which tendrild sent before it died), plus the one drive cycle in which
// the silence is noticed. The cycle is the one the simulated drive actually got from the VM (nominal
// 1 ms; the VM stalls now and then), so the assertion is about the mechanism, not about the speed of
// this machine. The numbers are printed for the report.
//
// Runs inside the qemu VM of tests/can-vm (vcan0, root, one CPU): TENDRIL_TENDRILD names the tendrild
// binary. Skips elsewhere.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/http.hpp>
#include <nlohmann/json.hpp>

#include "tendril/drivers/can/socketcan_bus.hpp"
#include "tendril/drivers/canopen/protocol.hpp"
#include "tendril/drivers/sim/simulated_analog_input_node.hpp"
#include "tendril/drivers/sim/simulated_drive.hpp"

extern char** environ;

namespace tendril {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;
using Cia = canopen::Cia402State;
namespace bhttp = boost::beast::http;
namespace net = boost::asio;

constexpr std::chrono::nanoseconds kDriveCycle = std::chrono::milliseconds(1);

double ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }
std::int64_t ticks(Clock::time_point t) { return t.time_since_epoch().count(); }
Clock::time_point from_ticks(std::int64_t n) { return Clock::time_point(Clock::duration(n)); }

sim::DriveParameters preset(const std::string& name, const std::string& joint) {
  if (name == "srmc_insertion") return sim::DriveParameters::srmc_insertion(joint);
  if (name == "srmc_roll") return sim::DriveParameters::srmc_roll(joint);
  if (name == "srmc_bend") return sim::DriveParameters::srmc_bend(joint);
  throw std::runtime_error("srmc.json: no simulated drive preset '" + name + "'");
}

// What one drive's cycle saw, published for the test thread (atomics: the drive thread writes).
struct DriveWatch {
  std::atomic<int> state{static_cast<int>(Cia::not_ready_to_switch_on)};
  std::atomic<double> velocity{0.0};
  std::atomic<double> position{0.0};
  std::atomic<std::uint32_t> consumer{0};       // 0x1016 sub1 as configured by the master
  std::atomic<std::int64_t> last_heartbeat{0};  // when the drive handled the master's heartbeat
  std::atomic<std::int64_t> kill_time{0};       // set by the test thread just before the kill
  std::atomic<double> kill_position{0.0};       // at the first cycle after the kill
  std::atomic<bool> kill_seen{false};
  // The quick stop: the first cycle after the kill that found the drive out of operation enabled.
  std::atomic<std::int64_t> stop_time{0};
  std::atomic<std::int64_t> stop_cycle{0};  // that cycle's length (now - previous cycle)
  std::atomic<std::int64_t> heartbeat_before_stop{0};
  std::atomic<int> stop_state{0};
  std::atomic<std::uint16_t> stop_statusword{0};
  std::atomic<std::int64_t> standstill_time{0};  // first cycle after the kill with |v| < 1 % of max
  std::atomic<double> standstill_position{0.0};
  std::atomic<std::int64_t> powerless_time{0};  // power stage off (fault / switch-on disabled)
  std::atomic<std::uint32_t> error_code{0};     // 0x603F once in fault
};

// The SIMULATED drives on vcan0 with their own 1 kHz loop (absolute deadlines, SCHED_FIFO when
// permitted), like hardware on the other end of the wire.
class DriveRack {
 public:
  struct Slot {
    std::unique_ptr<can::SocketCanBus> bus;
    std::unique_ptr<sim::SimulatedCia402Drive> drive;
    double max_velocity = 0.0;
    DriveWatch watch;
  };

  void add(std::uint8_t node_id, sim::DriveParameters params) {
    auto slot = std::make_unique<Slot>();
    slot->bus = std::make_unique<can::SocketCanBus>("vcan0");
    slot->max_velocity = params.max_velocity;
    slot->drive = std::make_unique<sim::SimulatedCia402Drive>(node_id, *slot->bus, std::move(params));
    slots_.push_back(std::move(slot));
  }
  // The catheter's SIMULATED spring-deflection ADC node (CiA 401) on its own vcan0 endpoint: the
  // catheter holds the robot without its readings, as it must on the real rack.
  void add_adc(std::uint8_t node_id) {
    adc_bus_ = std::make_unique<can::SocketCanBus>("vcan0");
    sim::AnalogInputNodeParameters params;
    params.node_id = node_id;
    adc_ = std::make_unique<sim::SimulatedAnalogInputNode>(*adc_bus_, params);
  }
  std::vector<std::unique_ptr<Slot>>& slots() { return slots_; }
  bool realtime() const { return realtime_.load(); }
  double worst_cycle_ms() const { return static_cast<double>(worst_cycle_ns_.load()) / 1e6; }

  void start() {
    thread_ = std::thread([this] { run(); });
  }
  void stop() {
    stop_.store(true);
    if (thread_.joinable()) thread_.join();
  }
  ~DriveRack() { stop(); }

 private:
  static void advance(timespec& t, std::chrono::nanoseconds by) {
    t.tv_nsec += by.count();
    while (t.tv_nsec >= 1'000'000'000) {
      t.tv_nsec -= 1'000'000'000;
      ++t.tv_sec;
    }
  }

  void run() {
    sched_param param{};
    param.sched_priority = 80;
    realtime_.store(pthread_setschedparam(pthread_self(), SCHED_FIFO, &param) == 0);
    timespec next{};
    clock_gettime(CLOCK_MONOTONIC, &next);
    auto previous = Clock::now();
    while (!stop_.load(std::memory_order_relaxed)) {
      const auto now = Clock::now();
      const auto cycle = now - previous;
      const double dt = std::clamp(std::chrono::duration<double>(cycle).count(), 1e-4, 0.01);
      for (auto& slot : slots_) cycle_one(*slot, now, previous, dt);
      if (adc_) adc_->step(dt);
      if (slots_[0]->watch.kill_time.load() != 0)
        worst_cycle_ns_.store(std::max<std::int64_t>(worst_cycle_ns_.load(), (now - previous).count()));
      previous = now;
      advance(next, kDriveCycle);
      // Behind (a cycle's work outlasted its period on the VM's emulated CPU): restart the schedule a
      // full cycle from now. Running late cycles back to back at SCHED_FIFO would leave tendrild (not
      // real-time here) almost no CPU: it then started in minutes and its heartbeat went silent.
      timespec now_ts{};
      clock_gettime(CLOCK_MONOTONIC, &now_ts);
      if (now_ts.tv_sec > next.tv_sec || (now_ts.tv_sec == next.tv_sec && now_ts.tv_nsec > next.tv_nsec)) {
        next = now_ts;
        advance(next, kDriveCycle);
      }
      clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, nullptr);
    }
  }

  static void cycle_one(Slot& slot, Clock::time_point now, Clock::time_point previous, double dt) {
    auto& drive = *slot.drive;
    auto& w = slot.watch;
    const std::uint32_t consumer = w.consumer.load();
    const std::uint32_t master_heartbeat = canopen::cob::heartbeat + (consumer >> 16);
    while (auto frame = slot.bus->receive(std::chrono::nanoseconds(0))) {
      if (!frame->error && consumer != 0 && frame->id == master_heartbeat) w.last_heartbeat.store(ticks(now));
      drive.handle(*frame, now);
    }
    drive.step(now, dt);
    const auto state = drive.state();
    const auto truth = drive.truth();
    w.state.store(static_cast<int>(state));
    w.velocity.store(truth.velocity);
    w.position.store(truth.position);
    w.consumer.store(
        static_cast<std::uint32_t>(drive.dictionary().find(canopen::od::consumer_heartbeat_time, 1)->value));
    const std::int64_t killed = w.kill_time.load();
    if (killed == 0 || ticks(now) < killed) return;
    if (!w.kill_seen.exchange(true)) w.kill_position.store(truth.position);
    if (w.stop_time.load() == 0 && state != Cia::operation_enabled) {
      w.stop_cycle.store((now - previous).count());
      w.heartbeat_before_stop.store(w.last_heartbeat.load());
      w.stop_state.store(static_cast<int>(state));
      w.stop_statusword.store(drive.statusword());
      w.stop_time.store(ticks(now));
    }
    if (w.standstill_time.load() == 0 && std::abs(truth.velocity) < 0.01 * slot.max_velocity) {
      w.standstill_position.store(truth.position);
      w.standstill_time.store(ticks(now));
    }
    if (w.powerless_time.load() == 0 && (state == Cia::fault || state == Cia::switch_on_disabled)) {
      w.error_code.store(
          static_cast<std::uint32_t>(drive.dictionary().find(canopen::od::error_code, 0)->value));
      w.powerless_time.store(ticks(now));
    }
  }

  std::vector<std::unique_ptr<Slot>> slots_;
  std::unique_ptr<can::SocketCanBus> adc_bus_;
  std::unique_ptr<sim::SimulatedAnalogInputNode> adc_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> realtime_{false};
  std::atomic<std::int64_t> worst_cycle_ns_{0};
};

struct Reply {
  int status = 0;
  json body;
};

// One request on a new connection (like curl); status 0 when tendrild is not answering.
Reply http(unsigned short port, bhttp::verb verb, const std::string& target, const std::string& token,
           const std::string& body = "") {
  Reply reply;
  try {
    net::io_context ioc;
    net::ip::tcp::socket socket(ioc);
    socket.connect({net::ip::make_address("127.0.0.1"), port});
    bhttp::request<bhttp::string_body> req{verb, target, 11};
    req.set(bhttp::field::host, "127.0.0.1");
    if (!token.empty()) req.set(bhttp::field::authorization, "Bearer " + token);
    req.body() = body;
    req.prepare_payload();
    bhttp::write(socket, req);
    boost::beast::flat_buffer buffer;
    bhttp::response<bhttp::string_body> res;
    bhttp::read(socket, buffer, res);
    reply.status = static_cast<int>(res.result_int());
    reply.body = json::parse(res.body(), nullptr, false);
  } catch (const std::exception&) {
    reply.status = 0;
  }
  return reply;
}

unsigned short free_port() {
  net::io_context ioc;
  net::ip::tcp::acceptor acceptor(ioc, {net::ip::make_address("127.0.0.1"), 0});
  return acceptor.local_endpoint().port();
}

std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(TendrildSigkill, DrivesQuickStopWithinTheHeartbeatConsumerTimeOfTheMastersDeath) {
  const char* tendrild = std::getenv("TENDRIL_TENDRILD");
  if (tendrild == nullptr || !std::filesystem::exists(tendrild)) {
    if (std::getenv("TENDRIL_CAN_VM") != nullptr) FAIL() << "set TENDRIL_TENDRILD to the tendrild binary";
    GTEST_SKIP() << "TENDRIL_TENDRILD is not set (this test runs inside tests/can-vm)";
  }
  DriveRack rack;
  // The shipped robot file: the drives, their presets and the bus timing (heartbeat period and the
  // drives' consumer time) are what tendril ships with.
  json robot = json::parse(read_file(std::string(TENDRIL_SOURCE_DIR) + "/config/robots/srmc.json"));
  try {
    for (const auto& joint : robot["joints"]) {
      auto params = preset(joint["simulation"]["preset"], joint["name"]);
      params.initial_position = joint.value("initial_position", 0.0);
      ASSERT_NEAR(params.counts_per_unit(), joint["drive"]["counts_per_unit"].get<double>(), 1e-6);
      rack.add(static_cast<std::uint8_t>(joint["drive"]["node_id"].get<int>()), std::move(params));
    }
  } catch (const can::CanSetupError& e) {
    if (std::getenv("TENDRIL_CAN_VM") != nullptr) FAIL() << "vcan0 not available inside the VM: " << e.what();
    GTEST_SKIP() << "vcan0 not available: " << e.what();
  }
  ASSERT_EQ(robot["buses"].size(), 1u);
  auto& bus = robot["buses"][0];
  bus["interface"] = "vcan0";
  // One TCG CPU runs the sanitized tendrild's start-up beside the drives: in a CI run the master's
  // 20 ms heartbeat once went silent for more than the shipped 250 ms consumer time before the enable
  // (EMCY 0x8130, the robot FAULT before the move). The mechanism under test does not depend on the
  // value, so the VM uses 1000 ms; the bound asserted below is the configured value, whatever it is.
  bus["master_heartbeat_timeout_ms"] = 1000;
  const int consumer_ms = bus["master_heartbeat_timeout_ms"];
  const int heartbeat_ms = bus["heartbeat_period_ms"];
  // The catheter's spring-deflection and joystick ADC nodes are simulated with the virtual bus only;
  // this test is about the drives, so the catheter section keeps its model and the spring-deflection
  // sensor (simulated in the rack, at rest), and the joystick node is left out. One TCG CPU is
  // shared with the drives, so the control loop's lost-time bound (half the shorter of the command
  // timeout and the heartbeat consumer time) is widened to 500 ms by a longer command timeout.
  robot["catheter"] = json{{"model", robot["catheter"]["model"]},
                           {"spring_deflection", robot["catheter"]["spring_deflection"]}};
  try {
    rack.add_adc(static_cast<std::uint8_t>(robot["catheter"]["spring_deflection"]["node_id"].get<int>()));
  } catch (const can::CanSetupError& e) {
    FAIL() << "vcan0 for the ADC node: " << e.what();
  }
  robot["command_timeout_ms"] = 1000;
  // A robot file's control rate must be the server's (the one control thread runs every robot).
  robot["control_rate_hz"] = 250;

  const auto dir = std::filesystem::temp_directory_path() / ("tendril-sigkill-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "srmc.json") << robot.dump(2);
  const unsigned short port = free_port();
  const std::string token = "sigkill-test-token";
  const json server = {{"listen", "127.0.0.1:" + std::to_string(port)},
                       {"token", token},
                       {"control_rate_hz", 250},
                       {"publish_rate_hz", 10},
                       {"realtime_priority", false},
                       {"imaging", {{"enabled", false}}},
                       {"robots", {(dir / "srmc.json").string()}}};
  std::ofstream(dir / "server.json") << server.dump(2);

  rack.start();  // the drives are powered before the master starts, as on a real rack
  const std::string log = (dir / "tendrild.log").string();
  posix_spawn_file_actions_t files;
  posix_spawn_file_actions_init(&files);
  posix_spawn_file_actions_addopen(&files, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&files, STDOUT_FILENO, STDERR_FILENO);
  const std::string config = (dir / "server.json").string();
  std::array<const char*, 5> argv{tendrild, "--config", config.c_str(), "--no-realtime", nullptr};
  pid_t pid = 0;
  ASSERT_EQ(posix_spawn(&pid, tendrild, &files, nullptr, const_cast<char* const*>(argv.data()), environ), 0);
  posix_spawn_file_actions_destroy(&files);
  bool reaped = false;
  struct Reaper {
    pid_t pid;
    bool& reaped;
    ~Reaper() {
      if (!reaped) {
        kill(pid, SIGKILL);
        waitpid(pid, nullptr, 0);
      }
    }
  } reaper{pid, reaped};

  // Up: /health answers (bounded by a count of tries, about two minutes: the 240 MB sanitized binary
  // alone takes ~9 s to load over 9p in the VM; a tendrild that exited is reported at once).
  bool up = false;
  for (int i = 0; i < 600 && !up; ++i) {
    int status = 0;
    if (waitpid(pid, &status, WNOHANG) == pid) {
      reaped = true;
      FAIL() << "tendrild exited during start-up (status " << status << "):\n" << read_file(log);
    }
    up = http(port, bhttp::verb::get, "/api/v1/health", "").status == 200;
    if (!up) std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  ASSERT_TRUE(up) << "tendrild did not answer /api/v1/health:\n" << read_file(log);

  // Enable and start a long move, as a plain-curl operator would.
  ASSERT_EQ(http(port, bhttp::verb::post, "/api/v1/lease", token).status, 200);
  const Reply enable =
      http(port, bhttp::verb::post, "/api/v1/robots/srmc/state_command", token, R"({"command":"enable"})");
  ASSERT_EQ(enable.status, 200) << enable.body.dump() << "\ntendrild log:\n" << read_file(log);
  bool ready = false;
  std::string last_state;
  for (int i = 0; i < 300 && !ready; ++i) {
    const Reply s = http(port, bhttp::verb::get, "/api/v1/robots/srmc/operating_state", token);
    ready = s.status == 200 && s.body.value("state", "") == "ENABLED" &&
            s.body.value("drives_ready", false) && !s.body.value("is_busy", true);
    last_state = s.body.dump();
    if (!ready) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(ready) << "last operating_state: " << last_state << "\n" << read_file(log);
  for (auto& slot : rack.slots()) {
    const auto configured = slot->watch.consumer.load();
    EXPECT_EQ(configured & 0xFFFFu, static_cast<std::uint32_t>(consumer_ms))
        << slot->drive->parameters().name << ": 0x1016 sub1 configured by tendrild";
    EXPECT_EQ(
        static_cast<int>(slot->drive->dictionary().find(canopen::od::abort_connection_option, 0)->value), 3)
        << slot->drive->parameters().name << ": 0x6007 = quick stop";
  }
  // Insertion from 10 mm to 60 mm at its 10 mm/s limit: about 5 s of motion.
  const Reply move =
      http(port, bhttp::verb::post, "/api/v1/robots/srmc/move_jp", token, R"({"goal":[60,0,0,0]})");
  ASSERT_EQ(move.status, 202) << move.body.dump();
  auto& insertion = rack.slots()[0]->watch;
  // Moving: the drive has left its start by 1 mm and is short of the goal. Judged by position, not by
  // a velocity sample: on the VM's emulated CPU the move can start seconds late and run slow (bounded
  // wait of 60 s of this process's clock).
  const double start_position = insertion.position.load();
  bool moving = false;
  const auto wait_until = Clock::now() + std::chrono::seconds(60);
  while (!moving && Clock::now() < wait_until) {
    const double p = insertion.position.load();
    moving = p > start_position + 1.0 && p < 59.0;  // mm
    if (!moving) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  ASSERT_TRUE(moving) << "the insertion drive did not move 1 mm towards 60 mm in 60 s (from "
                      << start_position << " mm, now " << insertion.position.load() << " mm)";
  std::vector<int> state_at_kill;
  for (auto& slot : rack.slots()) state_at_kill.push_back(slot->watch.state.load());
  const double velocity_at_kill = insertion.velocity.load();

  // SIGKILL: no signal handler, no orderly disable, the sockets close with the process.
  const auto killed = Clock::now();
  for (auto& slot : rack.slots()) slot->watch.kill_time.store(ticks(killed));
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  reaped = true;
  const auto dead = Clock::now();
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);

  // Every drive stops by itself (bounded wait so a broken consumer fails instead of hanging).
  auto all_powerless = [&] {
    for (auto& slot : rack.slots())
      if (slot->watch.powerless_time.load() == 0 || slot->watch.standstill_time.load() == 0) return false;
    return true;
  };
  for (int i = 0; i < 2000 && !all_powerless(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  rack.stop();

  std::printf(
      "tendrild SIGKILL while moving (insertion at %.2f mm/s): consumer time %d ms (0x1016), heartbeat "
      "period %d ms, drive cycle %.1f ms nominal, worst %.1f ms after the kill, drive loop %s; "
      "waitpid returned %.2f ms after kill()\n",
      velocity_at_kill, consumer_ms, heartbeat_ms, ms(kDriveCycle), rack.worst_cycle_ms(),
      rack.realtime() ? "SCHED_FIFO" : "not real-time", ms(dead - killed));
  for (std::size_t k = 0; k < rack.slots().size(); ++k) {
    auto& slot = *rack.slots()[k];
    auto& w = slot.watch;
    const std::string name = slot.drive->parameters().name;
    SCOPED_TRACE(name);
    EXPECT_EQ(state_at_kill[k], static_cast<int>(Cia::operation_enabled)) << "enabled when tendrild died";
    ASSERT_NE(w.stop_time.load(), 0) << "the drive never left operation enabled after the kill";
    ASSERT_NE(w.powerless_time.load(), 0) << "the power stage never went off";
    const auto stop = from_ticks(w.stop_time.load());
    const auto last_heartbeat = from_ticks(w.heartbeat_before_stop.load());
    const auto cycle = Clock::duration(w.stop_cycle.load());
    // The configured bound in the drive's time: consumer time after the last heartbeat it received,
    // plus the cycle that noticed. The last heartbeat came from the living tendrild; if the drive
    // handled it after the kill (a late cycle), the clock starts there.
    const auto consumer = std::chrono::milliseconds(consumer_ms);
    const auto clock_start = std::max(killed, last_heartbeat);
    EXPECT_GT(stop - last_heartbeat, consumer) << "quick-stopped before the consumer time of silence";
    EXPECT_LE(stop - clock_start, consumer + cycle) << "later than consumer time + one drive cycle";
    EXPECT_TRUE(w.stop_state.load() == static_cast<int>(Cia::fault_reaction_active) ||
                w.stop_state.load() == static_cast<int>(Cia::quick_stop_active) ||
                w.stop_state.load() == static_cast<int>(Cia::fault))
        << "state " << w.stop_state.load();
    EXPECT_EQ(w.error_code.load(), canopen::emcy_code::heartbeat_lost) << "0x603F: heartbeat lost (0x8130)";
    const auto standstill = from_ticks(w.standstill_time.load());
    std::printf(
        "  %-14s kill -> quick stop %7.1f ms (statusword 0x%04x, %s; bound %.1f ms = consumer %d ms + "
        "cycle %.1f ms, from the last heartbeat %.1f ms before the kill), -> standstill %6.1f ms "
        "(moved %.3f after the kill), -> power stage off %6.1f ms, EMCY 0x%04x\n",
        name.c_str(), ms(stop - killed), w.stop_statusword.load(),
        w.stop_state.load() == static_cast<int>(Cia::fault_reaction_active)
            ? "fault reaction (quick-stop ramp)"
            : "fault",
        ms(consumer + cycle + (clock_start - killed)), consumer_ms, ms(cycle), ms(killed - last_heartbeat),
        ms(standstill - killed), w.standstill_position.load() - w.kill_position.load(),
        ms(from_ticks(w.powerless_time.load()) - killed), w.error_code.load());
  }
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);
}

}  // namespace
}  // namespace tendril
