#include "tendril/server/http/lease.hpp"

namespace tendril::server::http {

LeaseManager::LeaseManager(std::chrono::milliseconds timeout) : timeout_(timeout) {}

bool LeaseManager::held_by_locked(const std::string& key, Clock::time_point now) const {
  return !holder_key_.empty() && holder_key_ == key && now < expires_;
}

bool LeaseManager::acquire(const std::string& key, const std::string& label, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  const bool free = holder_key_.empty() || now >= expires_;
  if (!free && holder_key_ != key) return false;
  holder_key_ = key;
  holder_label_ = label;
  expires_ = now + timeout_;
  return true;
}

bool LeaseManager::release(const std::string& key, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (!held_by_locked(key, now)) return false;
  holder_key_.clear();
  holder_label_.clear();
  return true;
}

bool LeaseManager::use(const std::string& key, Clock::time_point now) {
  std::lock_guard lock(mutex_);
  if (!held_by_locked(key, now)) return false;
  expires_ = now + timeout_;
  return true;
}

LeaseManager::Status LeaseManager::status(const std::string& key, Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  Status status;
  if (holder_key_.empty() || now >= expires_) return status;
  status.held = true;
  status.yours = holder_key_ == key;
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
  // Bounded: many refused clients cannot grow memory.
  if (takeover_tokens_.size() >= 64) takeover_tokens_.erase(takeover_tokens_.begin());
  takeover_tokens_[random] = {key, now + kTakeoverTokenLifetime};
}

LeaseManager::TakeoverResult LeaseManager::take_over(const std::string& key, const std::string& label,
                                                     const std::string& token, Clock::time_point now,
                                                     std::string& previous_key) {
  std::lock_guard lock(mutex_);
  previous_key.clear();
  const auto it = takeover_tokens_.find(token);
  if (it == takeover_tokens_.end() || it->second.key != key || now >= it->second.expires) {
    return TakeoverResult::kBadToken;
  }
  takeover_tokens_.erase(it);
  if (!holder_key_.empty() && now < expires_ && holder_key_ != key) previous_key = holder_key_;
  holder_key_ = key;
  holder_label_ = label;
  expires_ = now + timeout_;
  return TakeoverResult::kTaken;
}

std::optional<std::string> LeaseManager::holder(Clock::time_point now) const {
  std::lock_guard lock(mutex_);
  if (holder_key_.empty() || now >= expires_) return std::nullopt;
  return holder_key_;
}

}  // namespace tendril::server::http
