// Live mapping from a real network stream: gst-launch-1.0 sends a synthetic survey's frames as
// RTP/MJPEG over UDP on the loopback at the camera's rate, and `rolamos mosaic PIPELINE --live`
// receives them through OpenCV's GStreamer back end. The stream stalls and comes back while the
// receiving computer pauses once; then it stalls for good and SIGINT still ends the run (the
// reader blocked in the stalled read is left behind). Skipped when GStreamer's tools or plugins are not installed (scripts/setup.sh installs
// them).
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <thread>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

bool HaveGStreamer() {
  return test::RunShell("gst-inspect-1.0 rtpjpegpay >/dev/null 2>&1 && gst-inspect-1.0 avidemux >/dev/null 2>&1 && "
                        "gst-inspect-1.0 udpsrc >/dev/null 2>&1 && gst-inspect-1.0 jpegenc >/dev/null 2>&1")
             .exit_code == 0;
}

TEST(LiveStream, RtpMjpegOverUdpIsMappedThroughAStallAndStopsWhileStalled) {
  if (!HaveGStreamer()) GTEST_SKIP() << "gst-launch-1.0 and the good/base plugins are not installed";
  test::ScratchDir dir;
  auto r = test::RunCli("synth -q -o " + (dir / "survey") +
                        " --frames 40 --width 480 --height 360 --focal 420 --lanes 2 --video survey.avi --video-fps 10");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const int port = 21000 + static_cast<int>(::getpid() % 1000);
  const std::string store = dir / "stream.rolamos";
  // The receiver, as a pilot would write it: RTP/JPEG depayloaded, decoded, BGR into appsink.
  const std::string pipeline = "udpsrc port=" + std::to_string(port) +
                               " caps=\"application/x-rtp,media=video,encoding-name=JPEG,payload=26,clock-rate=90000\""
                               " ! rtpjpegdepay ! jpegdec ! videoconvert ! video/x-raw,format=BGR ! appsink sync=false";
  std::ofstream(dir / "pipeline.txt") << pipeline;
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic \"$(cat " + (dir / "pipeline.txt") + ")\" -o " + store +
                 " --live --mask none --idle-timeout 30 > " + (dir / "run.log") + " 2>&1 & echo $! > " + (dir / "run.pid"));
  auto running = [&] { return test::RunShell("kill -0 $(cat " + (dir / "run.pid") + ") 2>/dev/null").exit_code == 0; };
  auto status = [&] {
    std::ifstream in(fs::path(store) / "live/status.json");
    return in ? nlohmann::json::parse(in, nullptr, false) : nlohmann::json();
  };
  // The receiver listens before the camera sends (UDP keeps nothing for a late listener).
  for (int i = 0; i < 100 && !fs::exists(fs::path(store) / "live/status.json"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  std::this_thread::sleep_for(std::chrono::seconds(1));
  // The camera: the survey's video paced by its timestamps (10 frames/s), re-encoded as the
  // baseline JPEG that RTP carries (RFC 2435).
  const std::string send = "gst-launch-1.0 -q filesrc location=" + (dir / "survey/survey.avi") +
                           " ! avidemux ! jpegdec ! videoconvert ! jpegenc quality=92 ! rtpjpegpay ! udpsink host=127.0.0.1 port=" +
                           std::to_string(port);
  ASSERT_EQ(test::RunShell(send).exit_code, 0);
  std::this_thread::sleep_for(std::chrono::seconds(3));  // the stream stalls
  const auto before = status();
  // It comes back (the survey again), and halfway through the computer pauses for 1.2 s (a loaded
  // host): the datagrams wait in the receive buffer the engine gives udpsrc, none is lost. Where
  // the kernel grants less than that buffer (net.core.rmem_max), nothing can keep them: no pause.
  long rmem_max = 0;
  std::ifstream("/proc/sys/net/core/rmem_max") >> rmem_max;
  if (rmem_max >= 4 << 20) {
    const std::string pid = "$(cat " + (dir / "run.pid") + ")";
    test::RunShell("(sleep 1.5; kill -STOP " + pid + "; sleep 1.2; kill -CONT " + pid + ") >/dev/null 2>&1 &");
  } else {
    std::printf("net.core.rmem_max is %ld bytes, less than the 4 MiB receive buffer: the receiver is not paused\n",
                rmem_max);
  }
  ASSERT_EQ(test::RunShell(send).exit_code, 0);
  std::this_thread::sleep_for(std::chrono::seconds(2));
  const auto after = status();
  // Stalled for good: SIGINT ends the run anyway (a hang is caught after a minute, not timed).
  ASSERT_TRUE(running()) << test::RunShell("cat " + (dir / "run.log")).output;
  test::RunShell("kill -INT $(cat " + (dir / "run.pid") + ")");
  for (int i = 0; i < 600 && running(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const bool ended = !running();
  if (!ended) test::RunShell("kill -9 $(cat " + (dir / "run.pid") + ")");
  const std::string log = test::RunShell("cat " + (dir / "run.log")).output;
  ASSERT_TRUE(ended) << "SIGINT during a stall did not end the run\n" << log;
  EXPECT_NE(log.find("stopped by a signal, the open patch written"), std::string::npos) << log;
  ASSERT_TRUE(before.is_object() && after.is_object()) << log;
  EXPECT_GE(before["frames_received"].get<int>(), 36) << before.dump();
  EXPECT_GE(after["frames_received"].get<int>() - before["frames_received"].get<int>(), 36)
      << "frames after the stall: " << after.dump();
  const auto st = status();
  // Many frames are mapped: on a loaded machine some are skipped to keep up, and said so, and
  // the twelve that arrive at once after the pause are thinned to the backlog bound by design
  // (CI, beside other tests: 41 of 80 mapped; here beside two busy loops: 33).
  EXPECT_GE(st["frames_registered"].get<int>(), 30) << st.dump();
  EXPECT_EQ(st["frames_registered"].get<int>() + st["frames_rejected"].get<int>() + st["frames_skipped"].get<int>(),
            st["frames_received"].get<int>()) << st.dump();
  EXPECT_LE(st["backlog_max"].get<int>(), st["backlog_bound"].get<int>()) << st.dump();
  EXPECT_FALSE(st["running"].get<bool>());
  r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto info = nlohmann::json::parse(r.output);
  int placed = 0;
  for (const auto& p : info["patches"]) placed += p.value("n_images", 0);
  EXPECT_EQ(placed, st["frames_registered"].get<int>()) << st.dump();
  // Each frame named by its number in the stream (where it is in the recording), skipped frames
  // counted: distinct, within what arrived, and past the frames mapped where some were skipped.
  std::set<int> numbers;
  for (const auto& e : fs::directory_iterator(fs::path(store) / "patches")) {
    if (e.path().extension() != ".json" || e.path().string().find(".links") != std::string::npos) continue;
    std::ifstream in(e.path());
    const auto sidecar = nlohmann::json::parse(in);
    for (const char* list : {"frames", "rejected"})
      for (const auto& f : sidecar[list]) {
        const std::string source = f["source"].get<std::string>();
        ASSERT_NE(source.rfind('#'), std::string::npos) << source;
        EXPECT_TRUE(numbers.insert(std::stoi(source.substr(source.rfind('#') + 1))).second) << source;
      }
  }
  const int mapped = st["frames_registered"].get<int>() + st["frames_rejected"].get<int>();
  EXPECT_EQ(static_cast<int>(numbers.size()), mapped);
  ASSERT_FALSE(numbers.empty());
  EXPECT_LT(*numbers.rbegin(), st["frames_received"].get<int>());
  if (st["frames_skipped"].get<int>() > 0) EXPECT_GT(*numbers.rbegin(), mapped - 1) << st.dump();
}

}  // namespace
}  // namespace rolamos
