// A fixed set of worker threads with a bounded queue: Submit blocks while `max_pending` tasks
// wait, so producers cannot run ahead of the workers and memory stays bounded.
#pragma once

#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace rolamos {

class TaskPool {
 public:
  // threads <= 0: one per core.
  TaskPool(int threads, int max_pending);
  ~TaskPool();
  TaskPool(const TaskPool&) = delete;
  TaskPool& operator=(const TaskPool&) = delete;

  // Queues a task; rethrows the first error a task raised.
  void Submit(std::function<void()> task);
  // Waits until every queued task ran; rethrows the first error a task raised.
  void Wait();
  int threads() const { return static_cast<int>(workers_.size()); }

 private:
  void Run();
  void RethrowLocked();

  std::mutex mutex_;
  std::condition_variable work_ready_;
  std::condition_variable space_ready_;
  std::condition_variable idle_;
  std::deque<std::function<void()>> queue_;
  std::vector<std::thread> workers_;
  std::exception_ptr error_;
  size_t max_pending_;
  int running_ = 0;
  bool stopping_ = false;
};

}  // namespace rolamos
