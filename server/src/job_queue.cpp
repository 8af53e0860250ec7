#include "tendril/server/job_queue.hpp"

#include <algorithm>
#include <chrono>

namespace tendril::server {

namespace {
double unix_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}
}  // namespace

const char* to_string(JobState state) noexcept {
  switch (state) {
    case JobState::kQueued:
      return "queued";
    case JobState::kRunning:
      return "running";
    case JobState::kSucceeded:
      return "succeeded";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

nlohmann::json JobInfo::to_json(bool with_result) const {
  auto optional_time = [](const std::optional<double>& t) {
    return t ? nlohmann::json(*t) : nlohmann::json();
  };
  nlohmann::json j = {{"id", id},
                      {"kind", kind},
                      {"state", to_string(state)},
                      {"progress", progress},
                      {"message", message},
                      {"created_s", created_s},
                      {"started_s", optional_time(started_s)},
                      {"finished_s", optional_time(finished_s)}};
  if (with_result) j["result"] = result ? *result : nlohmann::json();
  return j;
}

JobQueue::JobQueue(JobQueueOptions options) : options_(options) {
  if (options_.workers < 1) options_.workers = 1;
  if (options_.max_pending < 1) options_.max_pending = 1;
  for (std::size_t i = 0; i < options_.workers; ++i) workers_.emplace_back([this] { worker(); });
}

JobQueue::~JobQueue() { shutdown(); }

void JobQueue::shutdown() {
  {
    std::lock_guard lock(mutex_);
    if (stopping_ && workers_.empty()) return;
    stopping_ = true;
    for (auto& [id, e] : jobs_) e->cancel.store(true);
  }
  work_ready_.notify_all();
  for (auto& t : workers_)
    if (t.joinable()) t.join();
  workers_.clear();
  std::lock_guard lock(mutex_);
  const double now = unix_now();
  for (auto& e : queue_) {
    e->info.state = JobState::kCancelled;
    e->info.message = "the server stopped before the job ran";
    e->info.finished_s = now;
  }
  queue_.clear();
  pending_ = 0;
}

std::optional<JobInfo> JobQueue::submit(std::string kind, Work work) {
  std::unique_lock lock(mutex_);
  if (stopping_ || pending_ >= options_.max_pending) return std::nullopt;
  auto e = std::make_shared<Entry>();
  e->info.id = "j" + std::to_string(next_id_++);
  e->info.kind = std::move(kind);
  e->info.created_s = unix_now();
  e->info.message = "waiting for a worker";
  e->work = std::move(work);
  jobs_[e->info.id] = e;
  order_.push_back(e->info.id);
  queue_.push_back(e);
  ++pending_;
  auto out = snapshot(*e);
  lock.unlock();
  work_ready_.notify_one();
  return out;
}

JobInfo JobQueue::snapshot(const Entry& e) const {
  JobInfo out = e.info;
  if (out.state == JobState::kRunning) out.progress = e.progress.load(std::memory_order_relaxed);
  return out;
}

std::optional<JobInfo> JobQueue::get(const std::string& id) const {
  std::lock_guard lock(mutex_);
  const auto it = jobs_.find(id);
  if (it == jobs_.end()) return std::nullopt;
  return snapshot(*it->second);
}

std::vector<JobInfo> JobQueue::list() const {
  std::lock_guard lock(mutex_);
  std::vector<JobInfo> out;
  for (auto it = order_.rbegin(); it != order_.rend(); ++it)
    if (const auto j = jobs_.find(*it); j != jobs_.end()) out.push_back(snapshot(*j->second));
  return out;
}

std::optional<JobInfo> JobQueue::cancel(const std::string& id, std::chrono::milliseconds wait) {
  std::unique_lock lock(mutex_);
  const auto it = jobs_.find(id);
  if (it == jobs_.end()) return std::nullopt;
  auto e = it->second;
  if (e->info.state == JobState::kQueued) {
    queue_.erase(std::remove(queue_.begin(), queue_.end(), e), queue_.end());
    e->info.state = JobState::kCancelled;
    e->info.message = "cancelled before it started";
    e->info.finished_s = unix_now();
    --pending_;
    finished_order_.push_back(id);
    forget_old_finished();
    return snapshot(*e);
  }
  if (e->info.state == JobState::kRunning) {
    e->cancel.store(true);
    // The computation polls the flag between steps; wait a little so the answer is usually final.
    job_finished_.wait_for(lock, wait, [&] { return e->info.finished(); });
    if (!e->info.finished()) e->info.message = "cancellation requested; the computation has not stopped yet";
  }
  return snapshot(*e);
}

void JobQueue::forget_old_finished() {
  while (finished_order_.size() > options_.max_finished) {
    const auto id = finished_order_.front();
    finished_order_.pop_front();
    jobs_.erase(id);
    order_.erase(std::remove(order_.begin(), order_.end(), id), order_.end());
  }
}

void JobQueue::worker() {
  for (;;) {
    std::shared_ptr<Entry> e;
    {
      std::unique_lock lock(mutex_);
      work_ready_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      e = queue_.front();
      queue_.pop_front();
      e->info.state = JobState::kRunning;
      e->info.started_s = unix_now();
      e->info.message = "running";
    }
    teleop::JobControl control;
    control.cancel = &e->cancel;
    Entry* raw = e.get();
    control.progress = [raw](double f) {
      raw->progress.store(std::clamp(f, 0.0, 1.0), std::memory_order_relaxed);
    };
    JobState final_state = JobState::kSucceeded;
    std::string message = "done";
    std::shared_ptr<const nlohmann::json> result;
    try {
      control.check_cancelled();
      result = std::make_shared<const nlohmann::json>(e->work(control));
    } catch (const teleop::OperationCancelled&) {
      final_state = JobState::kCancelled;
      message = "cancelled while running";
    } catch (const std::exception& ex) {
      final_state = JobState::kFailed;
      message = ex.what();
    }
    {
      std::lock_guard lock(mutex_);
      e->info.state = final_state;
      e->info.message = std::move(message);
      e->info.progress = final_state == JobState::kSucceeded ? 1.0 : e->progress.load();
      e->info.result = std::move(result);
      e->info.finished_s = unix_now();
      e->work = nullptr;  // frees whatever the job captured (vessel text, …)
      --pending_;
      finished_order_.push_back(e->info.id);
      forget_old_finished();
    }
    job_finished_.notify_all();
  }
}

}  // namespace tendril::server
