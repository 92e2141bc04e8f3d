#include "util/parallel_for.h"

#include <atomic>
#include <chrono>
#include <thread>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

namespace rolamos {
namespace {

TEST(ParallelFor, RunsEveryItemOnceWithinTheWorkerRange) {
  const int threads = 3;
  std::vector<std::atomic<int>> seen(1000);
  std::atomic<int> bad_worker{0};
  ParallelForOptions o;
  o.threads = threads;
  long long last_progress = -1;
  bool progress_grew = true;
  o.on_progress = [&](long long done) {
    progress_grew = progress_grew && done > last_progress;
    last_progress = done;
  };
  ParallelFor(1000, [&](long long i, int worker) {
    ++seen[static_cast<size_t>(i)];
    if (worker < 0 || worker >= threads) ++bad_worker;
  }, o);
  for (const auto& s : seen) EXPECT_EQ(s.load(), 1);
  EXPECT_EQ(bad_worker.load(), 0);
  EXPECT_TRUE(progress_grew);
  EXPECT_EQ(last_progress, 1000);
}

TEST(ParallelFor, RethrowsTheFirstErrorAndStopsStartingItems) {
  std::atomic<int> ran{0};
  std::atomic<bool> thrown{false};
  EXPECT_THROW(ParallelFor(100000, [&](long long i, int) {
                 ++ran;
                 if (i == 10) {
                   thrown = true;
                   throw std::runtime_error("item 10");
                 }
                 // Later items wait (up to 2 s) for item 10's error: on a loaded machine the other
                 // thread could otherwise run them all before item 10's thread is scheduled.
                 if (i > 1000)
                   for (const auto start = std::chrono::steady_clock::now();
                        !thrown && std::chrono::steady_clock::now() - start < std::chrono::seconds(2);)
                     std::this_thread::yield();
               }),
               std::runtime_error);
  EXPECT_LT(ran.load(), 100000);
  // A progress callback that throws cancels the loop, and its exception comes out.
  ParallelForOptions o;
  o.on_progress = [](long long done) {
    if (done >= 5) throw std::logic_error("cancelled");
  };
  EXPECT_THROW(ParallelFor(100000, [](long long, int) {}, o), std::logic_error);
  ParallelFor(0, [](long long, int) { FAIL() << "no items"; });
}

}  // namespace
}  // namespace rolamos
