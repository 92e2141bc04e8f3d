#include "util/task_pool.h"

#include <algorithm>

namespace rolamos {

TaskPool::TaskPool(int threads, int max_pending)
    : max_pending_(static_cast<size_t>(std::max(1, max_pending))) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Run(); });
}

TaskPool::~TaskPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  work_ready_.notify_all();
  space_ready_.notify_all();
  for (auto& w : workers_) w.join();
}

void TaskPool::RethrowLocked() {
  if (error_) {
    auto e = error_;
    error_ = nullptr;
    std::rethrow_exception(e);
  }
}

void TaskPool::Submit(std::function<void()> task) {
  std::unique_lock<std::mutex> lock(mutex_);
  space_ready_.wait(lock, [&] { return queue_.size() < max_pending_ || error_ || stopping_; });
  RethrowLocked();
  queue_.push_back(std::move(task));
  work_ready_.notify_one();
}

void TaskPool::Wait() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [&] { return queue_.empty() && running_ == 0; });
  RethrowLocked();
}

void TaskPool::Run() {
  for (;;) {
    std::function<void()> task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_ready_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping and drained
      task = std::move(queue_.front());
      queue_.pop_front();
      ++running_;
    }
    space_ready_.notify_one();
    std::exception_ptr failure;
    try {
      task();
    } catch (...) {
      failure = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      --running_;
      if (failure && !error_) {
        error_ = failure;
        queue_.clear();  // the job failed: the rest of it is moot
      }
    }
    space_ready_.notify_all();
    idle_.notify_all();
  }
}

}  // namespace rolamos
