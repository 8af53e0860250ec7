#include "tendril/server/http/lease.hpp"

#include <algorithm>

#include "tendril/server/http/request_codec.hpp"

namespace tendril::server::http {

namespace {

bool is_token_key(const std::string& key) { return key.rfind(LeaseManager::kTokenKeyPrefix, 0) == 0; }

std::string token_key(const std::string& token) { return std::string(LeaseManager::kTokenKeyPrefix) + token; }

}  // namespace

LeaseManager::LeaseManager(std::chrono::milliseconds timeout) : timeout_(timeout) {}

bool LeaseManager::held_by_locked(const std::string& key, Clock::time_point now) const {
  // Keys carry secrets (session ids, lease tokens): compared without an early exit.
  return live_locked(now) && !key.empty() &&
         (constant_time_equal(key, holder_key_) || constant_time_equal(key, token_key(lease_token_)));
}

LeaseManager::Grant LeaseManager::grant_locked(const std::string& key, const std::string& label,
                                               const std::string& fresh_token, Clock::time_point now) {
  lease_token_ = fresh_token;
  // A caller that names itself by a lease token gets a lease only the new token holds.
  holder_key_ = is_token_key(key) ? token_key(fresh_token) : key;
  holder_label_ = label;
  expires_ = now + timeout_;
  ++generation_;
  return {lease_token_, generation_};
}

std::optional<LeaseManager::Grant> LeaseManager::acquire(const std::string& key, const std::string& label,
                                                         const std::string& fresh_token,
                                                         Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (held_by_locked(key, now)) {
    expires_ = now + timeout_;
    return Grant{lease_token_, generation_};
  }
  if (live_locked(now)) return std::nullopt;
  return grant_locked(key, label, fresh_token, now);
}

bool LeaseManager::release(const std::string& key, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (!held_by_locked(key, now)) return false;
  holder_key_.clear();
  lease_token_.clear();
  holder_label_.clear();
  ++generation_;
  return true;
}

bool LeaseManager::release_bound_to(const std::string& key, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (!live_locked(now) || key.empty() || !constant_time_equal(key, holder_key_)) return false;
  holder_key_.clear();
  lease_token_.clear();
  holder_label_.clear();
  ++generation_;
  return true;
}

std::optional<std::uint64_t> LeaseManager::use(const std::string& key, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (!held_by_locked(key, now)) return std::nullopt;
  expires_ = now + timeout_;
  return generation_;
}

LeaseManager::Status LeaseManager::status(const std::string& key, Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  Status status;
  status.generation = generation_;
  if (!live_locked(now)) return status;
  status.held = true;
  status.yours = held_by_locked(key, now);
  status.holder_label = holder_label_;
  status.remaining = std::chrono::duration_cast<std::chrono::milliseconds>(expires_ - now);
  return status;
}

void LeaseManager::issue_takeover_token(const std::string& key, const std::string& random,
                                        Clock::time_point now) {
  std::lock_guard lock(mutex_);
  for (auto it = takeover_tokens_.begin(); it != takeover_tokens_.end();) {
    // Expired tokens go, and so does an older token of the same requester: one pending offer each.
    if (now >= it->second.expires || it->second.key == key) {
      it = takeover_tokens_.erase(it);
    } else {
      ++it;
    }
  }
  // Bounded: many refused clients cannot grow memory. The oldest offer goes (not the first token in
  // the map's order, which is random: that would withdraw a fresh offer as readily as a stale one).
  if (takeover_tokens_.size() >= kMaxTakeoverOffers) {
    takeover_tokens_.erase(
        std::min_element(takeover_tokens_.begin(), takeover_tokens_.end(),
                         [](const auto& a, const auto& b) { return a.second.issued < b.second.issued; }));
  }
  takeover_tokens_[random] = {key, now + kTakeoverTokenLifetime, ++takeovers_issued_};
}

LeaseManager::Takeover LeaseManager::take_over(const std::string& key, const std::string& label,
                                               const std::string& token, const std::string& fresh_token,
                                               Clock::time_point now) {
  std::lock_guard lock(mutex_);
  Takeover out;
  const auto it = takeover_tokens_.find(token);
  if (it == takeover_tokens_.end() || it->second.key != key || now >= it->second.expires) return out;
  takeover_tokens_.erase(it);
  if (live_locked(now) && !held_by_locked(key, now)) {
    out.previous_keys = {holder_key_, token_key(lease_token_)};
  }
  out.result = TakeoverResult::kTaken;
  out.grant = grant_locked(key, label, fresh_token, now);
  return out;
}

bool LeaseManager::takeover_token_valid(const std::string& key, const std::string& token,
                                        Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  const auto it = takeover_tokens_.find(token);
  return it != takeover_tokens_.end() && it->second.key == key && now < it->second.expires;
}

std::optional<std::string> LeaseManager::token_if_held(const std::string& key, Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  if (!held_by_locked(key, now)) return std::nullopt;
  return lease_token_;
}

RobotLeases::RobotLeases(const std::vector<std::string>& robots, std::chrono::milliseconds timeout)
    : robots_(robots), timeout_(timeout) {
  for (const auto& robot : robots_) by_robot_.emplace(robot, std::make_unique<LeaseManager>(timeout));
}

LeaseManager* RobotLeases::find(const std::string& robot) const {
  const auto it = by_robot_.find(robot);
  return it == by_robot_.end() ? nullptr : it->second.get();
}

std::optional<std::string> RobotLeases::token_held_by(const std::string& key, Clock::time_point now) const {
  for (const auto& robot : robots_) {
    if (auto token = by_robot_.at(robot)->token_if_held(key, now)) return token;
  }
  return std::nullopt;
}

}  // namespace tendril::server::http
