#include "input/live_source.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// The keeping-up rule alone: which waiting frames are kept when there is no room for all.
class Rule : public LiveSource {
 public:
  bool Next(InputFrame*) override { return false; }
  using LiveSource::Keep;
  using LiveSource::SkippedBefore;
};

std::vector<int> Kept(const Rule& rule, size_t waiting, int max_waiting) {
  std::vector<int> out;
  const auto keep = rule.Keep(waiting, max_waiting);
  for (size_t i = 0; i < keep.size(); ++i)
    if (keep[i]) out.push_back(static_cast<int>(i));
  return out;
}

TEST(LiveSourceKeep, EveryFrameWhenThereIsRoom) {
  Rule rule;
  EXPECT_EQ(Kept(rule, 3, 3), (std::vector<int>{0, 1, 2}));
}

TEST(LiveSourceKeep, TheNewestWhenTheSpeedIsUnknown) {
  Rule rule;
  EXPECT_EQ(Kept(rule, 10, 3), (std::vector<int>{7, 8, 9}));
}

// At a known speed, frames that still overlap the one kept before them are kept as stepping
// stones from the last frame taken to the newest: what is skipped lies between frames kept.
TEST(LiveSourceKeep, SteppingStonesAtTheVehiclesSpeed) {
  Rule rule;
  rule.SetMaxGap(4);
  EXPECT_EQ(Kept(rule, 10, 3), (std::vector<int>{3, 7, 9}));
  rule.SetMaxGap(9);  // fast frames, slow vehicle: the newest alone spans the gap
  EXPECT_EQ(Kept(rule, 10, 3), (std::vector<int>{7, 8, 9}));
  rule.SetMaxGap(2);  // too little room to keep the thread: as far as the room goes, and the newest
  EXPECT_EQ(Kept(rule, 10, 3), (std::vector<int>{1, 3, 9}));
}

// Each frame taken says how many came between it and the frame taken before (the engine's motion
// model predicts over them); frames skipped before the first one precede nothing.
TEST(LiveSourceKeep, FramesTakenCountTheSkippedBeforeThem) {
  Rule rule;
  EXPECT_EQ(rule.SkippedBefore(3), 0);
  EXPECT_EQ(rule.SkippedBefore(4), 0);
  EXPECT_EQ(rule.SkippedBefore(7), 2);
  EXPECT_EQ(rule.SkippedBefore(8), 0);
}

// A pilot's udpsrc gets a receive buffer that outlasts a pause of the computer; one the pilot
// sized, and anything else named like it, is left as written.
TEST(LiveSourceOpen, UdpSourcesGetAReceiveBuffer) {
  EXPECT_EQ(LiveSource::WithUdpReceiveBuffer("udpsrc port=5600 ! rtpjpegdepay ! appsink", 1000),
            "udpsrc buffer-size=1000 port=5600 ! rtpjpegdepay ! appsink");
  EXPECT_EQ(LiveSource::WithUdpReceiveBuffer("udpsrc buffer-size=5 port=1 ! appsink", 1000),
            "udpsrc buffer-size=5 port=1 ! appsink");
  EXPECT_EQ(LiveSource::WithUdpReceiveBuffer("videotestsrc ! myudpsrc ! appsink name=udpsrc2", 1000),
            "videotestsrc ! myudpsrc ! appsink name=udpsrc2");
  EXPECT_EQ(LiveSource::WithUdpReceiveBuffer("udpsrc port=1 ! appsink udpsrc port=2 ! fakesink", 7),
            "udpsrc buffer-size=7 port=1 ! appsink udpsrc buffer-size=7 port=2 ! fakesink");
}

}  // namespace
}  // namespace rolamos
