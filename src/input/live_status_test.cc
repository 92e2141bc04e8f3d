#include "input/live_status.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// A source whose frames arrive by hand: only its counters matter to the keeper.
class Arrivals : public LiveSource {
 public:
  bool Next(InputFrame*) override { return false; }
  void Arrive() { ++counters_.received; }
};

struct Seen {
  std::mutex mutex;
  std::condition_variable changed;
  std::vector<LiveStatus> all;
  // Waits until a status says `received` frames arrived (a hang guard, not a speed test).
  bool WaitFor(long long received) {
    std::unique_lock<std::mutex> lock(mutex);
    return changed.wait_for(lock, std::chrono::seconds(30),
                            [&] { return !all.empty() && all.back().frames_received == received; });
  }
};

TEST(LiveStatusKeeper, FollowsTheSourceWhileNoFrameIsMapped) {
  Arrivals source;
  Seen seen;
  LiveStatusKeeper keeper(&source, 3, [&](const LiveStatus& s) {
    std::lock_guard<std::mutex> lock(seen.mutex);
    seen.all.push_back(s);
    seen.changed.notify_all();
  });
  ASSERT_TRUE(seen.WaitFor(0));
  EXPECT_TRUE(seen.all.front().running);
  EXPECT_EQ(seen.all.front().backlog_bound, 3);
  // Frames arrive and the engine maps none of them (busy, or the stream stalls after them).
  for (int i = 0; i < 5; ++i) source.Arrive();
  EXPECT_TRUE(seen.WaitFor(5)) << "the status never said the five frames arrived";
}

TEST(LiveStatusKeeper, CountsFramesMappedAndEndsNotRunning) {
  Arrivals source;
  std::vector<LiveStatus> all;
  std::mutex mutex;
  {
    LiveStatusKeeper keeper(&source, 2, [&](const LiveStatus& s) {
      std::lock_guard<std::mutex> lock(mutex);
      all.push_back(s);
    });
    const auto now = std::chrono::steady_clock::now();
    FrameReport r;
    r.status = "stitched";
    r.patch_id = 1;
    for (long i = 0; i < 3; ++i) {
      source.Arrive();
      keeper.Taken(i, now);
      keeper.Mapped(r, 0.1);
    }
    r.status = "rejected";
    source.Arrive();
    keeper.Taken(3, now);
    keeper.Mapped(r, 0);
    keeper.PatchWritten();
    EXPECT_EQ(keeper.mapped(), 4);
    EXPECT_EQ(keeper.patches(), 1);
    MosaicSummary summary;
    summary.stitched = 4;  // the rejected frame placed later (second chance)
    summary.rejected = 0;
    keeper.Finish(summary);
  }
  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_FALSE(all.empty());
  const LiveStatus& last = all.back();
  EXPECT_FALSE(last.running);
  EXPECT_EQ(last.frames_received, 4);
  EXPECT_EQ(last.frames_registered, 4);
  EXPECT_EQ(last.frames_rejected, 0);
  EXPECT_EQ(last.patches, 1);
  EXPECT_EQ(last.open_patch, 0);
  EXPECT_GE(last.latency_ms_p95, last.latency_ms_p50);
  EXPECT_GE(last.latency_ms_p50, 0);
}

TEST(LiveStatusKeeper, ARunThatFailsIsNotLeftRunning) {
  Arrivals source;
  std::vector<LiveStatus> all;
  {
    LiveStatusKeeper keeper(&source, 3, [&](const LiveStatus& s) { all.push_back(s); });
    source.Arrive();
    // The run throws here (a full disk): Finish is never called.
  }
  ASSERT_GE(all.size(), 2u);
  EXPECT_TRUE(all.front().running);
  EXPECT_FALSE(all.back().running);
  EXPECT_EQ(all.back().frames_received, 1);
}

}  // namespace
}  // namespace rolamos
