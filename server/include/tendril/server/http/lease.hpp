// The operator lease: at most one client may command a robot at a time (RobotLeases below keeps one
// lease per robot). A lease lasts `timeout` after it was
// taken or last used, so a vanished console cannot keep it forever. Time is passed in, so tests step it.
//
// Ownership is a secret only the holder has. Every lease has a lease token (random, issued when the
// lease is taken); a caller holds the lease when it presents that token, or when it is the identity
// the lease was taken by. Callers are named by keys the front end derives from their credentials:
//   "session:<cookie session id>"  the console's cookie session (the cookie is a secret)
//   "lease:<token>"                a caller that presents a lease token (header X-Tendril-Lease)
//   "bearer"                       a caller with the bearer token and nothing else (plain curl)
//   "ws:<connection id>"           a WebSocket connection with neither cookie nor lease token
// A caller that presents a lease token asks for a lease bound to the token alone: when it takes the
// lease (fresh or by takeover) the new token is its only key, whatever token it sent before. Any
// other caller's lease is bound to its key, and its token works too (e.g. a console's REST lease used
// from a script, or a REST lease used on a WebSocket).
//
// Takeover: another operator who is refused gets a takeover token (issue_takeover_token); presenting it
// within `kTakeoverTokenLifetime` (take_over) is the confirmation that moves the lease. Whether the
// holder may be displaced at all (not while it streams servo commands) is the caller's decision.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace tendril::server::http {

class LeaseManager {
 public:
  using Clock = std::chrono::steady_clock;
  static constexpr std::chrono::seconds kTakeoverTokenLifetime{15};
  static constexpr std::size_t kMaxTakeoverOffers = 64;
  // Key prefix of a caller that identifies itself by a lease token alone.
  static constexpr std::string_view kTokenKeyPrefix = "lease:";

  struct Status {
    bool held = false;
    bool yours = false;
    std::string holder_label;  // public name of the holder (never a secret)
    std::chrono::milliseconds remaining{0};
    // Changes whenever the lease is taken anew, taken over or released; not on renewal.
    std::uint64_t generation = 0;
  };

  // What a successful acquire or takeover hands back: the lease token to present from now on.
  struct Grant {
    std::string lease_token;
    std::uint64_t generation = 0;
  };

  explicit LeaseManager(std::chrono::milliseconds timeout);

  // Takes the lease when it is free or expired, or renews it when `key` holds it (then the token in
  // force is returned and `fresh_token` is unused). nullopt when another caller holds it.
  // `fresh_token` is the token to issue for a new lease (the caller makes it unguessable).
  std::optional<Grant> acquire(const std::string& key, const std::string& label,
                               const std::string& fresh_token, Clock::time_point now);
  // Gives the lease back; false when `key` did not hold it.
  bool release(const std::string& key, Clock::time_point now);
  // Gives the lease back when it is bound to `key` itself (a WebSocket connection that closed); a
  // lease merely reachable with a token is left alone. True when it was released.
  bool release_bound_to(const std::string& key, Clock::time_point now);
  // When `key` holds an unexpired lease: renews it (a command counts as activity) and returns its
  // generation. nullopt otherwise.
  std::optional<std::uint64_t> use(const std::string& key, Clock::time_point now);
  Status status(const std::string& key, Clock::time_point now) const;
  bool holds(const std::string& key, Clock::time_point now) const { return status(key, now).yours; }
  std::chrono::milliseconds timeout() const noexcept { return timeout_; }

  // A one-time token that lets `key` take the lease over from its current holder within
  // kTakeoverTokenLifetime. `random` is the token text (the caller makes it unguessable). At most
  // kMaxTakeoverOffers are pending (one per requester); beyond that the oldest offer is withdrawn.
  void issue_takeover_token(const std::string& key, const std::string& random, Clock::time_point now);
  enum class TakeoverResult { kTaken, kBadToken };
  struct Takeover {
    TakeoverResult result = TakeoverResult::kBadToken;
    Grant grant;                             // when taken
    std::vector<std::string> previous_keys;  // keys that held the displaced lease (empty if it was free)
  };
  // Takes the lease for `key` when `token` was issued to `key` and has not expired; consumes the token.
  Takeover take_over(const std::string& key, const std::string& label, const std::string& token,
                     const std::string& fresh_token, Clock::time_point now);
  // Whether take_over would accept `token` from `key` now (checked on every robot before any moves).
  bool takeover_token_valid(const std::string& key, const std::string& token, Clock::time_point now) const;
  // The lease token when `key` holds the lease now.
  std::optional<std::string> token_if_held(const std::string& key, Clock::time_point now) const;

 private:
  bool live_locked(Clock::time_point now) const { return !holder_key_.empty() && now < expires_; }
  bool held_by_locked(const std::string& key, Clock::time_point now) const;
  Grant grant_locked(const std::string& key, const std::string& label, const std::string& fresh_token,
                     Clock::time_point now);

  const std::chrono::milliseconds timeout_;
  mutable std::mutex mutex_;
  std::string holder_key_;  // the identity the lease is bound to ("lease:<token>" when token-only)
  std::string lease_token_;
  std::string holder_label_;
  Clock::time_point expires_{};
  std::uint64_t generation_ = 0;
  struct PendingTakeover {
    std::string key;
    Clock::time_point expires;
    std::uint64_t issued = 0;  // order of issue: at the cap, the oldest offer goes
  };
  std::map<std::string, PendingTakeover> takeover_tokens_;  // token -> who may use it, until when
  std::uint64_t takeovers_issued_ = 0;
};

// The leases of a server's robots, one LeaseManager each: a surgeon may command the catheter while a
// script commands the arm (the set-up of Heunis et al. 2021), and neither can command the other's robot. A
// caller's leases share one lease token: a caller that already holds a live lease gets that token again with
// the next robot's lease, so one X-Tendril-Lease header commands every robot it holds.
class RobotLeases {
 public:
  using Clock = LeaseManager::Clock;
  RobotLeases(const std::vector<std::string>& robots, std::chrono::milliseconds timeout);
  // nullptr for a robot the server does not have.
  LeaseManager* find(const std::string& robot) const;
  const std::vector<std::string>& robots() const noexcept { return robots_; }
  std::chrono::milliseconds timeout() const noexcept { return timeout_; }
  // The token of a live lease `key` holds on any robot (nullopt when it holds none).
  std::optional<std::string> token_held_by(const std::string& key, Clock::time_point now) const;

 private:
  std::vector<std::string> robots_;
  std::chrono::milliseconds timeout_;
  std::map<std::string, std::unique_ptr<LeaseManager>> by_robot_;  // a LeaseManager holds a mutex
};

}  // namespace tendril::server::http
