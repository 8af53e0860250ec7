// The serial arm's force topic /{robot}/force (issue 17; the sweep shows "the current contact force
// versus 0.8 N, and the controller mode"): a TopicSource with its own light thread that reads, at 100 Hz,
// what the control thread already publishes every tick through seqlocks (ArmSnapshot, SweepSnapshot and
// the probe state's tick) and serialises one small JSON message per new control tick:
//
//   {"timestamp": {"sec", "nsec"}, "frame_id": "{robot}_probe", "t": control time (s),
//    "force_n": [fx, fy, fz] (the 3-axis reading in the probe frame, N; null before a reading),
//    "normal_n": F_n (along the probe axis, positive pressing, = −fz; null before a reading),
//    "target_n": d_f (0.8 N; null without an "ultrasound" section), "in_contact": the hybrid controller's
//    force phase (as /{robot}/sweep says; without a sweep F_n > 0.1 N), "phase": the sweep's phase (null
//    without a sweep), "fresh": the reading is within the stale bound}
//
// Why a separate topic and thread: /{robot}/sweep is the whole operating state at 20 Hz, too slow and
// too heavy to plot a force at the sensor's pace; this one is small, plottable as is in Foxglove
// (/us_arm/force.normal_n) and the console's force plot reads it. The control thread does nothing new:
// the reads are seqlock loads (the control thread never waits for them).
//
// The thread produces messages only while someone watches or a session recording keeps the topic (the
// front end's set_demand; the topic is TopicInfo::recorded_always, so a recording keeps it even while
// nobody watches); a stalled control loop publishes no new tick, so the topic's rate shows the loop's.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "tendril/server/topic_source.hpp"

namespace tendril::server {

// One control tick's force, as the reader returns it (tick 0: nothing published yet).
struct ArmForceSample {
  std::uint64_t tick = 0;
  double t = 0.0;                   // control time (s)
  std::array<double, 3> force_n{};  // probe (tool) frame, environment on the probe (N)
  bool force_valid = false;         // a reading has arrived
  bool force_fresh = false;         // within the stale bound
  bool in_contact = false;          // the force phase (sweep) or F_n over 0.1 N
  const char* phase = nullptr;      // the sweep's phase (a static string), null without a sweep
};

struct ArmForceTopicSettings {
  std::string robot = "us_arm";    // topic prefix and the probe frame's name
  double rate_hz = 100.0;          // the reader is polled this often
  std::optional<double> target_n;  // d_f of the sweep (N)
  bool own_thread = true;          // false: the caller drives step() (tests)
};

class ArmForceTopic final : public TopicSource {
 public:
  using Reader = std::function<ArmForceSample()>;

  // Throws std::invalid_argument for a rate that is not positive and finite (or over 1 kHz, the control
  // rate) and an empty reader.
  ArmForceTopic(ArmForceTopicSettings settings, Reader reader);
  ~ArmForceTopic() override;
  ArmForceTopic(const ArmForceTopic&) = delete;
  ArmForceTopic& operator=(const ArmForceTopic&) = delete;

  // Reads one sample and publishes it if its tick is new; true when a message was published.
  bool step(std::uint64_t now_ns);

  std::string topic() const { return "/" + settings_.robot + "/force"; }
  std::vector<TopicInfo> topics() const override;
  std::optional<TopicPayload> latest(const std::string& topic, std::uint64_t since_version) const override;
  void set_ready_callback(std::function<void()> ready) override;
  void set_demand(const std::string& topic, bool wanted) override;
  std::string metrics() const override;

  // The message for a sample at wall-clock `now_ns` (public for tests).
  std::string message(const ArmForceSample& sample, std::uint64_t now_ns) const;

 private:
  void run();

  ArmForceTopicSettings settings_;
  Reader reader_;
  std::uint64_t last_tick_ = 0;  // step() only
  std::atomic<bool> wanted_{false};
  mutable std::mutex mutex_;
  TopicPayload latest_;
  std::function<void()> ready_;
  std::uint64_t published_ = 0;
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
  std::thread worker_;
};

class SerialArm;
// The arm's force topic (any serial arm: its force sensor is part of the type); the arm must outlive it
// (tendrild stops its front end, which holds the topic sources, before the runtime).
// own_thread false: the caller drives step() (tests).
std::shared_ptr<ArmForceTopic> make_arm_force_topic(const SerialArm& arm, bool own_thread = true);

}  // namespace tendril::server
