// ConnectionRegistry: the front end's open connections and their limits (issue 30, "The e-stop must not
// wait for anyone"). Every accepted TCP connection takes a slot, so that unauthenticated clients can
// never take the descriptors an operator or a new e-stop client needs:
// - total: at most `total` connections, authenticated or not;
// - unauthenticated: connections that have not yet presented a valid token or cookie form a pool of at
//   most `unauthenticated` (< total), so `total - unauthenticated` stay for authenticated connections;
// - per address: at most `per_address` unauthenticated connections from one remote address.
// A new connection beyond a limit closes the oldest idle unauthenticated connection (of its own address
// when that address is at its limit), so a new e-stop client always gets in and one address can only
// push out its own connections; it is refused (closed at once) only when none is idle. Authenticated
// connections are never evicted. "Idle": waiting for a request (or for the TLS handshake), not one
// being answered.
//
// One mutex; each operation is O(log n). The connection is closed through the function its session
// attached, called outside the lock (it posts to the connection's strand).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

namespace tendril::server {

class ConnectionRegistry;

// One connection's place in the registry, shared by its HTTP session and, after an upgrade, by its
// WebSocket session; the place is given back when the last of them goes.
class ConnectionSlot {
 public:
  ConnectionSlot(ConnectionRegistry& registry, std::uint64_t key) : registry_(registry), key_(key) {}
  ~ConnectionSlot();
  ConnectionSlot(const ConnectionSlot&) = delete;
  ConnectionSlot& operator=(const ConnectionSlot&) = delete;
  ConnectionSlot(ConnectionSlot&&) = delete;
  ConnectionSlot& operator=(ConnectionSlot&&) = delete;

  // The session serving this connection: its id (authentication is reported by id) and how to close
  // it from any thread. A WebSocket session attaches again when it takes the connection over.
  void attach(std::uint64_t connection_id, std::function<void()> close);
  void set_idle(bool idle);
  bool authenticated() const;
  std::uint64_t key() const noexcept { return key_; }
  // Set (on the connection's strand) by the WebSocket session that took the stream over, so that the
  // HTTP session's close hook, running later on that strand, leaves the stream alone.
  bool handed_over = false;

 private:
  ConnectionRegistry& registry_;
  const std::uint64_t key_;
};

class ConnectionRegistry {
 public:
  struct Limits {
    std::size_t total = 0;
    std::size_t unauthenticated = 0;
    std::size_t per_address = 0;
  };
  struct Counts {
    std::size_t authenticated = 0;
    std::size_t unauthenticated = 0;
    std::uint64_t evicted = 0;              // idle unauthenticated connections closed to make room
    std::uint64_t refused_full = 0;         // closed at once: the total or unauthenticated limit
    std::uint64_t refused_per_address = 0;  // closed at once: their address's limit
  };

  void set_limits(const Limits& limits) {
    std::lock_guard lock(mutex_);
    limits_ = limits;
  }
  Limits limits() const {
    std::lock_guard lock(mutex_);
    return limits_;
  }

  // A connection from `address` was accepted: its slot, or null when it must be closed at once. Makes
  // room by closing the oldest idle unauthenticated connection when a limit is reached.
  std::shared_ptr<ConnectionSlot> admit(const std::string& address) {
    // Made before the lock: a slot given up (refused) releases its key, which takes the lock.
    auto slot = std::make_shared<ConnectionSlot>(*this, next_key_++);
    std::function<void()> close_evicted;
    {
      std::lock_guard lock(mutex_);
      const auto address_it = addresses_.find(address);
      const bool address_full =
          address_it != addresses_.end() && address_it->second.unauthenticated >= limits_.per_address;
      const bool pool_full =
          authenticated_ + unauthenticated_ >= limits_.total || unauthenticated_ >= limits_.unauthenticated;
      if (address_full || pool_full) {
        // An address at its limit competes only with itself; otherwise the oldest idle one anywhere.
        const std::set<std::uint64_t>& candidates =
            address_full ? address_it->second.idle : idle_unauthenticated_;
        if (candidates.empty()) {
          ++(address_full ? counts_.refused_per_address : counts_.refused_full);
          return nullptr;
        }
        const auto victim = entries_.find(*candidates.begin());
        close_evicted = std::move(victim->second.close);
        remove_locked(victim);
        ++counts_.evicted;
      }
      const std::uint64_t key = slot->key();
      Entry& entry = entries_[key];
      entry.address = address;
      entry.slot = slot;
      ++unauthenticated_;
      AddressState& state = addresses_[address];
      ++state.unauthenticated;
      state.idle.insert(key);
      idle_unauthenticated_.insert(key);
    }
    if (close_evicted) close_evicted();
    return slot;
  }

  // Descriptors ran out: closes the oldest idle unauthenticated connection. False when there is none.
  bool evict_oldest() {
    std::function<void()> close_evicted;
    {
      std::lock_guard lock(mutex_);
      if (idle_unauthenticated_.empty()) return false;
      const auto victim = entries_.find(*idle_unauthenticated_.begin());
      close_evicted = std::move(victim->second.close);
      remove_locked(victim);
      ++counts_.evicted;
    }
    if (close_evicted) close_evicted();
    return true;
  }

  // The connection presented a valid token or cookie: it leaves the unauthenticated pool for good.
  void authenticated(std::uint64_t connection_id) {
    std::lock_guard lock(mutex_);
    const auto key = by_connection_.find(connection_id);
    if (key == by_connection_.end()) return;  // not admitted by the listener (the fuzzer), or gone
    const auto it = entries_.find(key->second);
    if (it == entries_.end() || it->second.authenticated) return;
    leave_unauthenticated_locked(it->first, it->second);
    it->second.authenticated = true;
    ++authenticated_;
  }

  // The slot of a connection, for the WebSocket session that takes it over (null when none).
  std::shared_ptr<ConnectionSlot> slot_of(std::uint64_t connection_id) const {
    std::lock_guard lock(mutex_);
    const auto key = by_connection_.find(connection_id);
    if (key == by_connection_.end()) return nullptr;
    const auto it = entries_.find(key->second);
    return it == entries_.end() ? nullptr : it->second.slot.lock();
  }

  Counts counts() const {
    std::lock_guard lock(mutex_);
    Counts out = counts_;
    out.authenticated = authenticated_;
    out.unauthenticated = unauthenticated_;
    return out;
  }

 private:
  friend class ConnectionSlot;

  struct Entry {
    std::string address;
    std::uint64_t connection_id = 0;  // 0 until a session attaches
    bool authenticated = false;
    bool idle = true;
    std::function<void()> close;
    std::weak_ptr<ConnectionSlot> slot;
  };
  struct AddressState {
    std::size_t unauthenticated = 0;
    std::set<std::uint64_t> idle;  // keys of its idle unauthenticated connections, oldest first
  };

  void attach(std::uint64_t key, std::uint64_t connection_id, std::function<void()> close) {
    std::function<void()> previous;  // destroyed outside the lock
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(key);
    if (it == entries_.end()) return;  // evicted meanwhile
    if (it->second.connection_id != connection_id) {
      by_connection_.erase(it->second.connection_id);
      it->second.connection_id = connection_id;
      by_connection_[connection_id] = key;
    }
    previous = std::exchange(it->second.close, std::move(close));
  }

  void set_idle(std::uint64_t key, bool idle) {
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(key);
    if (it == entries_.end() || it->second.idle == idle) return;
    it->second.idle = idle;
    if (it->second.authenticated) return;
    auto& address_idle = addresses_[it->second.address].idle;
    if (idle) {
      idle_unauthenticated_.insert(key);
      address_idle.insert(key);
    } else {
      idle_unauthenticated_.erase(key);
      address_idle.erase(key);
    }
  }

  bool is_authenticated(std::uint64_t key) const {
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(key);
    return it != entries_.end() && it->second.authenticated;
  }

  void release(std::uint64_t key) {
    std::function<void()> close;  // destroyed outside the lock (it may hold the last session reference)
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(key);
    if (it == entries_.end()) return;  // evicted before
    close = std::move(it->second.close);
    remove_locked(it);
  }

  void leave_unauthenticated_locked(std::uint64_t key, const Entry& entry) {
    --unauthenticated_;
    idle_unauthenticated_.erase(key);
    const auto address = addresses_.find(entry.address);
    if (address == addresses_.end()) return;
    address->second.idle.erase(key);
    if (--address->second.unauthenticated == 0) addresses_.erase(address);
  }

  void remove_locked(std::map<std::uint64_t, Entry>::iterator it) {
    if (it->second.authenticated) {
      --authenticated_;
    } else {
      leave_unauthenticated_locked(it->first, it->second);
    }
    if (it->second.connection_id != 0) by_connection_.erase(it->second.connection_id);
    entries_.erase(it);
  }

  mutable std::mutex mutex_;
  Limits limits_;
  std::map<std::uint64_t, Entry> entries_;  // key: admission order
  std::set<std::uint64_t> idle_unauthenticated_;
  std::unordered_map<std::string, AddressState> addresses_;  // addresses with unauthenticated connections
  std::unordered_map<std::uint64_t, std::uint64_t> by_connection_;  // connection id -> key
  std::size_t authenticated_ = 0;
  std::size_t unauthenticated_ = 0;
  Counts counts_;
  std::atomic<std::uint64_t> next_key_{1};
};

inline ConnectionSlot::~ConnectionSlot() { registry_.release(key_); }
inline void ConnectionSlot::attach(std::uint64_t connection_id, std::function<void()> close) {
  registry_.attach(key_, connection_id, std::move(close));
}
inline void ConnectionSlot::set_idle(bool idle) { registry_.set_idle(key_, idle); }
inline bool ConnectionSlot::authenticated() const { return registry_.is_authenticated(key_); }

}  // namespace tendril::server
