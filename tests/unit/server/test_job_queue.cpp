// JobQueue: states, progress, cancellation (queued and running), bounds, failure messages.
#include "tendril/server/job_queue.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

namespace tendril::server {
namespace {

using namespace std::chrono_literals;

// Polls until pred() holds or ~5 s passed (a count of polls, not a timing assertion).
template <typename Pred>
bool eventually(Pred pred) {
  for (int i = 0; i < 500; ++i) {
    if (pred()) return true;
    std::this_thread::sleep_for(10ms);
  }
  return pred();
}

// A job that reports progress and stops when released or cancelled.
struct Gate {
  std::atomic<bool> release{false};
  std::atomic<bool> started{false};
  JobQueue::Work work(double progress = 0.5) {
    return [this, progress](const teleop::JobControl& control) {
      started = true;
      control.report(progress);
      while (!release) {
        control.check_cancelled();
        std::this_thread::sleep_for(1ms);
      }
      return nlohmann::json{{"answer", 42}};
    };
  }
};

TEST(JobQueue, RunsAJobThroughQueuedRunningSucceededWithProgressAndResult) {
  Gate gate;
  JobQueue q({1, 8, 32});
  const auto job = q.submit("plan", gate.work(0.25));
  ASSERT_TRUE(job);
  EXPECT_EQ(job->kind, "plan");
  EXPECT_FALSE(job->finished());
  ASSERT_TRUE(eventually([&] { return q.get(job->id)->state == JobState::kRunning; }));
  ASSERT_TRUE(eventually([&] { return q.get(job->id)->progress == 0.25; }));
  gate.release = true;
  ASSERT_TRUE(eventually([&] { return q.get(job->id)->finished(); }));
  const auto done = q.get(job->id);
  EXPECT_EQ(done->state, JobState::kSucceeded);
  EXPECT_EQ(done->progress, 1.0);
  ASSERT_TRUE(done->result);
  EXPECT_EQ((*done->result)["answer"], 42);
  const auto j = done->to_json();
  EXPECT_EQ(j["state"], "succeeded");
  EXPECT_TRUE(j["finished_s"].is_number());
  EXPECT_GE(j["finished_s"].get<double>(), j["created_s"].get<double>());
}

TEST(JobQueue, AFailingJobEndsFailedWithTheReason) {
  JobQueue q;
  const auto job = q.submit("plan", [](const teleop::JobControl&) -> nlohmann::json {
    throw std::invalid_argument("the vessel is shorter than one insertion step");
  });
  ASSERT_TRUE(eventually([&] { return q.get(job->id)->finished(); }));
  const auto done = q.get(job->id);
  EXPECT_EQ(done->state, JobState::kFailed);
  EXPECT_EQ(done->message, "the vessel is shorter than one insertion step");
  EXPECT_FALSE(done->result);
}

TEST(JobQueue, CancelsARunningJobThroughJobControl) {
  Gate gate;
  JobQueue q;
  const auto job = q.submit("plan", gate.work());
  ASSERT_TRUE(eventually([&] { return gate.started.load(); }));
  const auto cancelled = q.cancel(job->id);
  ASSERT_TRUE(cancelled);
  EXPECT_EQ(cancelled->state, JobState::kCancelled) << cancelled->message;
}

TEST(JobQueue, CancelsAQueuedJobAtOnceAndTheWorkerSkipsIt) {
  JobQueue q({1, 8, 32});
  Gate first, second;
  const auto a = q.submit("plan", first.work());
  const auto b = q.submit("plan", second.work());
  ASSERT_TRUE(eventually([&] { return first.started.load(); }));
  const auto cancelled = q.cancel(b->id, 0ms);
  EXPECT_EQ(cancelled->state, JobState::kCancelled);
  first.release = true;
  ASSERT_TRUE(eventually([&] { return q.get(a->id)->finished(); }));
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(second.started.load());
  EXPECT_EQ(q.get(b->id)->state, JobState::kCancelled);
}

TEST(JobQueue, CancellingAFinishedJobLeavesItAsItWas) {
  JobQueue q;
  const auto job = q.submit("plan", [](const teleop::JobControl&) { return nlohmann::json{{"ok", true}}; });
  ASSERT_TRUE(eventually([&] { return q.get(job->id)->finished(); }));
  EXPECT_EQ(q.cancel(job->id)->state, JobState::kSucceeded);
  EXPECT_FALSE(q.cancel("j999"));
  EXPECT_FALSE(q.get("j999"));
}

TEST(JobQueue, RefusesJobsBeyondThePendingBound) {
  Gate gate;
  JobQueue q({1, 2, 32});
  ASSERT_TRUE(q.submit("plan", gate.work()));
  ASSERT_TRUE(q.submit("plan", gate.work()));
  EXPECT_FALSE(q.submit("plan", gate.work()));
  gate.release = true;
  ASSERT_TRUE(eventually([&] { return q.list().front().finished(); }));
  EXPECT_TRUE(q.submit("plan", gate.work()));
}

TEST(JobQueue, ForgetsTheOldestFinishedJobsFirst) {
  JobQueue q({1, 8, 3});
  std::vector<std::string> ids;
  for (int i = 0; i < 5; ++i) {
    const auto job = q.submit("plan", [](const teleop::JobControl&) { return nlohmann::json::object(); });
    ids.push_back(job->id);
    ASSERT_TRUE(eventually([&] { return q.get(job->id) && q.get(job->id)->finished(); }));
  }
  EXPECT_FALSE(q.get(ids[0]));
  EXPECT_FALSE(q.get(ids[1]));
  for (int i = 2; i < 5; ++i) EXPECT_TRUE(q.get(ids[static_cast<std::size_t>(i)]));
  const auto list = q.list();
  ASSERT_EQ(list.size(), 3u);
  EXPECT_EQ(list.front().id, ids[4]);  // newest first
}

TEST(JobQueue, ShutdownCancelsRunningAndQueuedJobs) {
  Gate gate;
  JobQueue q({1, 8, 32});
  const auto a = q.submit("plan", gate.work());
  const auto b = q.submit("plan", gate.work());
  ASSERT_TRUE(eventually([&] { return gate.started.load(); }));
  q.shutdown();
  EXPECT_EQ(q.get(a->id)->state, JobState::kCancelled);
  EXPECT_EQ(q.get(b->id)->state, JobState::kCancelled);
  EXPECT_FALSE(q.submit("plan", gate.work()));
}

TEST(JobQueue, RunsJobsInParallelOnSeveralWorkers) {
  Gate a, b;  // outlive the queue, whose workers read them until they finish
  JobQueue q({2, 8, 32});
  q.submit("plan", a.work());
  q.submit("plan", b.work());
  EXPECT_TRUE(eventually([&] { return a.started && b.started; }));
  a.release = true;
  b.release = true;
}

}  // namespace
}  // namespace tendril::server
