// The operator lease: at most one client may command at a time. A lease lasts `timeout` after it was
// taken or last used, so a vanished console cannot keep it forever. Time is passed in, so tests step it.
#pragma once

#include <chrono>
#include <mutex>
#include <optional>
#include <string>

namespace tendril::server::http {

class LeaseManager {
 public:
  using Clock = std::chrono::steady_clock;

  struct Status {
    bool held = false;
    bool yours = false;
    std::string holder_label;  // public name of the holder (never a session secret)
    std::chrono::milliseconds remaining{0};
  };

  explicit LeaseManager(std::chrono::milliseconds timeout);

  // Takes the lease when it is free, expired or already `key`'s (then renews it). False when held by another.
  bool acquire(const std::string& key, const std::string& label, Clock::time_point now);
  // Gives the lease back; false when `key` did not hold it.
  bool release(const std::string& key, Clock::time_point now);
  // True when `key` holds an unexpired lease; renews it (a command counts as activity).
  bool use(const std::string& key, Clock::time_point now);
  Status status(const std::string& key, Clock::time_point now) const;
  // Key of the current holder, if any and not expired.
  std::optional<std::string> holder(Clock::time_point now) const;
  std::chrono::milliseconds timeout() const noexcept { return timeout_; }

 private:
  bool held_by_locked(const std::string& key, Clock::time_point now) const;

  const std::chrono::milliseconds timeout_;
  mutable std::mutex mutex_;
  std::string holder_key_;
  std::string holder_label_;
  Clock::time_point expires_{};
};

}  // namespace tendril::server::http
