// The serial arm's force topic; see the header.
#include "serial_arm/force_topic.hpp"

#include <pthread.h>

#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <utility>

#include "serial_arm/serial_arm_robot.hpp"

namespace tendril::server {

namespace {

using nlohmann::json;

std::uint64_t wall_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

// Forces to 0.1 mN: the sensor's noise is 20 mN, more digits are noise in the recording.
double round4(double v) { return std::round(v * 1e4) / 1e4; }

}  // namespace

ArmForceTopic::ArmForceTopic(ArmForceTopicSettings settings, Reader reader)
    : settings_(std::move(settings)), reader_(std::move(reader)) {
  if (!std::isfinite(settings_.rate_hz) || settings_.rate_hz <= 0.0 || settings_.rate_hz > 1000.0)
    throw std::invalid_argument("force topic: expected a rate in (0, 1000] Hz, got " +
                                std::to_string(settings_.rate_hz));
  if (!reader_) throw std::invalid_argument("force topic: expected a reader of the arm's force");
  if (settings_.own_thread) worker_ = std::thread([this] { run(); });
}

ArmForceTopic::~ArmForceTopic() {
  {
    std::lock_guard lock(stop_mutex_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

std::string ArmForceTopic::message(const ArmForceSample& s, std::uint64_t now_ns) const {
  json m = {{"timestamp", {{"sec", now_ns / 1'000'000'000ULL}, {"nsec", now_ns % 1'000'000'000ULL}}},
            {"frame_id", settings_.robot + "_probe"},
            {"t", std::round(s.t * 1e6) / 1e6},
            {"force_n", nullptr},
            {"normal_n", nullptr},
            {"target_n", settings_.target_n ? json(*settings_.target_n) : json(nullptr)},
            {"in_contact", s.in_contact},
            {"phase", s.phase ? json(s.phase) : json(nullptr)},
            {"fresh", s.force_valid && s.force_fresh}};
  if (s.force_valid) {
    m["force_n"] = {round4(s.force_n[0]), round4(s.force_n[1]), round4(s.force_n[2])};
    // The tissue pushes the probe back along its axis: negative z in the probe frame.
    m["normal_n"] = round4(-s.force_n[2]);
  }
  return m.dump();
}

bool ArmForceTopic::step(std::uint64_t now_ns) {
  const ArmForceSample s = reader_();
  if (s.tick == 0 || s.tick == last_tick_) return false;  // nothing new from the control loop
  last_tick_ = s.tick;
  auto payload = std::make_shared<const std::string>(message(s, now_ns));
  std::function<void()> ready;
  {
    std::lock_guard lock(mutex_);
    latest_.payload = std::move(payload);
    ++latest_.version;
    latest_.log_time_ns = now_ns;
    ++published_;
    ready = ready_;
  }
  if (ready) ready();
  return true;
}

void ArmForceTopic::run() {
  pthread_setname_np(pthread_self(), "arm-force");
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(1.0 / settings_.rate_hz));
  auto next = std::chrono::steady_clock::now();
  for (;;) {
    if (wanted_.load(std::memory_order_relaxed)) {
      try {
        step(wall_ns());
      } catch (const std::exception&) {  // NOLINT(bugprone-empty-catch): out of memory; the next tick retries
      }
    }
    next += period;
    const auto now = std::chrono::steady_clock::now();
    if (next < now) next = now;  // after a stall, no burst
    std::unique_lock lock(stop_mutex_);
    if (stop_cv_.wait_until(lock, next, [this] { return stopping_; })) return;
  }
}

std::vector<TopicInfo> ArmForceTopic::topics() const {
  const json number_or_null = {{"type", {"number", "null"}}};
  const json schema = {
      {"type", "object"},
      {"title", "tendril.ArmForce"},
      {"description",
       "The arm's 3-axis force reading in the probe frame at the control loop's pace (≤ 100 Hz), F_n against "
       "the sweep's target"},
      {"properties",
       {{"timestamp",
         {{"type", "object"},
          {"properties",
           {{"sec", {{"type", "integer"}, {"minimum", 0}}},
            {"nsec", {{"type", "integer"}, {"minimum", 0}, {"maximum", 999999999}}}}}}},
        {"frame_id", {{"type", "string"}}},
        {"t", {{"type", "number"}, {"description", "control time (s)"}}},
        {"force_n",
         {{"type", {"array", "null"}},
          {"items", {{"type", "number"}}},
          {"description", "[fx, fy, fz] in the probe frame (N), environment on the probe"}}},
        {"normal_n",
         {{"type", {"number", "null"}}, {"description", "F_n along the probe axis (N), pressing > 0"}}},
        {"target_n", {{"type", {"number", "null"}}, {"description", "the sweep's force target d_f (N)"}}},
        {"in_contact", {{"type", "boolean"}}},
        {"phase", {{"type", {"string", "null"}}}},
        {"fresh", {{"type", "boolean"}}}}}};
  TopicInfo info{topic(), "tendril.ArmForce", schema.dump()};
  info.recorded_always = true;  // ~250 bytes per tick: a recorded sweep keeps its force curve
  return {info};
}

std::optional<TopicPayload> ArmForceTopic::latest(const std::string& topic_name,
                                                  std::uint64_t since_version) const {
  if (topic_name != topic()) return std::nullopt;
  std::lock_guard lock(mutex_);
  if (!latest_.payload || latest_.version <= since_version) return std::nullopt;
  return latest_;
}

void ArmForceTopic::set_ready_callback(std::function<void()> ready) {
  std::lock_guard lock(mutex_);
  ready_ = std::move(ready);
}

void ArmForceTopic::set_demand(const std::string& topic_name, bool wanted) {
  if (topic_name == topic()) wanted_.store(wanted, std::memory_order_relaxed);
}

std::string ArmForceTopic::metrics() const {
  std::lock_guard lock(mutex_);
  return "# HELP tendril_arm_force_messages_total Force topic messages published\n"
         "# TYPE tendril_arm_force_messages_total counter\n"
         "tendril_arm_force_messages_total{robot=\"" +
         settings_.robot + "\"} " + std::to_string(published_) + "\n";
}

std::shared_ptr<ArmForceTopic> make_arm_force_topic(const SerialArm& arm, bool own_thread) {
  ArmForceTopicSettings settings;
  settings.own_thread = own_thread;
  settings.robot = arm.config().name;
  if (arm.ultrasound()) settings.target_n = arm.ultrasound()->force.contact_force;
  const bool sweep = arm.ultrasound().has_value();
  return std::make_shared<ArmForceTopic>(std::move(settings), [&arm, sweep] {
    ArmForceSample out;
    // Three seqlock reads of the same tick's publish(): the probe state's tick first, so that a message
    // is never stamped with a tick newer than its force.
    const UltrasoundProbeState probe = arm.probe_state();
    const ArmSnapshot s = arm.snapshot();
    out.tick = probe.tick;
    out.t = probe.t;
    out.force_n = s.force_n;
    out.force_valid = s.force_valid;
    out.force_fresh = s.force_fresh;
    out.in_contact = s.force_valid && -s.force_n[2] > 0.1;
    if (sweep) {
      const SweepSnapshot w = arm.sweep_snapshot();
      out.phase = to_string(w.phase);
      out.in_contact = w.in_contact;
    }
    return out;
  });
}

}  // namespace tendril::server
