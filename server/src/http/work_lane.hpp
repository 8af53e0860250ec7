// WorkLane: a few worker threads with a bounded queue, where the front end runs a request's work
// (routing, parsing, the ControlApi call) so that the I/O threads only move bytes and no client's
// request can keep another's e-stop waiting for a thread. Two lanes exist (HttpServer::Impl): one for
// ordinary requests, one for large uploads and slow pictures, so that a vessel upload never queues an
// operator's command either. Workers run at a lower scheduling priority (nice) than the I/O threads.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace tendril::server::http {

class WorkLane {
 public:
  struct Options {
    std::string name;             // for logs and metrics ("requests", "uploads")
    int threads = 1;              // at least 1
    std::size_t max_queued = 16;  // tasks waiting (not running) before try_submit() refuses
    int nice = 0;                 // added to each worker's nice value (Linux: per thread); 0 = unchanged
  };
  explicit WorkLane(Options options);
  ~WorkLane();
  WorkLane(const WorkLane&) = delete;
  WorkLane& operator=(const WorkLane&) = delete;

  // Queues a task; false when the lane is full or stopped (the caller answers "busy" itself).
  bool try_submit(std::function<void()> task);
  // Refuses new tasks, drops the queued ones, and waits for the running ones to finish.
  void stop();

  struct Stats {
    std::size_t queued = 0;
    std::size_t running = 0;
    std::uint64_t done = 0;
    std::uint64_t refused = 0;  // try_submit() answered false
  };
  Stats stats() const;
  const std::string& name() const { return options_.name; }
  std::size_t max_queued() const { return options_.max_queued; }

 private:
  void work();

  const Options options_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> queue_;
  std::vector<std::thread> threads_;
  std::size_t running_ = 0;
  std::uint64_t done_ = 0;
  std::uint64_t refused_ = 0;
  bool stopping_ = false;
};

}  // namespace tendril::server::http
