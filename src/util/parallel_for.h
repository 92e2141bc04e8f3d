// The one parallel loop of the library: items [0, n) on a fixed set of threads, the first error
// rethrown to the caller once every thread stopped, progress reported on the calling thread.
#pragma once

#include <functional>

namespace rolamos {

struct ParallelForOptions {
  int threads = 0;  // 0: one per core
  // Called on the calling thread (never concurrently) with the number of items finished, each
  // time it grows. An exception it throws cancels the loop (items not started are skipped) and
  // is rethrown once the threads have stopped.
  std::function<void(long long done)> on_progress;
};

// The number of threads ParallelFor uses for `threads` (0: one per core, at least 1).
int ParallelThreads(int threads);

// Runs work(i, worker) for every i in [0, n); `worker` in [0, ParallelThreads(threads)) names the
// thread, for per-thread state. After the first exception no new item starts; it is rethrown.
void ParallelFor(long long n, const std::function<void(long long i, int worker)>& work,
                 const ParallelForOptions& options = {});

}  // namespace rolamos
