// The operator lease: at most one client may command at a time. A lease lasts `timeout` after it was
// taken or last used, so a vanished console cannot keep it forever. Time is passed in, so tests step it.
//
// Takeover: another operator who is refused gets a takeover token (issue_takeover_token); presenting it
// within `kTakeoverTokenLifetime` (take_over) is the confirmation that moves the lease. Whether the
// holder may be displaced at all (not while it streams servo commands) is the caller's decision.
#pragma once

#include <chrono>
#include <map>
#include <mutex>
#include <optional>
#include <string>

namespace tendril::server::http {

class LeaseManager {
 public:
  using Clock = std::chrono::steady_clock;
  static constexpr std::chrono::seconds kTakeoverTokenLifetime{15};

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

  // A one-time token that lets `key` take the lease over from its current holder within
  // kTakeoverTokenLifetime. `random` is the token text (the caller makes it unguessable).
  void issue_takeover_token(const std::string& key, const std::string& random, Clock::time_point now);
  enum class TakeoverResult { kTaken, kBadToken };
  // Takes the lease for `key` when `token` was issued to `key` and has not expired; consumes the token.
  // `previous_key` receives the displaced holder (empty when the lease was free).
  TakeoverResult take_over(const std::string& key, const std::string& label, const std::string& token,
                           Clock::time_point now, std::string& previous_key);

 private:
  bool held_by_locked(const std::string& key, Clock::time_point now) const;

  const std::chrono::milliseconds timeout_;
  mutable std::mutex mutex_;
  std::string holder_key_;
  std::string holder_label_;
  Clock::time_point expires_{};
  struct PendingTakeover {
    std::string key;
    Clock::time_point expires;
  };
  std::map<std::string, PendingTakeover> takeover_tokens_;  // token -> who may use it, until when
};

}  // namespace tendril::server::http
