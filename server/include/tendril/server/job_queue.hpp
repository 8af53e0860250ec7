// JobQueue: a small worker pool for long computations (path plans, design optimisation) requested
// over the network. Jobs wait in a bounded queue, run on N worker threads (never on the real-time
// or I/O threads), report progress, and can be cancelled through teleop::JobControl. Finished jobs
// are kept for GET /jobs/{id}; the oldest finished job is forgotten first once the bound is reached.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "tendril/teleop/job_control.hpp"

namespace tendril::server {

enum class JobState { kQueued, kRunning, kSucceeded, kFailed, kCancelled };
const char* to_string(JobState state) noexcept;  // API names: queued, running, succeeded, ...

struct JobQueueOptions {
  std::size_t workers = 1;        // threads; 1 leaves the second core of a small PC to control and I/O
  std::size_t max_pending = 8;    // queued + running jobs; submit() refuses more
  std::size_t max_finished = 32;  // finished jobs kept for read-out
};

// A copy of one job's state (the result is shared, not copied).
struct JobInfo {
  std::string id;
  std::string kind;
  JobState state = JobState::kQueued;
  double progress = 0.0;   // 0..1
  std::string message;     // why it failed, or what it is doing
  double created_s = 0.0;  // unix time
  std::optional<double> started_s, finished_s;
  std::shared_ptr<const nlohmann::json> result;  // set when succeeded

  bool finished() const noexcept {
    return state == JobState::kSucceeded || state == JobState::kFailed || state == JobState::kCancelled;
  }
  // API shape: {"id","kind","state","progress","message","created_s","started_s","finished_s","result"}.
  nlohmann::json to_json(bool with_result = true) const;
};

class JobQueue {
 public:
  // Runs on a worker thread. Returns the result; throws teleop::OperationCancelled when it saw the
  // cancel flag (the job ends "cancelled"); any other exception ends it "failed" with what() as message.
  using Work = std::function<nlohmann::json(const teleop::JobControl&)>;

  explicit JobQueue(JobQueueOptions options = {});
  ~JobQueue();  // cancels every job and joins the workers
  JobQueue(const JobQueue&) = delete;
  JobQueue& operator=(const JobQueue&) = delete;

  // Queues a job; nullopt when max_pending jobs are already queued or running.
  std::optional<JobInfo> submit(std::string kind, Work work);
  std::optional<JobInfo> get(const std::string& id) const;
  std::vector<JobInfo> list() const;  // newest first
  // Cancels a queued job at once; asks a running one to stop and waits up to `wait` for it to end.
  // Returns the job as it then is (a finished job is returned unchanged); nullopt when unknown.
  std::optional<JobInfo> cancel(const std::string& id,
                                std::chrono::milliseconds wait = std::chrono::milliseconds(2000));
  // Cancels everything and joins the workers; later submits are refused. Idempotent.
  void shutdown();

  const JobQueueOptions& options() const noexcept { return options_; }

 private:
  struct Entry {
    JobInfo info;  // guarded by mutex_ (progress lives in `progress` while running)
    Work work;
    std::atomic<bool> cancel{false};
    std::atomic<double> progress{0.0};
  };
  void worker();
  JobInfo snapshot(const Entry& e) const;  // mutex_ held
  void forget_old_finished();              // mutex_ held

  JobQueueOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable work_ready_, job_finished_;
  std::map<std::string, std::shared_ptr<Entry>> jobs_;
  std::deque<std::shared_ptr<Entry>> queue_;
  std::deque<std::string> finished_order_;
  std::vector<std::string> order_;  // creation order, for list()
  std::uint64_t next_id_ = 1;
  std::size_t pending_ = 0;  // queued + running
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace tendril::server
