#include "work_lane.hpp"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <utility>

namespace tendril::server::http {

WorkLane::WorkLane(Options options) : options_(std::move(options)) {
  const int threads = std::max(1, options_.threads);
  threads_.reserve(static_cast<std::size_t>(threads));
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { work(); });
}

WorkLane::~WorkLane() { stop(); }

bool WorkLane::try_submit(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    if (stopping_ || queue_.size() >= options_.max_queued) {
      ++refused_;
      return false;
    }
    queue_.push_back(std::move(task));
  }
  wake_.notify_one();
  return true;
}

void WorkLane::stop() {
  std::deque<std::function<void()>> dropped;
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
    dropped.swap(queue_);
  }
  wake_.notify_all();
  for (auto& thread : threads_)
    if (thread.joinable()) thread.join();
  // The dropped tasks (and the connections they hold) go here, outside the lock.
}

WorkLane::Stats WorkLane::stats() const {
  std::lock_guard lock(mutex_);
  return {queue_.size(), running_, done_, refused_};
}

void WorkLane::work() {
  if (options_.nice != 0) {
    // Linux gives each thread its own nice value: the I/O threads (and so the e-stop) stay ahead.
    const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
    errno = 0;
    const int current = ::getpriority(PRIO_PROCESS, tid);
    if (errno == 0) (void)::setpriority(PRIO_PROCESS, tid, std::min(19, current + options_.nice));
  }
  while (true) {
    std::function<void()> task;
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      task = std::move(queue_.front());
      queue_.pop_front();
      ++running_;
    }
    try {
      task();        // a request's task contains its own exceptions (it answers its connection)
    } catch (...) {  // NOLINT(bugprone-empty-catch): a worker must outlive any one task
    }
    task = nullptr;
    std::lock_guard lock(mutex_);
    --running_;
    ++done_;
  }
}

}  // namespace tendril::server::http
