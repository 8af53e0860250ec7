// JobControl: how a long computation (plan, design optimisation, calibration fit) running on a
// worker thread reports progress and learns that it was cancelled. Never used on the real-time path.
#pragma once

#include <atomic>
#include <functional>
#include <stdexcept>

namespace tendril::teleop {

// Thrown out of a long computation when its JobControl's cancel flag was set.
class OperationCancelled : public std::runtime_error {
 public:
  OperationCancelled() : std::runtime_error("the computation was cancelled") {}
};

struct JobControl {
  std::function<void(double fraction)> progress;  // 0..1, may be empty; called from the worker thread
  const std::atomic<bool>* cancel = nullptr;      // polled between steps; may be null

  void report(double fraction) const {
    if (progress) progress(fraction);
  }
  // Throws OperationCancelled when cancellation was requested.
  void check_cancelled() const {
    if (cancel != nullptr && cancel->load(std::memory_order_relaxed)) throw OperationCancelled();
  }
};

}  // namespace tendril::teleop
