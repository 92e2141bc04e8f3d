// CPU time of the calling thread: what a stage costs, whatever else the cores are doing (wall
// time would count the waits of a thread that shares its core with others).
#pragma once

#include <ctime>

namespace rolamos {

// CPU time of the whole process (user + system, all threads), seconds.
inline double ProcessCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

inline long long ThreadCpuNanoseconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<long long>(t.tv_sec) * 1000000000LL + t.tv_nsec;
}

// Adds the calling thread's CPU time since construction (or the last lap) to counters.
class CpuLaps {
 public:
  CpuLaps() : t_(ThreadCpuNanoseconds()) {}
  // Nanoseconds since the last lap.
  long long Lap() {
    const long long now = ThreadCpuNanoseconds();
    const long long d = now - t_;
    t_ = now;
    return d;
  }
  void Restart() { t_ = ThreadCpuNanoseconds(); }

 private:
  long long t_;
};

}  // namespace rolamos
