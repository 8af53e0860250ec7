// server_latency_bench: end-to-end timing of tendrild, in one process, in real time (not stepped).
//
// Builds the runtime from a robot file (simulated drives on a virtual CAN bus) at 1 kHz, serves
// REST + WebSocket on 127.0.0.1, keeps N Foxglove WebSocket clients subscribed and reading, and
// measures:
//   1. control-loop period error (p50/p99/max) from RobotRuntime::loop_statistics();
//   2. REST servo_jv → first CAN RPDO1 that carries the new motion, seen on a bus tap;
//   3. the same through a Foxglove WebSocket service call;
//   and, as a reference without the network, ControlApi::servo_jv called in process -> RPDO1.
// Latency = from just before the request is written to the tap frame's bus timestamp (the moment
// the CANopen master put the frame on the virtual bus; same steady clock). It therefore includes
// the network stack, request parsing, the command mailbox, the wait for the next control tick and
// the wait for the next SYNC period (RPDOs go out once per SYNC, 2.5 ms for the SRMC bus).
//
// A benchmark, not a test: it reports numbers and asserts nothing about speed.
#include <sys/utsname.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include "tendril/drivers/can/bus.hpp"
#include "tendril/server/config.hpp"
#include "tendril/server/http/control_json.hpp"
#include "tendril/server/http/foxglove_protocol.hpp"
#include "tendril/server/http/http_server.hpp"
#include "tendril/server/robot_runtime.hpp"
#include "tendril/server/robot_types.hpp"

#ifndef TENDRIL_SOURCE_DIR
#define TENDRIL_SOURCE_DIR "."
#endif

namespace {

namespace beast = boost::beast;
namespace bhttp = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
namespace fg = tendril::server::http::foxglove;
using tcp = net::ip::tcp;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

constexpr const char* kUsage = R"(usage: server_latency_bench [options]

End-to-end timing of the tendril server in one process: RT loop period error with WebSocket
subscribers connected, and command -> CAN frame latency over REST and over a WebSocket service call.

options:
  --config FILE      robot file (default: config/robots/srmc.json in the source tree)
  --robot NAME       robot to command (default: the robot file's name)
  --bus NAME         bus to tap (default: the commanded joint's bus)
  --joint NAME       joint to command (default: proximal_bend)
  --velocity V       servo velocity in joint units/s (default: 1.0)
  --seconds S        length of the loop-statistics window (default: 10)
  --iterations N     measured commands per path (default: 300; plus 10 warm-up)
  --clients N        subscribed WebSocket clients (default: 4)
  --rate HZ          control rate (default: 1000)
  --realtime         ask for SCHED_FIFO + mlockall for the control thread (default: off)
  --json FILE        also write the results as JSON to FILE
  --help             print this help
)";

struct Options {
  std::filesystem::path robot_file = std::filesystem::path(TENDRIL_SOURCE_DIR) / "config/robots/srmc.json";
  std::string robot, bus, joint = "proximal_bend";
  double velocity = 1.0;
  double loop_seconds = 10.0;
  int iterations = 300;
  int warmup = 10;
  int clients = 4;
  double rate_hz = 1000.0;
  bool realtime = false;
  std::string json_path;
};

[[noreturn]] void usage_error(const std::string& message) {
  std::cerr << "server_latency_bench: " << message << "\n(see --help)\n";
  std::exit(2);
}

Options parse_options(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usage_error(arg + " needs a value");
      return argv[++i];
    };
    auto number = [&]() -> double {
      const std::string v = value();
      try {
        std::size_t used = 0;
        const double d = std::stod(v, &used);
        if (used == v.size() && std::isfinite(d)) return d;
      } catch (const std::exception&) {
      }
      usage_error(arg + " expects a number, got '" + v + "'");
    };
    if (arg == "--help" || arg == "-h") {
      std::cout << kUsage;
      std::exit(0);
    } else if (arg == "--config") {
      o.robot_file = value();
    } else if (arg == "--robot") {
      o.robot = value();
    } else if (arg == "--bus") {
      o.bus = value();
    } else if (arg == "--joint") {
      o.joint = value();
    } else if (arg == "--velocity") {
      o.velocity = number();
    } else if (arg == "--seconds") {
      o.loop_seconds = number();
    } else if (arg == "--iterations") {
      o.iterations = static_cast<int>(number());
    } else if (arg == "--clients") {
      o.clients = static_cast<int>(number());
    } else if (arg == "--rate") {
      o.rate_hz = number();
    } else if (arg == "--realtime") {
      o.realtime = true;
    } else if (arg == "--json") {
      o.json_path = value();
    } else {
      usage_error("unknown option '" + arg + "'");
    }
  }
  if (o.velocity <= 0) usage_error("--velocity must be > 0");
  if (o.loop_seconds <= 0) usage_error("--seconds must be > 0");
  if (o.iterations < 1) usage_error("--iterations must be >= 1");
  if (o.clients < 0 || o.clients > 64) usage_error("--clients must be 0..64");
  if (o.rate_hz <= 0) usage_error("--rate must be > 0");
  return o;
}

double to_us(Clock::duration d) { return std::chrono::duration<double, std::micro>(d).count(); }

std::string load_average() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  in >> a >> b >> c;
  return in ? a + " " + b + " " + c : "unknown";
}

// ---- statistics -------------------------------------------------------------------------------

struct Summary {
  std::size_t count = 0;
  double p50 = 0, p99 = 0, max = 0, min = 0, mean = 0;
};

// Nearest-rank quantiles of exact samples (no binning).
Summary summarize(std::vector<double> samples) {
  Summary s;
  s.count = samples.size();
  if (samples.empty()) return s;
  std::sort(samples.begin(), samples.end());
  auto rank = [&](double q) {
    const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(samples.size())));
    return samples[std::clamp<std::size_t>(k, 1, samples.size()) - 1];
  };
  s.p50 = rank(0.50);
  s.p99 = rank(0.99);
  s.min = samples.front();
  s.max = samples.back();
  double sum = 0;
  for (double v : samples) sum += v;
  s.mean = sum / static_cast<double>(samples.size());
  return s;
}

json to_json(const Summary& s) {
  return {{"count", s.count}, {"p50_us", s.p50}, {"p99_us", s.p99},
          {"max_us", s.max},  {"min_us", s.min}, {"mean_us", s.mean}};
}

json to_json(const tendril::server::LoopStatistics& s) {
  return {{"cycles", s.cycles},
          {"overruns", s.overruns},
          {"period_error_p50_us", s.period_error_p50_us},
          {"period_error_p99_us", s.period_error_p99_us},
          {"period_error_max_us", s.period_error_max_us},
          {"work_p50_us", s.work_p50_us},
          {"work_p99_us", s.work_p99_us},
          {"work_max_us", s.work_max_us},
          {"realtime_scheduling", s.realtime_scheduling},
          {"memory_locked", s.memory_locked}};
}

// ---- CAN tap: watches one drive's RPDO1 -------------------------------------------------------

// Drains a bus tap on its own thread (so its queue never overflows) and tracks the target
// position (RPDO1 bytes 2..5, i32 little-endian counts) of one node. A measurement arms it with a
// direction; the first RPDO whose target moved that way from the armed baseline is the detection.
class RpdoWatcher {
 public:
  RpdoWatcher(std::unique_ptr<tendril::can::Bus> tap, std::uint32_t cob_id)
      : tap_(std::move(tap)), cob_id_(cob_id) {
    thread_ = std::thread([this] { run(); });
  }
  ~RpdoWatcher() { stop(); }

  void stop() {
    stop_.store(true);
    if (thread_.joinable()) thread_.join();
  }

  // Waits until `frames` consecutive RPDOs carried the same target (motion has stopped).
  bool wait_settled(int frames, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    const std::uint64_t from = rpdo_count_;
    return cv_.wait_for(lock, timeout, [&] {
      return rpdo_count_ >= from + static_cast<std::uint64_t>(frames) && unchanged_run_ >= frames;
    });
  }

  void arm(int direction) {
    std::lock_guard lock(mutex_);
    armed_ = true;
    direction_ = direction;
    baseline_ = last_target_;
    detected_.reset();
  }

  // The bus timestamp of the detecting frame, or nullopt on timeout. Disarms.
  std::optional<Clock::time_point> wait_detected(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    cv_.wait_for(lock, timeout, [&] { return detected_.has_value(); });
    armed_ = false;
    return detected_;
  }

  bool have_target() const {
    std::lock_guard lock(mutex_);
    return rpdo_count_ > 0;
  }
  std::uint64_t overflows() const { return tap_->statistics().receive_overflows; }

 private:
  void run() {
    while (!stop_.load(std::memory_order_relaxed)) {
      const auto frame = tap_->receive(std::chrono::milliseconds(5));
      if (!frame || frame->error || frame->rtr || frame->extended) continue;
      if (frame->id != cob_id_ || frame->len < 6) continue;
      const auto target = static_cast<std::int32_t>(static_cast<std::uint32_t>(frame->data[2]) |
                                                    static_cast<std::uint32_t>(frame->data[3]) << 8 |
                                                    static_cast<std::uint32_t>(frame->data[4]) << 16 |
                                                    static_cast<std::uint32_t>(frame->data[5]) << 24);
      {
        std::lock_guard lock(mutex_);
        unchanged_run_ = rpdo_count_ > 0 && target == last_target_ ? unchanged_run_ + 1 : 0;
        last_target_ = target;
        ++rpdo_count_;
        if (armed_ && !detected_ && (static_cast<std::int64_t>(target) - baseline_) * direction_ > 0)
          detected_ = frame->timestamp;
      }
      cv_.notify_all();
    }
  }

  std::unique_ptr<tendril::can::Bus> tap_;
  const std::uint32_t cob_id_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::uint64_t rpdo_count_ = 0;
  int unchanged_run_ = 0;
  std::int32_t last_target_ = 0;
  bool armed_ = false;
  int direction_ = 0;
  std::int32_t baseline_ = 0;
  std::optional<Clock::time_point> detected_;
};

// ---- REST client ------------------------------------------------------------------------------

// One keep-alive HTTP/1.1 connection (reconnects when the server closes it).
class RestClient {
 public:
  struct Reply {
    int status = 0;
    json body;
  };

  RestClient(unsigned short port, std::string token, std::string client_id)
      : port_(port), token_(std::move(token)), client_id_(std::move(client_id)) {
    connect();
  }

  Reply request(bhttp::verb method, const std::string& target,
                const std::optional<json>& body = std::nullopt) {
    return request_raw(method, target, body ? body->dump() : std::string());
  }

  // `body` is sent as is (pre-serialised so that timing excludes building JSON).
  Reply request_raw(bhttp::verb method, const std::string& target, const std::string& body) {
    if (!socket_.is_open()) connect();
    bhttp::request<bhttp::string_body> req{method, target, 11};
    req.set(bhttp::field::host, "127.0.0.1:" + std::to_string(port_));
    req.set(bhttp::field::authorization, "Bearer " + token_);
    req.set("X-Tendril-Client", client_id_);
    req.keep_alive(true);
    if (!body.empty()) {
      req.set(bhttp::field::content_type, "application/json");
      req.body() = body;
    }
    req.prepare_payload();
    bhttp::write(socket_, req);
    bhttp::response<bhttp::string_body> res;
    bhttp::read(socket_, buffer_, res);
    Reply reply;
    reply.status = static_cast<int>(res.result_int());
    reply.body = json::parse(res.body(), nullptr, false);
    if (!res.keep_alive()) {
      beast::error_code ec;
      socket_.shutdown(tcp::socket::shutdown_both, ec);
      socket_.close(ec);
      buffer_.clear();
    }
    return reply;
  }

 private:
  void connect() {
    socket_ = tcp::socket(ioc_);
    socket_.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port_));
    socket_.set_option(tcp::no_delay(true));
    buffer_.clear();
  }

  net::io_context ioc_;
  tcp::socket socket_{ioc_};
  beast::flat_buffer buffer_;
  unsigned short port_;
  std::string token_, client_id_;
};

// ---- Foxglove WebSocket client ----------------------------------------------------------------

class FoxgloveClient {
 public:
  // client_id: sent as X-Tendril-Client (a label); lease_token: sent as X-Tendril-Lease so the socket
  // acts under the lease the REST client took.
  FoxgloveClient(unsigned short port, const std::string& token, const std::string& client_id,
                 const std::string& lease_token = {}) {
    ws_.next_layer().connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
    ws_.next_layer().set_option(tcp::no_delay(true));
    ws_.set_option(websocket::stream_base::decorator([client_id, lease_token](websocket::request_type& req) {
      req.set(bhttp::field::sec_websocket_protocol, std::string(fg::kSubprotocol));
      if (!client_id.empty()) req.set("X-Tendril-Client", client_id);
      if (!lease_token.empty()) req.set("X-Tendril-Lease", lease_token);
    }));
    ws_.handshake("127.0.0.1:" + std::to_string(port), "/ws?token=" + token);
  }

  // Reads until a text message with this "op" arrives; other messages are skipped.
  json read_op(const std::string& op) {
    for (;;) {
      buffer_.clear();
      ws_.read(buffer_);
      if (ws_.got_binary()) continue;
      json message = json::parse(beast::buffers_to_string(buffer_.data()), nullptr, false);
      if (message.is_object() && message.value("op", "") == op) return message;
    }
  }

  void write_text(const std::string& text) {
    ws_.text(true);
    ws_.write(net::buffer(text));
  }
  void write_binary(const std::string& data) {
    ws_.binary(true);
    ws_.write(net::buffer(data));
  }
  // One message; false when the connection ended.
  bool read(std::string& out, bool& binary) {
    buffer_.clear();
    beast::error_code ec;
    ws_.read(buffer_, ec);
    if (ec) return false;
    binary = ws_.got_binary();
    out = beast::buffers_to_string(buffer_.data());
    return true;
  }
  void close() {
    beast::error_code ec;
    ws_.close(websocket::close_code::normal, ec);
  }

 private:
  net::io_context ioc_;
  websocket::stream<tcp::socket> ws_{ioc_};
  beast::flat_buffer buffer_;
};

// A viewer-like client: subscribes to the robot's streams and reads until the server closes.
struct SubscriberResult {
  std::uint64_t messages = 0, bytes = 0;
  std::map<std::string, std::uint64_t> per_topic;
  std::string error;
  Clock::time_point subscribed_at{}, ended_at{};
};

void run_subscriber(unsigned short port, const std::string& token, const std::vector<std::string>& topics,
                    std::atomic<int>& ready, SubscriberResult& result) {
  try {
    FoxgloveClient client(port, token, "");
    const json advertise = client.read_op("advertise");
    json subscribe = {{"op", "subscribe"}, {"subscriptions", json::array()}};
    std::map<std::uint32_t, std::string> by_subscription;
    std::uint32_t next_id = 1;
    for (const auto& channel : advertise.at("channels")) {
      const std::string topic = channel.at("topic");
      if (std::find(topics.begin(), topics.end(), topic) == topics.end()) continue;
      subscribe["subscriptions"].push_back({{"id", next_id}, {"channelId", channel.at("id")}});
      by_subscription[next_id++] = topic;
    }
    if (by_subscription.size() != topics.size())
      throw std::runtime_error("the server advertised " + std::to_string(by_subscription.size()) +
                               " of the " + std::to_string(topics.size()) + " topics to subscribe to");
    client.write_text(subscribe.dump());
    result.subscribed_at = Clock::now();
    ready.fetch_add(1);
    std::string data;
    bool binary = false;
    while (client.read(data, binary)) {
      if (!binary) continue;
      const auto message = fg::parse_message_data(data);
      if (!message) continue;
      ++result.messages;
      result.bytes += message->payload.size();
      ++result.per_topic[by_subscription[message->subscription_id]];
    }
  } catch (const std::exception& e) {
    result.error = e.what();
    ready.fetch_add(1);
  }
  result.ended_at = Clock::now();
}

// ---- latency measurement ----------------------------------------------------------------------

struct LatencyRun {
  std::vector<double> to_can_us;      // request write -> first RPDO with the new motion
  std::vector<double> round_trip_us;  // request write -> response read
  int missed = 0;                     // no matching RPDO within the timeout
};

// send(velocity) issues one servo_jv and returns the status code of its answer.
LatencyRun measure_latency(const char* name, const Options& o, std::size_t joints, std::size_t joint,
                           int sync_period_us, RpdoWatcher& watcher,
                           const std::function<int(const std::vector<double>&)>& send) {
  LatencyRun run;
  const std::vector<double> zero(joints, 0.0);
  std::mt19937 rng(12345);  // fixed seed: the same phases every run
  std::uniform_int_distribution<int> phase(0, 2 * sync_period_us - 1);
  for (int i = 0; i < o.warmup + o.iterations; ++i) {
    if (!watcher.wait_settled(3, std::chrono::seconds(2)))
      throw std::runtime_error(std::string(name) + ": the commanded joint did not come to rest");
    // The watcher wakes right after an RPDO, i.e. at a fixed SYNC phase; sending at once would
    // measure that one phase only. A random delay over two SYNC periods samples every phase, as
    // commands from a person arrive.
    std::this_thread::sleep_for(std::chrono::microseconds(phase(rng)));
    // Alternate the direction so that the joint stays where it is on average.
    const int direction = i % 2 == 0 ? 1 : -1;
    std::vector<double> velocity = zero;
    velocity[joint] = direction * o.velocity;
    watcher.arm(direction);
    const auto start = Clock::now();
    const int status = send(velocity);
    const auto answered = Clock::now();
    if (status != 200)
      throw std::runtime_error(std::string(name) + ": servo_jv answered " + std::to_string(status));
    const auto seen = watcher.wait_detected(std::chrono::seconds(1));
    // Stop the motion (an explicit zero velocity, not the command timeout, so the next iteration
    // does not wait 150 ms).
    if (const int stop_status = send(zero); stop_status != 200)
      throw std::runtime_error(std::string(name) + ": servo_jv (stop) answered " +
                               std::to_string(stop_status));
    if (i < o.warmup) continue;
    run.round_trip_us.push_back(to_us(answered - start));
    if (seen) {
      run.to_can_us.push_back(to_us(*seen - start));
    } else {
      ++run.missed;
    }
  }
  return run;
}

void print_row(const char* what, const Summary& s, const char* note = "") {
  std::printf("  %-44s %8zu %10.1f %10.1f %10.1f  %s\n", what, s.count, s.p50, s.p99, s.max, note);
}

void print_loop(const char* what, const tendril::server::LoopStatistics& s) {
  std::printf("  %-44s %8llu %10.1f %10.1f %10.1f  overruns %llu, work p50/p99/max %.1f/%.1f/%.1f us\n", what,
              static_cast<unsigned long long>(s.cycles), s.period_error_p50_us, s.period_error_p99_us,
              s.period_error_max_us, static_cast<unsigned long long>(s.overruns), s.work_p50_us,
              s.work_p99_us, s.work_max_us);
}

int run(const Options& options) {
  using namespace tendril::server;
  Options o = options;
  RobotConfig robot = load_robot_config(o.robot_file);
  // Latency is measured in free space: the simulated vessel would hold the robot on wall contact.
  if (auto catheter = robot.settings.find("catheter");
      catheter != robot.settings.end() && catheter->is_object() && catheter->contains("simulation"))
    (*catheter)["simulation"].erase("vessel");
  if (o.robot.empty()) o.robot = robot.name;
  if (o.robot != robot.name)
    throw std::runtime_error("--robot " + o.robot + ": the robot file defines '" + robot.name + "'");
  std::size_t joint = robot.joints.size();
  for (std::size_t i = 0; i < robot.joints.size(); ++i)
    if (robot.joints[i].name() == o.joint) joint = i;
  if (joint == robot.joints.size())
    throw std::runtime_error("--joint " + o.joint + ": no such joint in " + o.robot_file.string());
  const JointConfig& jc = robot.joints[joint];
  if (!jc.drive) throw std::runtime_error("--joint " + o.joint + ": the joint has no CANopen drive to watch");
  if (o.bus.empty()) o.bus = jc.drive->bus;
  if (o.velocity > jc.limit.max_velocity)
    throw std::runtime_error("--velocity " + std::to_string(o.velocity) +
                             " is above the joint's max_velocity " + std::to_string(jc.limit.max_velocity));
  int sync_period_us = 0;
  for (const auto& b : robot.buses)
    if (b.name == o.bus) sync_period_us = b.sync_period_us;
  if (sync_period_us <= 0)
    throw std::runtime_error("robot '" + o.robot + "' has no bus named '" + o.bus + "'");
  const std::uint32_t rpdo1 = 0x200u + static_cast<std::uint32_t>(jc.drive->node_id);
  const std::size_t joints = robot.joints.size();

  RuntimeOptions ro;
  ro.control_rate_hz = o.rate_hz;
  ro.realtime_priority = o.realtime;
  ro.stepped = false;
  RobotRuntime runtime({robot}, ro, builtin_robot_types());
  auto tap = runtime.tap_bus(o.bus);
  if (!tap)
    throw std::runtime_error("bus '" + o.bus + "' of robot '" + o.robot + "' is not virtual; cannot tap it");
  RpdoWatcher watcher(std::move(tap), rpdo1);
  runtime.start();

  HttpOptions ho;
  ho.host = "127.0.0.1";
  ho.port = 0;
  ho.token = "bench-token";
  JsonControlApi api(runtime, [&runtime](const std::string& name) { return runtime.api_extension(name); });
  HttpServer server(api, ho);
  server.start();
  const unsigned short port = server.port();

  const std::vector<std::string> topics = {"/" + o.robot + "/joint_states",
                                           "/" + o.robot + "/operating_state", "/" + o.robot + "/scene"};
  std::atomic<int> ready{0};
  std::vector<SubscriberResult> subscribers(static_cast<std::size_t>(o.clients));
  std::vector<std::thread> subscriber_threads;
  // On any exit (also an exception) the server must close the sockets before the readers are joined.
  struct JoinSubscribers {
    HttpServer& server;
    std::vector<std::thread>& threads;
    ~JoinSubscribers() {
      server.stop();
      for (auto& t : threads)
        if (t.joinable()) t.join();
    }
  } join_subscribers{server, subscriber_threads};
  for (auto& result : subscribers)
    subscriber_threads.emplace_back([&, port] { run_subscriber(port, ho.token, topics, ready, result); });
  const auto ready_deadline = Clock::now() + std::chrono::seconds(10);
  while (ready.load() < o.clients && Clock::now() < ready_deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));

  // Lease and enable over REST.
  const std::string client_id = "latency-bench";
  RestClient rest(port, ho.token, client_id);
  const std::string robot_path = "/api/v1/robots/" + o.robot;
  const auto leased = rest.request(bhttp::verb::post, "/api/v1/lease");
  if (leased.status != 200)
    throw std::runtime_error("POST /api/v1/lease answered " + std::to_string(leased.status) + " " +
                             leased.body.dump());
  const std::string lease_token = leased.body.value("lease_token", std::string());
  if (auto r = rest.request(bhttp::verb::post, robot_path + "/state_command", json{{"command", "enable"}});
      r.status >= 300)
    throw std::runtime_error("enable answered " + std::to_string(r.status) + " " + r.body.dump());
  const auto enable_deadline = Clock::now() + std::chrono::seconds(5);
  for (;;) {
    const auto r = rest.request(bhttp::verb::get, robot_path + "/operating_state");
    if (r.status == 200 && r.body.value("state", "") == "ENABLED" && r.body.value("drives_ready", false))
      break;
    if (Clock::now() > enable_deadline)
      throw std::runtime_error("the robot did not become ENABLED with drives ready: " + r.body.dump());
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  if (!watcher.have_target()) std::this_thread::sleep_for(std::chrono::milliseconds(50));

  // 1. Loop timing with the subscribers reading, nothing else going on.
  const std::string load_before = load_average();
  const LoopStatistics loop_before = runtime.loop_statistics();
  std::this_thread::sleep_for(std::chrono::duration<double>(o.loop_seconds));
  const LoopStatistics loop_after_idle = runtime.loop_statistics();

  // 2a. Reference without the network: ControlApi::servo_jv called in process -> CAN. Shows the
  // share of mailbox, control tick and SYNC wait in the end-to-end numbers.
  auto direct_send = [&](const std::vector<double>& velocity) {
    return runtime.servo_jv(o.robot, json{{"velocity", velocity}}).status;
  };
  const LatencyRun direct_run =
      measure_latency("in-process", o, joints, joint, sync_period_us, watcher, direct_send);

  // 2. REST servo_jv -> CAN.
  const std::string servo_target = robot_path + "/servo_jv";
  auto rest_send = [&](const std::vector<double>& velocity) {
    const std::string body = json{{"velocity", velocity}}.dump();
    return rest.request_raw(bhttp::verb::post, servo_target, body).status;
  };
  const LatencyRun rest_run = measure_latency("REST", o, joints, joint, sync_period_us, watcher, rest_send);

  // 3. WebSocket service call servo_jv -> CAN, on a socket presenting the REST client's lease token.
  FoxgloveClient commander(port, ho.token, client_id, lease_token);
  const json services = commander.read_op("advertiseServices");
  std::uint32_t servo_service = 0;
  for (const auto& s : services.at("services"))
    if (s.at("name") == "servo_jv") servo_service = s.at("id");
  if (servo_service == 0) throw std::runtime_error("the server did not advertise a servo_jv service");
  std::uint32_t call_id = 0;
  auto ws_send = [&](const std::vector<double>& velocity) {
    const std::string payload = json{{"robot", o.robot}, {"velocity", velocity}}.dump();
    const std::uint32_t id = ++call_id;
    commander.write_binary(fg::encode_service_call_request(servo_service, id, "json", payload));
    std::string data;
    bool binary = false;
    while (commander.read(data, binary)) {
      if (binary) {
        const auto response = fg::parse_service_call_response(data);
        if (!response || response->call_id != id) continue;
        const json answer = json::parse(response->payload, nullptr, false);
        return answer.is_object() ? answer.value("status", 0) : 0;
      }
      const json message = json::parse(data, nullptr, false);
      if (message.is_object() && message.value("op", "") == "serviceCallFailure" &&
          message.value("callId", 0u) == id)
        throw std::runtime_error("service call failed: " + message.value("message", std::string()));
    }
    throw std::runtime_error("the WebSocket closed during a service call");
  };
  const LatencyRun ws_run = measure_latency("WebSocket", o, joints, joint, sync_period_us, watcher, ws_send);
  const LoopStatistics loop_end = runtime.loop_statistics();
  const std::string load_after = load_average();
  const auto state = rest.request(bhttp::verb::get, robot_path + "/operating_state");

  commander.close();
  server.stop();  // closes the subscribers' sockets: their read loops end
  for (auto& t : subscriber_threads) t.join();
  watcher.stop();
  const std::uint64_t tap_overflows = watcher.overflows();
  runtime.stop();

  // ---- report ----
  const Summary rest_can = summarize(rest_run.to_can_us), rest_rt = summarize(rest_run.round_trip_us);
  const Summary direct_can = summarize(direct_run.to_can_us);
  const Summary ws_can = summarize(ws_run.to_can_us), ws_rt = summarize(ws_run.round_trip_us);
  utsname host{};
  uname(&host);
  std::printf("\ntendril server latency benchmark (%s, %s %s, %u hardware threads)\n", o.robot_file.c_str(),
              host.sysname, host.release, std::thread::hardware_concurrency());
  std::printf(
      "control %.0f Hz real time, SCHED_FIFO %s (requested: %s), mlockall %s; %d WebSocket subscribers to "
      "%zu "
      "topics; load average before %s, after %s\n",
      o.rate_hz, loop_end.realtime_scheduling ? "granted" : "not granted", o.realtime ? "yes" : "no",
      loop_end.memory_locked ? "granted" : "not granted", o.clients, topics.size(), load_before.c_str(),
      load_after.c_str());
  std::printf("\n  %-44s %8s %10s %10s %10s\n", "RT loop period error (cumulative since start)", "cycles",
              "p50 us", "p99 us", "max us");
  print_loop("at the start of the idle window", loop_before);
  print_loop("after the idle window (subscribers only)", loop_after_idle);
  print_loop("at the end (after both command phases)", loop_end);
  std::printf("  idle window: %llu cycles in %.1f s, %llu overruns\n",
              static_cast<unsigned long long>(loop_after_idle.cycles - loop_before.cycles), o.loop_seconds,
              static_cast<unsigned long long>(loop_after_idle.overruns - loop_before.overruns));

  std::printf("\n  %-44s %8s %10s %10s %10s\n", "servo_jv latency", "count", "p50 us", "p99 us", "max us");
  const std::string rpdo_name = "RPDO1 0x" + [&] {
    char b[8];
    std::snprintf(b, sizeof b, "%03X", rpdo1);
    return std::string(b);
  }();
  print_row(("in-process ControlApi call -> CAN " + rpdo_name).c_str(), direct_can,
            direct_run.missed ? ("missed " + std::to_string(direct_run.missed)).c_str() : "");
  print_row(("REST request -> CAN " + rpdo_name).c_str(), rest_can,
            rest_run.missed ? ("missed " + std::to_string(rest_run.missed)).c_str() : "");
  print_row("REST request -> HTTP response", rest_rt);
  print_row(("WS service call -> CAN " + rpdo_name).c_str(), ws_can,
            ws_run.missed ? ("missed " + std::to_string(ws_run.missed)).c_str() : "");
  print_row("WS service call -> service response", ws_rt);
  std::printf(
      "  (CAN latency includes waiting for the next control tick (%.2f ms) and the next SYNC (%d us))\n",
      1000.0 / o.rate_hz, sync_period_us);

  std::printf("\n  WebSocket subscribers:\n");
  json subscriber_json = json::array();
  for (std::size_t i = 0; i < subscribers.size(); ++i) {
    const auto& s = subscribers[i];
    const double seconds = std::chrono::duration<double>(s.ended_at - s.subscribed_at).count();
    std::printf("    client %zu: %llu messages (%.1f/s), %.1f kB%s%s\n", i,
                static_cast<unsigned long long>(s.messages),
                seconds > 0 ? static_cast<double>(s.messages) / seconds : 0.0,
                static_cast<double>(s.bytes) / 1000.0, s.error.empty() ? "" : ", error: ", s.error.c_str());
    subscriber_json.push_back({{"messages", s.messages},
                               {"bytes", s.bytes},
                               {"seconds", seconds},
                               {"per_topic", s.per_topic},
                               {"error", s.error}});
  }
  std::printf("  tap receive overflows: %llu; final operating state: %s\n",
              static_cast<unsigned long long>(tap_overflows), state.body.dump().c_str());

  if (!o.json_path.empty()) {
    const json out = {
        {"benchmark", "server_latency_bench"},
        {"robot_file", o.robot_file.string()},
        {"robot", o.robot},
        {"joint", o.joint},
        {"bus", o.bus},
        {"rpdo_cob_id", rpdo1},
        {"control_rate_hz", o.rate_hz},
        {"realtime_requested", o.realtime},
        {"clients", o.clients},
        {"topics", topics},
        {"velocity", o.velocity},
        {"iterations", o.iterations},
        {"warmup_iterations", o.warmup},
        {"hardware_threads", std::thread::hardware_concurrency()},
        {"load_average_before", load_before},
        {"load_average_after", load_after},
        {"loop",
         {{"note", "histograms are cumulative since start (they cannot be reset)"},
          {"window_seconds", o.loop_seconds},
          {"window_start", to_json(loop_before)},
          {"window_end", to_json(loop_after_idle)},
          {"end", to_json(loop_end)}}},
        {"in_process_to_can", to_json(direct_can)},
        {"in_process_missed", direct_run.missed},
        {"rest_to_can", to_json(rest_can)},
        {"rest_round_trip", to_json(rest_rt)},
        {"rest_missed", rest_run.missed},
        {"ws_to_can", to_json(ws_can)},
        {"ws_round_trip", to_json(ws_rt)},
        {"ws_missed", ws_run.missed},
        {"subscribers", subscriber_json},
        {"tap_receive_overflows", tap_overflows},
        {"final_operating_state", state.body},
    };
    std::ofstream file(o.json_path);
    file << out.dump(2) << "\n";
    if (!file) throw std::runtime_error("cannot write " + o.json_path);
    std::printf("  results written to %s\n", o.json_path.c_str());
  }
  return direct_run.missed + rest_run.missed + ws_run.missed == 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parse_options(argc, argv);
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::cerr << "server_latency_bench: " << e.what() << "\n";
    return 1;
  }
}
