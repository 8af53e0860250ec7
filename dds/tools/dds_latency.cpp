// tendril-dds-latency: one-way latency of tendril's joint states over DDS, for the latency bench
// (tests/bench/dds_latency.sh). `sub` reads rt/<robot>/joint_states and times every sample on arrival
// against two clocks: the writer's DDS source time stamp (set inside dds_write, so this is the
// transport: serialisation, the network, delivery to the reader) and the sample's header stamp (the
// control tick the joint state comes from, so this is the age of the state: the wait for the
// bridge's next publish pass plus the transport). Both are CLOCK_REALTIME readings, which is valid
// only where writer and reader share a clock: processes on one machine, network namespaces included.
// `pub` writes a synthetic stream of the same type at a fixed rate through the bridge's own writer
// function (write_joint_state), with the same QoS, for a rate tendrild is not configured to publish at.
#include <dds/dds.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <iostream>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/dds/wire.hpp"
#include "tool_arguments.hpp"

namespace {

using namespace tendril::dds;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr const char* kUsage = R"(usage: tendril-dds-latency [--domain N] [--timeout S] MODE ROBOT [options]

Joins DDS domain N (default 0; Cyclone DDS reads its network settings from $CYCLONEDDS_URI).

modes:
  sub ROBOT [--seconds S] [--warmup S]
      read rt/ROBOT/joint_states (sensor_msgs/JointState, tendril's state QoS) for S seconds (default
      10) after a warm-up of W seconds (default 2) counted from the first sample, then print one JSON
      line: samples, rate, and the latency percentiles in microseconds of
        transport_us  arrival - the writer's DDS source time stamp (dds_write -> reader)
        age_us        arrival - header.stamp (the state's own time -> reader)
      and the median and largest of the per-second p50 and p99 (as ddsperf reports per second)
  pub ROBOT [--rate HZ] [--seconds S] [--joints NAME,NAME,...]
      write a synthetic joint state stream to rt/ROBOT/joint_states at HZ (default 1000) for S
      seconds (default 10) once a reader has matched, through tendrild's own writer function, with
      the joints named as the shipped srmc's (insertion,roll,proximal_bend,distal_bend) unless given;
      prints one JSON line: samples written, the rate kept, write errors, the dds_write call's time

Both ends must share a clock (one machine, or network namespaces of one machine).
--timeout S: how long to wait for the first sample or for a reader to match (default 20 s).
Exit status: 0 done, 2 usage error, 3 nothing arrived / nobody matched in time.
)";

[[noreturn]] void usage_error(const std::string& message) {
  std::cerr << "tendril-dds-latency: " << message << "\n(see tendril-dds-latency --help)\n";
  std::exit(2);
}

dds_entity_t check(dds_entity_t e, const std::string& what) {
  if (e < 0) {
    std::cerr << "tendril-dds-latency: cannot create " << what << ": " << retcode_text(e) << "\n";
    std::exit(1);
  }
  return e;
}

struct Options {
  std::uint32_t domain = 0;
  double timeout_s = 20;
  double seconds = 10;
  double warmup_s = 2;
  double rate_hz = 1000;
  std::vector<std::string> joints{"insertion", "roll", "proximal_bend", "distal_bend"};
  std::vector<std::string> positional;
};

Clock::duration seconds_of(double s) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

// Percentiles by rank (nearest rank below), on a copy.
struct Summary {
  double p50 = 0, p90 = 0, p99 = 0, max = 0, mean = 0;
};
Summary summarise(std::vector<double> v) {
  Summary s;
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  auto at = [&](double q) { return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))]; };
  s.p50 = at(0.50);
  s.p90 = at(0.90);
  s.p99 = at(0.99);
  s.max = v.back();
  double sum = 0;
  for (const double x : v) sum += x;
  s.mean = sum / static_cast<double>(v.size());
  return s;
}
json to_json(const Summary& s) {
  auto r = [](double x) { return std::round(x * 10) / 10; };  // 0.1 us: more is noise
  return {{"p50", r(s.p50)}, {"p90", r(s.p90)}, {"p99", r(s.p99)}, {"max", r(s.max)}, {"mean", r(s.mean)}};
}

// ---- sub ----

struct Arrival {
  std::int64_t received_ns;   // dds_time() when taken
  std::int64_t transport_ns;  // received - source time stamp
  std::int64_t age_ns;        // received - header.stamp
};

struct Recorder {
  std::mutex mutex;
  std::vector<Arrival> arrivals;  // guarded by mutex (the listener's thread appends)
  std::atomic<bool> any{false};
};

// Called on Cyclone's receive thread as soon as a sample is in the reader. The arrival time is read
// first: the take that follows (which turns the CDR into the C struct, allocating its strings and
// sequences) is the application's work, not the way there. With the reader's keep-last 1 there is at
// most one sample waiting, so one reading serves.
void on_data(dds_entity_t reader, void* arg) {
  const std::int64_t now = dds_time();
  auto* rec = static_cast<Recorder*>(arg);
  void* samples[32] = {};
  dds_sample_info_t infos[32];
  const dds_return_t n = dds_take(reader, samples, infos, 32, 32);
  if (n <= 0) return;
  {
    std::lock_guard lock(rec->mutex);
    for (dds_return_t i = 0; i < n; ++i) {
      if (!infos[i].valid_data) continue;
      const auto* m = static_cast<const sensor_msgs_msg_dds__JointState_*>(samples[i]);
      const std::int64_t stamp =
          static_cast<std::int64_t>(m->header.stamp.sec) * 1'000'000'000 + m->header.stamp.nanosec;
      rec->arrivals.push_back({now, now - infos[i].source_timestamp, now - stamp});
    }
  }
  rec->any.store(true, std::memory_order_release);
  dds_return_loan(reader, samples, n);
}

int sub(dds_entity_t participant, const Options& o) {
  const std::string name = robot_topic(o.positional[1], kJointStates);
  Recorder rec;
  rec.arrivals.reserve(static_cast<std::size_t>(2000 * (o.seconds + o.warmup_s + 2)));
  dds_qos_t* qos = make_qos(TopicKind::kState);
  const dds_entity_t topic =
      check(dds_create_topic(participant, &sensor_msgs_msg_dds__JointState__desc, name.c_str(), qos, nullptr),
            "topic " + name);
  dds_listener_t* listener = dds_create_listener(&rec);
  dds_lset_data_available(listener, on_data);
  const dds_entity_t reader =
      check(dds_create_reader(participant, topic, qos, listener), "a reader of " + name);
  dds_delete_listener(listener);
  dds_delete_qos(qos);
  const auto give_up = Clock::now() + seconds_of(o.timeout_s);
  while (!rec.any.load(std::memory_order_acquire) && Clock::now() < give_up)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  if (!rec.any.load(std::memory_order_acquire)) {
    std::cerr << "tendril-dds-latency: nothing on " << name << " in domain " << o.domain << " within "
              << o.timeout_s << " s\n";
    return 3;
  }
  std::this_thread::sleep_for(seconds_of(o.warmup_s + o.seconds));
  dds_delete(reader);  // no callback runs after this returns
  std::vector<Arrival> arrivals;
  {
    std::lock_guard lock(rec.mutex);
    arrivals.swap(rec.arrivals);
  }
  const std::int64_t start = arrivals.front().received_ns + static_cast<std::int64_t>(o.warmup_s * 1e9);
  const std::int64_t end = start + static_cast<std::int64_t>(o.seconds * 1e9);
  std::vector<double> transport, age;
  std::map<std::int64_t, std::vector<double>> per_second;  // second index -> transport latencies
  for (const auto& a : arrivals) {
    if (a.received_ns < start || a.received_ns >= end) continue;
    transport.push_back(static_cast<double>(a.transport_ns) * 1e-3);
    age.push_back(static_cast<double>(a.age_ns) * 1e-3);
    per_second[(a.received_ns - start) / 1'000'000'000].push_back(transport.back());
  }
  std::vector<double> second_p50, second_p99;
  for (const auto& [second, values] : per_second) {
    const Summary s = summarise(values);
    second_p50.push_back(s.p50);
    second_p99.push_back(s.p99);
  }
  const Summary s50 = summarise(second_p50), s99 = summarise(second_p99);
  const Summary t = summarise(transport), g = summarise(age);
  const json out = {{"topic", name},
                    {"seconds", o.seconds},
                    {"samples", transport.size()},
                    {"rate_hz", std::round(static_cast<double>(transport.size()) / o.seconds * 10) / 10},
                    {"transport_us", to_json(t)},
                    {"age_us", to_json(g)},
                    {"per_second_transport_us",
                     {{"p50_median", std::round(s50.p50 * 10) / 10},
                      {"p99_median", std::round(s99.p50 * 10) / 10},
                      {"p99_max", std::round(s99.max * 10) / 10}}}};
  std::cout << out.dump() << std::endl;
  std::cerr << "tendril-dds-latency: " << name << ": " << transport.size() << " samples in " << o.seconds
            << " s; transport us p50 " << t.p50 << " p99 " << t.p99 << " max " << t.max << "; age us p50 "
            << g.p50 << " p99 " << g.p99 << " max " << g.max << "\n";
  return transport.empty() ? 3 : 0;
}

// ---- pub ----

int pub(dds_entity_t participant, const Options& o) {
  if (!(o.rate_hz > 0)) usage_error("pub: --rate must be > 0");
  const std::string robot = o.positional[1];
  const std::string name = robot_topic(robot, kJointStates);
  dds_qos_t* qos = make_qos(TopicKind::kState);
  const dds_entity_t topic =
      check(dds_create_topic(participant, &sensor_msgs_msg_dds__JointState__desc, name.c_str(), qos, nullptr),
            "topic " + name);
  const dds_entity_t writer =
      check(dds_create_writer(participant, topic, qos, nullptr), "a writer of " + name);
  dds_delete_qos(qos);
  const auto give_up = Clock::now() + seconds_of(o.timeout_s);
  for (;;) {
    dds_publication_matched_status_t pm{};
    dds_get_publication_matched_status(writer, &pm);
    if (pm.current_count > 0) break;
    if (Clock::now() >= give_up) {
      std::cerr << "tendril-dds-latency: no reader of " << name << " in domain " << o.domain << " within "
                << o.timeout_s << " s\n";
      return 3;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const std::string frame = robot + "_base";  // as the bridge names it
  const std::size_t n = o.joints.size();
  std::vector<double> position(n), velocity(n), effort(n);
  std::vector<double> write_us;
  const auto total = static_cast<long>(std::llround(o.rate_hz * o.seconds));
  write_us.reserve(static_cast<std::size_t>(total));
  long errors = 0;
  const auto period_ns = static_cast<std::int64_t>(std::llround(1e9 / o.rate_hz));
  // Absolute deadlines on CLOCK_MONOTONIC, as tendril's control loop keeps time: a late write is not
  // followed by a burst of catch-up writes beyond the one that is due.
  timespec next{};
  clock_gettime(CLOCK_MONOTONIC, &next);
  const auto started = Clock::now();
  long late = 0;
  for (long i = 0; i < total; ++i) {
    const double t = static_cast<double>(i) / o.rate_hz;
    for (std::size_t j = 0; j < n; ++j) {  // a slow sine per joint: the values change every sample
      position[j] = std::sin(t + static_cast<double>(j));
      velocity[j] = std::cos(t + static_cast<double>(j));
      effort[j] = 0.1 * static_cast<double>(j);
    }
    const auto before = Clock::now();
    const double stamp =
        std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
    if (write_joint_state(writer, stamp, frame, o.joints, position, velocity, effort) != DDS_RETCODE_OK)
      ++errors;
    write_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - before).count());
    next.tv_nsec += period_ns;
    while (next.tv_nsec >= 1'000'000'000) {
      next.tv_nsec -= 1'000'000'000;
      ++next.tv_sec;
    }
    timespec now{};
    clock_gettime(CLOCK_MONOTONIC, &now);
    if (now.tv_sec > next.tv_sec || (now.tv_sec == next.tv_sec && now.tv_nsec > next.tv_nsec)) {
      ++late;
      next = now;
    }
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, nullptr) == EINTR) {
    }
  }
  const double elapsed = std::chrono::duration<double>(Clock::now() - started).count();
  const json out = {{"topic", name},
                    {"samples", total},
                    {"rate_hz", std::round(static_cast<double>(total) / elapsed * 10) / 10},
                    {"late_periods", late},
                    {"write_errors", errors},
                    {"write_call_us", to_json(summarise(write_us))}};
  std::cout << out.dump() << std::endl;
  return errors == 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  tools::ArgumentCursor args(argc, argv, usage_error);
  while (args.next()) {
    const std::string arg = args.current();
    auto value = [&](const char* name) { return args.value(name); };
    auto number = [&](const char* name) { return args.number(name); };
    if (arg == "--help" || arg == "-h") {
      std::cout << kUsage;
      return 0;
    } else if (arg == "--domain") {
      o.domain = args.domain();
    } else if (arg == "--timeout") {
      o.timeout_s = number("--timeout");
    } else if (arg == "--seconds") {
      o.seconds = number("--seconds");
      if (!(o.seconds > 0)) usage_error("--seconds must be > 0");
    } else if (arg == "--warmup") {
      o.warmup_s = number("--warmup");
    } else if (arg == "--rate") {
      o.rate_hz = number("--rate");
    } else if (arg == "--joints") {
      o.joints.clear();
      std::stringstream in(value("--joints"));
      for (std::string item; std::getline(in, item, ',');)
        if (!item.empty()) o.joints.push_back(item);
      if (o.joints.empty()) usage_error("--joints needs at least one name");
    } else if (arg.rfind("--", 0) == 0) {
      usage_error("unknown option '" + arg + "'");
    } else {
      o.positional.push_back(arg);
    }
  }
  if (o.positional.size() != 2) usage_error("expected MODE ROBOT (sub srmc, pub srmc)");
  const std::string& mode = o.positional[0];
  if (mode != "sub" && mode != "pub") usage_error("unknown mode '" + mode + "' (sub, pub)");
  const dds_entity_t participant = check(
      dds_create_participant(static_cast<dds_domainid_t>(o.domain), nullptr, nullptr), "a DDS participant");
  const int status = mode == "sub" ? sub(participant, o) : pub(participant, o);
  dds_delete(participant);
  return status;
}
