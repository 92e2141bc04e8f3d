#include "util/parallel_for.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace rolamos {

int ParallelThreads(int threads) {
  if (threads > 0) return threads;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

void ParallelFor(long long n, const std::function<void(long long, int)>& work,
                 const ParallelForOptions& options) {
  if (n <= 0) return;
  const int threads = static_cast<int>(std::min<long long>(ParallelThreads(options.threads), n));
  std::atomic<long long> next{0};
  std::atomic<bool> stop{false};
  std::mutex mutex;
  std::condition_variable changed;
  long long finished = 0;
  int running = threads;
  std::exception_ptr error;
  auto run = [&](int worker) {
    try {
      for (long long i; !stop && (i = next++) < n;) {
        work(i, worker);
        std::lock_guard<std::mutex> lock(mutex);
        ++finished;
        changed.notify_all();
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex);
      if (!error) error = std::current_exception();
      stop = true;
    }
    std::lock_guard<std::mutex> lock(mutex);
    --running;
    changed.notify_all();
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(run, t);
  if (!options.on_progress) {
    run(0);  // no one to report to: the calling thread works too
  } else {
    pool.emplace_back(run, 0);
    std::exception_ptr cancelled;
    std::unique_lock<std::mutex> lock(mutex);
    long long reported = 0;
    for (;;) {  // the last count is reported too, after the threads finished
      if (finished != reported && !cancelled) {
        reported = finished;
        lock.unlock();
        try {
          options.on_progress(reported);
        } catch (...) {
          cancelled = std::current_exception();
          stop = true;
        }
        lock.lock();
        continue;
      }
      if (running == 0) break;
      changed.wait(lock);
    }
    lock.unlock();
    for (auto& t : pool) t.join();
    if (error) std::rethrow_exception(error);
    if (cancelled) std::rethrow_exception(cancelled);
    return;
  }
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

}  // namespace rolamos
