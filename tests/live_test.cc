// Live mapping as a vehicle runs it: a logger writes frames into a folder at 10 frames/s while
// `rolamos mosaic --live` maps them and `rolamos serve` reports the run; SIGINT ends the run with
// the open patch written; kill -9 leaves a store that opens; a later live run continues the store.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <httplib.h>
#include <nlohmann/json.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

// Copies the survey's frames into `to` at `fps`, each written under a temporary name and renamed
// (as loggers do) or, with `in_place`, written in two halves (a frame caught half-written); named
// as in the survey, or by `name_of` (the frame's number).
void Feed(const fs::path& from, const fs::path& to, double fps, int first, int count, bool in_place = false,
          const std::function<std::string(int)>& name_of = nullptr) {
  std::vector<fs::path> frames;
  for (const auto& e : fs::directory_iterator(from)) frames.push_back(e.path());
  std::sort(frames.begin(), frames.end());
  fs::create_directories(to);
  for (int i = first; i < std::min<int>(first + count, static_cast<int>(frames.size())); ++i) {
    const fs::path target = to / (name_of ? fs::path(name_of(i)) : frames[size_t(i)].filename());
    if (in_place) {
      std::ifstream in(frames[size_t(i)], std::ios::binary);
      const std::string bytes((std::istreambuf_iterator<char>(in)), {});
      std::ofstream out(target, std::ios::binary);
      out.write(bytes.data(), static_cast<std::streamsize>(bytes.size() / 2));
      out.flush();
      std::this_thread::sleep_for(std::chrono::milliseconds(150));  // longer than one poll
      out.write(bytes.data() + bytes.size() / 2, static_cast<std::streamsize>(bytes.size() - bytes.size() / 2));
    } else {
      fs::copy_file(frames[size_t(i)], to / ".incoming");
      fs::rename(to / ".incoming", target);
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(1.0 / fps));
  }
}

nlohmann::json Status(const fs::path& store) {
  std::ifstream in(store / "live/status.json");
  return nlohmann::json::parse(in);
}

// Live settings out of range are refused with what is wrong, before the store is made.
TEST(LiveSettings, BadOnesAreRefusedAndLeaveNoStore) {
  test::ScratchDir dir;
  fs::create_directories(dir / "incoming");
  for (const std::string& bad : {std::string("--max-waiting 0"), std::string("--shed-overlap 0")}) {
    const std::string store = dir / "live.rolamos";
    auto r = test::RunCli("mosaic -q " + (dir / "incoming") + " -o " + store + " --live --idle-timeout 1 " + bad);
    EXPECT_NE(r.exit_code, 0) << bad;
    EXPECT_NE(r.output.find(bad.find("waiting") != std::string::npos ? "frames allowed to wait" : "shedding load"),
              std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(store)) << bad;
  }
}

class LiveTest : public testing::Test {
 protected:
  void SetUp() override {
    auto r = test::RunCli("synth -q -o " + (dir_ / "survey") + " --frames 40 --width 480 --height 360 --focal 420 --lanes 2");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  // `mosaic --live` over dir_/incoming into `store`, without an overlay mask, until the feed has
  // been idle for `idle_s`.
  test::CommandResult MapIncoming(const std::string& store, int idle_s) {
    return test::RunCli("mosaic -q " + (dir_ / "incoming") + " -o " + store + " --live --idle-timeout " +
                        std::to_string(idle_s) + " --mask none");
  }
  test::ScratchDir dir_;
};

TEST_F(LiveTest, AGrowingFolderIsMappedAndServedAsItArrives) {
  const std::string store = dir_ / "live.rolamos";
  std::thread logger([&] {
    Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 20);
    Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 20, 20, /*in_place=*/true);
  });
  // The viewer's server on the same store while it is written, started before its first patch.
  const int port = 18000 + static_cast<int>(::getpid() % 1000);
  std::thread server([&] {
    for (int i = 0; i < 200 && !fs::exists(fs::path(store) / "live/status.json"); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    test::RunShell(std::string(ROLAMOS_CLI) + " serve " + store + " --port " + std::to_string(port) +
                   " > " + (dir_ / "serve.log") + " 2>&1 & echo $! > " + (dir_ / "serve.pid"));
  });
  auto r = test::RunCli("mosaic -q " + (dir_ / "incoming") + " -o " + store + " --live --idle-timeout 3 --patch-megapixels 0.5 "
                        "--checkpoint-frames 15");
  logger.join();
  server.join();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("frames skipped"), std::string::npos) << r.output;
  const auto st = Status(store);
  EXPECT_EQ(st["frames_received"], 40) << st.dump();  // every frame, the half-written ones once complete
  EXPECT_EQ(st["frames_registered"].get<int>() + st["frames_rejected"].get<int>() + st["frames_skipped"].get<int>(), 40)
      << st.dump();
  EXPECT_GE(st["frames_registered"].get<int>(), 30) << st.dump();
  EXPECT_FALSE(st["running"].get<bool>());
  EXPECT_GE(st["patches"].get<int>(), 3) << "checkpoints every 15 frames: " << st.dump();
  EXPECT_LE(st["backlog_max"].get<int>(), st["backlog_bound"].get<int>()) << st.dump();
  EXPECT_LE(st["coverage_lost"].get<int>(), st["frames_skipped"].get<int>()) << st.dump();
  for (const char* key : {"frames_received", "frames_registered", "frames_rejected", "frames_skipped", "patches",
                          "open_patch", "last_frame_time", "latency_ms_p50", "latency_ms_p95", "coverage_lost",
                          "backlog_max", "backlog_bound"})
    EXPECT_TRUE(st.contains(key)) << key;
  // The server, started before the first patch existed, serves what the run wrote.
  httplib::Client http("127.0.0.1", port);
  std::string body;
  for (int i = 0; i < 50 && body.empty(); ++i) {
    if (auto res = http.Get("/api/status")) body = res->body;
    else std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_FALSE(body.empty()) << test::RunShell("cat " + (dir_ / "serve.log")).output;
  EXPECT_EQ(nlohmann::json::parse(body)["frames_received"], 40) << body;
  std::this_thread::sleep_for(std::chrono::milliseconds(600));  // the server refreshes twice a second
  auto images = http.Get("/api/images");
  ASSERT_TRUE(images);
  EXPECT_EQ(nlohmann::json::parse(images->body).size(), st["patches"].get<size_t>()) << images->body;
  test::RunShell("kill $(cat " + (dir_ / "serve.pid") + ")");
}

TEST_F(LiveTest, SigintWritesTheOpenPatchAndKillLeavesAStoreThatOpens) {
  const std::string store = dir_ / "s.rolamos";
  std::thread logger([&] { Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 25); });
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic -q " + (dir_ / "incoming") + " -o " + store +
                 " --live --patch-megapixels 4 > " + (dir_ / "run.log") + " 2>&1 & echo $! > " + (dir_ / "run.pid"));
  logger.join();
  std::this_thread::sleep_for(std::chrono::seconds(2));
  test::RunShell("kill -INT $(cat " + (dir_ / "run.pid") + ")");
  for (int i = 0; i < 100 && test::RunShell("kill -0 $(cat " + (dir_ / "run.pid") + ") 2>/dev/null").exit_code == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const std::string log = test::RunShell("cat " + (dir_ / "run.log")).output;
  EXPECT_NE(log.find("stopped by a signal"), std::string::npos) << log;
  auto r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int frames = 0;
  const auto info = nlohmann::json::parse(r.output);
  for (const auto& p : info["patches"]) frames += p.value("n_images", 0);
  EXPECT_EQ(frames + Status(store)["frames_rejected"].get<int>() + Status(store)["frames_skipped"].get<int>(), 25)
      << Status(store).dump() << "\n" << log;

  // A second run continues the store; kill -9 mid-run leaves it readable with the first run's patches.
  std::thread more([&] { Feed(dir_ / "survey/frames", dir_ / "incoming2", 10, 25, 15); });
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic -q " + (dir_ / "incoming2") + " -o " + store +
                 " --live --checkpoint-frames 5 > /dev/null 2>&1 & echo $! > " + (dir_ / "run2.pid"));
  more.join();
  test::RunShell("kill -9 $(cat " + (dir_ / "run2.pid") + ")");
  r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int after = 0;
  const auto info2 = nlohmann::json::parse(r.output);
  for (const auto& p : info2["patches"]) {
    EXPECT_FALSE(p.contains("problem")) << p.dump();
    after += p.value("n_images", 0);
  }
  EXPECT_GE(after, frames) << "the first run's patches are still there";
}

// One process maps and serves: while frames arrive, /api/live places the open patch's preview and
// the patches it continues in one frame, with a track that runs on without a jump from patch to
// patch; the preview is served as an image like any other, and is gone once the run ends.
TEST_F(LiveTest, MosaicLiveServesTheOpenPatchAndThePatchesBeneathIt) {
  const std::string store = dir_ / "served.rolamos";
  const int port = 19000 + static_cast<int>(::getpid() % 1000);
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic -q " + (dir_ / "incoming") + " -o " + store +
                 " --live --serve " + std::to_string(port) + " --patch-megapixels 0.4 --preview-interval 0.5 > " +
                 (dir_ / "run.log") + " 2>&1 & echo $! > " + (dir_ / "run.pid"));
  std::thread logger([&] { Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 34); });
  httplib::Client http("127.0.0.1", port);
  nlohmann::json view;
  std::string images, tile_type;
  int tile_status = 0;
  // Sampled while the logger writes; the last sample with closed patches beneath is kept.
  for (int i = 0; i < 60; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    auto res = http.Get("/api/live");
    if (!res || res->status != 200) continue;
    auto v = nlohmann::json::parse(res->body);
    if (v["preview"].is_null() || v["patches"].empty()) continue;
    view = v;
    if (auto im = http.Get("/api/images")) images = im->body;
    if (auto t = http.Get("/dzi/live_files/0/0_0.webp")) {
      tile_status = t->status;
      tile_type = t->get_header_value("Content-Type");
    }
  }
  logger.join();
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  test::RunShell("kill -INT $(cat " + (dir_ / "run.pid") + ")");
  while (test::RunShell("kill -0 $(cat " + (dir_ / "run.pid") + ") 2>/dev/null").exit_code == 0)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const std::string log = test::RunShell("cat " + (dir_ / "run.log")).output;
  ASSERT_FALSE(view.is_null()) << "no live view with closed patches beneath it was served\n" << log;
  EXPECT_GT(view["patch"].get<int>(), view["patches"][0]["patch"].get<int>()) << view.dump();
  EXPECT_EQ(view["footprint"].size(), 4u);
  EXPECT_EQ(tile_status, 200);
  EXPECT_EQ(tile_type, "image/webp");
  bool listed = false;
  for (const auto& i : nlohmann::json::parse(images)) listed |= i["name"] == "live" && i.value("changing", false);
  EXPECT_TRUE(listed) << images;
  // The track through closed patches and the open one: steps alike, no jump where patches meet.
  const auto& track = view["track"];
  ASSERT_GE(track.size(), 10u) << view.dump();
  std::vector<double> steps;
  for (size_t k = 1; k < track.size(); ++k)
    steps.push_back(std::hypot(track[k][0].get<double>() - track[k - 1][0].get<double>(),
                               track[k][1].get<double>() - track[k - 1][1].get<double>()));
  std::vector<double> sorted = steps;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted[sorted.size() / 2];
  for (size_t k = 0; k < steps.size(); ++k)
    EXPECT_LT(steps[k], 3 * median + 5) << "a jump in the track at point " << k + 1 << ": " << view["track"].dump();
  // The current frame lies at the track's end (its corners' mean is not its centre's image under
  // perspective: a few pixels).
  double cx = 0, cy = 0;
  for (const auto& p : view["footprint"]) cx += p[0].get<double>() / 4, cy += p[1].get<double>() / 4;
  EXPECT_LT(std::hypot(cx - track.back()[0].get<double>(), cy - track.back()[1].get<double>()), 10.0);
  // The run over: nothing is open, and the store serves as any other.
  std::ifstream in(fs::path(store) / "live/preview.json");
  EXPECT_EQ(nlohmann::json::parse(in)["patch"], 0);
  EXPECT_NE(log.find("viewer on http://"), std::string::npos) << log;
  auto r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
}

// A feed that pauses: the preview's image catches up with the last frame once no frame has come
// for the preview interval, so the page does not follow the vehicle beyond the seafloor it shows.
// (CI caught the viewer's live page looking at an empty canvas after the feed's last frames.)
TEST_F(LiveTest, APausedFeedIsPreviewedUpToItsLastFrame) {
  const std::string store = dir_ / "paused.rolamos";
  fs::create_directories(dir_ / "incoming");
  // An interval longer than the feed: only the patch's first frame would be imaged without the
  // idle refresh.
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic -q " + (dir_ / "incoming") + " -o " + store +
                 " --live --mask none --preview-interval 3 > " + (dir_ / "run.log") + " 2>&1 & echo $! > " + (dir_ / "run.pid"));
  Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 12);
  nlohmann::json preview = nlohmann::json::object();
  for (int i = 0; i < 150; ++i) {  // up to 15 s: the interval, the engine's backlog and a write
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    std::ifstream in(fs::path(store) / "live/preview.json");
    if (!in) continue;
    try {
      const auto read = nlohmann::json::parse(in);
      if (read.is_object()) preview = read;
    } catch (const nlohmann::json::exception&) {
      continue;
    }
    if (preview.value("frames", 0) == 12 && preview.value("image_frames", 0) == 12) break;
  }
  test::RunShell("kill -INT $(cat " + (dir_ / "run.pid") + ")");
  while (test::RunShell("kill -0 $(cat " + (dir_ / "run.pid") + ") 2>/dev/null").exit_code == 0)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const std::string log = test::RunShell("cat " + (dir_ / "run.log")).output;
  EXPECT_EQ(preview.value("frames", 0), 12) << preview.dump() << "\n" << log;
  EXPECT_EQ(preview.value("image_frames", 0), 12) << "the image shows fewer frames than the patch holds\n"
                                                  << preview.dump() << "\n" << log;
}

// Navigation that arrives with the frames (a CSV the vehicle appends to, as compose --navigation
// reads it, with a line that does not parse) georeferences the live view: the current frame's
// centre lands where the navigation puts it; the bad line is named in a warning and the run goes on.
TEST_F(LiveTest, AGrowingNavigationCsvGeoreferencesTheLiveView) {
  // The survey's truth: texture pixel (X, Y) is (500000 + 0.01 X, 5200000 - 0.01 Y) in EPSG:32755.
  std::ifstream truth_in(dir_ / "survey/ground_truth.json");
  const auto truth = nlohmann::json::parse(truth_in);
  const double w = truth["frame_size"][0].get<double>(), h = truth["frame_size"][1].get<double>();
  auto centre_on_map = [&](const nlohmann::json& f) {
    cv::Matx33d H;
    for (int k = 0; k < 9; ++k) H.val[k] = f["frame_to_world"][size_t(k)].get<double>();
    auto world = [&](double x, double y) {
      const cv::Vec3d v = H * cv::Vec3d(x, y, 1);
      return cv::Point2d(500000 + 0.01 * v[0] / v[2], 5200000 - 0.01 * v[1] / v[2]);
    };
    const double cx = (w - 1) / 2, cy = (h - 1) / 2;
    const cv::Point2d c = world(cx, cy), up = world(cx, cy - 1), right = world(cx + 1, cy);
    return std::make_tuple(c, std::atan2(up.x - c.x, up.y - c.y) * 180 / CV_PI, cv::norm(right - c));
  };
  const std::string store = dir_ / "nav.rolamos", csv = dir_ / "nav.csv";
  {
    std::ofstream out(csv);
    out << "frame,easting,northing,epsg,altitude,heading\n";
  }
  const int port = 20000 + static_cast<int>(::getpid() % 1000);
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic -q " + (dir_ / "incoming") + " -o " + store + " --live --serve " +
                 std::to_string(port) + " --navigation " + csv + " --focal 420 --preview-interval 0.5 > " +
                 (dir_ / "run.log") + " 2>&1 & echo $! > " + (dir_ / "run.pid"));
  std::vector<fs::path> frames;
  for (const auto& e : fs::directory_iterator(dir_ / "survey/frames")) frames.push_back(e.path());
  std::sort(frames.begin(), frames.end());
  fs::create_directories(dir_ / "incoming");
  httplib::Client http("127.0.0.1", port);
  nlohmann::json view;
  for (size_t i = 0; i < 25; ++i) {
    fs::copy_file(frames[i], dir_ / "incoming/.incoming");
    fs::rename(dir_ / "incoming/.incoming", dir_ / "incoming" / frames[i].filename());
    const auto [c, heading, gsd] = centre_on_map(truth["frames"][i]);
    std::ofstream out(csv, std::ios::app);
    out.precision(12);
    out << frames[i].filename().string() << "," << c.x << "," << c.y << ",32755," << gsd * 420 << "," << heading << "\n";
    if (i == 6) out << "frame_bad.jpg,500000,not-a-number,32755,4,0\n";
    out.close();
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  // The last frames reach the view (held at first for the overlay search; a loaded machine is slow).
  for (int k = 0; k < 300; ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (auto res = http.Get("/api/live")) {
      auto v = nlohmann::json::parse(res->body);
      if (v.contains("georef") && !v["georef"].is_null() && v.contains("last_frame") &&
          v["last_frame"]["source"].get<std::string>().find(frames[24].filename().string()) != std::string::npos) {
        view = v;
        break;
      }
    }
  }
  test::RunShell("kill -INT $(cat " + (dir_ / "run.pid") + ")");
  while (test::RunShell("kill -0 $(cat " + (dir_ / "run.pid") + ") 2>/dev/null").exit_code == 0)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const std::string log = test::RunShell("cat " + (dir_ / "run.log")).output;
  ASSERT_FALSE(view.is_null()) << "no georeferenced live view with the last frame\n" << log << Status(store).dump();
  const auto& g = view["georef"];
  EXPECT_EQ(g["crs"], "EPSG:32755");
  EXPECT_GE(g["frames"].get<int>(), 10);
  EXPECT_LT(g["residual_median_m"].get<double>(), 0.05) << g.dump();  // 5 frame pixels
  EXPECT_EQ(view["navigation"]["lines_skipped"], 1) << view.dump();
  // The current frame's centre through the view's georeference, against the navigation.
  double cx = 0, cy = 0;
  for (const auto& p : view["footprint"]) cx += p[0].get<double>() / 4, cy += p[1].get<double>() / 4;
  const auto& t = g["geotransform"];
  const double e = t[0].get<double>() + cx * t[1].get<double>() + cy * t[2].get<double>();
  const double n = t[3].get<double>() + cx * t[4].get<double>() + cy * t[5].get<double>();
  const auto [c, heading, gsd] = centre_on_map(truth["frames"][24]);
  EXPECT_LT(std::hypot(e - c.x, n - c.y), 0.1) << "metres off the navigation: " << e << " " << n;
  EXPECT_NE(log.find("warning: navigation " + csv + ":9"), std::string::npos) << "the bad line, named:\n" << log;
}

// --mask auto in live mode finds the burned-in overlay from the first frames, as the folder mode
// does, writes it into the store, and maps every frame (those it waited for too).
TEST_F(LiveTest, MaskAutoFindsTheOverlayFromTheFirstLiveFrames) {
  auto r = test::RunCli("synth -q -o " + (dir_ / "tv") + " --frames 36 --width 480 --height 360 --focal 420 --overlay");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string store = dir_ / "mask.rolamos";
  std::thread logger([&] { Feed(dir_ / "tv/frames", dir_ / "incoming", 20, 0, 36); });
  r = test::RunCli("mosaic " + (dir_ / "incoming") + " -o " + store + " --live --idle-timeout 3 --mask auto");
  logger.join();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(fs::path(store) / "static_mask.png")) << r.output;
  EXPECT_NE(r.output.find("of the live run"), std::string::npos) << r.output;
  const cv::Mat mask = cv::imread(store + "/static_mask.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(mask.empty());
  const double fraction = cv::countNonZero(mask) / double(mask.total());
  EXPECT_GT(fraction, 0.001);
  EXPECT_LT(fraction, 0.15);
  const auto st = Status(store);
  EXPECT_EQ(st["frames_received"], 36) << st.dump();
  EXPECT_EQ(st["frames_registered"].get<int>() + st["frames_rejected"].get<int>() + st["frames_skipped"].get<int>(), 36);
  EXPECT_GE(st["frames_registered"].get<int>(), 30) << st.dump();
}

// An ROV's live feed starts with its descent: open water that holds nothing but the burned-in
// overlay, which the first frames cannot tell from a seafloor that does not move. The search goes
// on over the frames as they come, a window ahead of the mapping, and the seafloor is mapped with
// the overlay left out. (Before, a live run gave up after its first frames: on the spread's
// overlay survey after 40 frames of water, patches were drawn 290 px RMS off.)
TEST_F(LiveTest, MaskAutoLooksPastADescent) {
  std::vector<fs::path> seafloor;
  for (const auto& e : fs::directory_iterator(dir_ / "survey/frames")) seafloor.push_back(e.path());
  std::sort(seafloor.begin(), seafloor.end());
  const int water = 40;
  const fs::path dive = dir_ / "dive";
  fs::create_directories(dive);
  for (int i = 0; i < water + static_cast<int>(seafloor.size()); ++i) {
    cv::Mat frame = i < water ? cv::Mat(360, 480, CV_8UC3, cv::Scalar(120, 100, 40)) : cv::imread(seafloor[size_t(i - water)]);
    cv::circle(frame, {240, 180}, 12, cv::Scalar(255, 255, 255), cv::FILLED);
    cv::rectangle(frame, {10, 10}, {150, 32}, cv::Scalar(255, 255, 255), cv::FILLED);
    cv::putText(frame, "12:00:00", {16, 28}, cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 2);
    char name[32];
    std::snprintf(name, sizeof name, "d%03d.png", i);
    ASSERT_TRUE(cv::imwrite((dive / name).string(), frame));
  }
  const int total = water + static_cast<int>(seafloor.size());
  const std::string store = dir_ / "dive.rolamos";
  std::thread logger([&] { Feed(dive, dir_ / "incoming", 20, 0, total); });
  auto r = test::RunCli("mosaic " + (dir_ / "incoming") + " -o " + store + " --live --idle-timeout 3 --mask auto");
  logger.join();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("the first 24 could not tell"), std::string::npos) << r.output;
  const cv::Mat mask = cv::imread(store + "/static_mask.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(mask.empty()) << r.output;
  EXPECT_GT(mask.at<uchar>(180, 240), 0);
  EXPECT_GT(mask.at<uchar>(20, 80), 0);
  EXPECT_EQ(mask.at<uchar>(300, 400), 0);
  const auto st = Status(store);
  EXPECT_EQ(st["frames_received"], total) << st.dump();
  EXPECT_EQ(st["frames_skipped"], 0) << st.dump();  // the frames read ahead were mapped, none skipped
  // Each seafloor frame placed against the one before it in its patch as the survey flew them.
  std::ifstream truth_in(dir_ / "survey/ground_truth.json");
  const auto truth = nlohmann::json::parse(truth_in);
  auto matrix = [](const nlohmann::json& m) {
    cv::Matx33d H;
    for (int k = 0; k < 9; ++k) H.val[k] = m[size_t(k)].get<double>();
    return H;
  };
  const std::vector<cv::Point2d> corners{{0, 0}, {479, 0}, {479, 359}, {0, 359}};
  int placed = 0, pairs = 0;
  double worst = 0;
  for (const auto& e : fs::directory_iterator(fs::path(store) / "patches")) {
    if (e.path().extension() != ".json" || e.path().string().find(".links") != std::string::npos) continue;
    std::ifstream in(e.path());
    const auto sidecar = nlohmann::json::parse(in);
    int last = -1, open_water = 0;
    cv::Matx33d last_patch;
    for (const auto& f : sidecar["frames"]) {
      const int k = std::stoi(fs::path(f["source"].get<std::string>()).stem().string().substr(1)) - water;
      if (k < 0) {  // open water, with nothing but the mark: never chained to the seafloor by it
        ++open_water;
        continue;
      }
      EXPECT_EQ(open_water, 0) << e.path() << " holds open water and the seafloor\n" << r.output;
      ++placed;
      const cv::Matx33d patch = matrix(f["frame_to_patch"]);
      if (last >= 0) {
        const cv::Matx33d mapped = last_patch.inv() * patch;
        const cv::Matx33d flown = matrix(truth["frames"][size_t(last)]["frame_to_world"]).inv() *
                                  matrix(truth["frames"][size_t(k)]["frame_to_world"]);
        for (const cv::Point2d& c : corners) {
          const cv::Vec3d a = mapped * cv::Vec3d(c.x, c.y, 1), b = flown * cv::Vec3d(c.x, c.y, 1);
          worst = std::max(worst, std::hypot(a[0] / a[2] - b[0] / b[2], a[1] / a[2] - b[1] / b[2]));
        }
        ++pairs;
      }
      last = k;
      last_patch = patch;
    }
  }
  EXPECT_EQ(placed, static_cast<int>(seafloor.size())) << r.output;
  EXPECT_GE(pairs, static_cast<int>(seafloor.size()) - 6) << r.output;
  EXPECT_LT(worst, 3.0) << "px between consecutive frames, against the survey's own\n" << r.output;
}

// The disk fills during a live run (the store on a 700 KiB tmpfs, in a mount namespace of the
// run's own): the status stops being written with a warning, the run ends with a message that
// says the disk is full and what the store holds, and the store opens with every patch written
// before. Skipped where a private tmpfs cannot be mounted (not root).
TEST_F(LiveTest, ADiskThatFillsLeavesAStoreThatOpensAndSaysSo) {
  if (test::RunShell("unshare -m sh -c 'mount -t tmpfs -o size=64k tmpfs /mnt' 2>/dev/null").exit_code != 0)
    GTEST_SKIP() << "cannot mount a private tmpfs here (needs root and unshare)";
  const fs::path small = dir_ / "small";
  fs::create_directories(small);
  std::thread logger([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
    Feed(dir_ / "survey/frames", dir_ / "incoming", 20, 0, 40);
  });
  const std::string store = (small / "d.rolamos").string();
  const std::string script =
      "mount -t tmpfs -o size=700k tmpfs " + small.string() + " && " + std::string(ROLAMOS_CLI) + " mosaic " +
      (dir_ / "incoming") + " -o " + store + " --live --idle-timeout 3 --mask none --checkpoint-frames 8; echo exit=$?; " +
      ROLAMOS_CLI + " info --json " + store + " > " + (dir_ / "info.json") + "; echo info=$?";
  std::ofstream(dir_ / "full.sh") << script;
  fs::create_directories(dir_ / "incoming");
  const auto r = test::RunShell("unshare -m sh " + (dir_ / "full.sh") + " 2>&1");
  logger.join();
  EXPECT_NE(r.output.find("exit=1"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("the disk is full"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("the store holds the"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("info=0"), std::string::npos) << "the store opens:\n" << r.output;
  std::ifstream in(dir_ / "info.json");
  const auto info = nlohmann::json::parse(in);
  EXPECT_GE(info["patches"].size(), 1u) << info.dump();
  for (const auto& p : info["patches"]) EXPECT_FALSE(p.contains("problem")) << p.dump();
}

// A file cut short in the watched folder (its writer died) is not waited for for ever: it is taken
// as it is, counted as incomplete, and the frame is accounted for with the others.
TEST_F(LiveTest, AFileCutShortIsTakenAndCounted) {
  const std::string store = dir_ / "cut.rolamos";
  std::thread logger([&] {
    Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 10);
    std::ifstream in(dir_ / "survey/frames/frame_00010.jpg", std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), {});
    std::ofstream(dir_ / "incoming/frame_00010.jpg", std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size() / 3));
    std::this_thread::sleep_for(std::chrono::seconds(4));  // the writer is gone; no later frame
  });
  auto r = MapIncoming(store, 6);
  logger.join();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto st = Status(store);
  EXPECT_EQ(st["frames_received"], 11) << st.dump();
  EXPECT_EQ(st["frames_incomplete"], 1) << st.dump();
  EXPECT_EQ(st["frames_registered"].get<int>() + st["frames_rejected"].get<int>() + st["frames_skipped"].get<int>(), 11)
      << st.dump();
}

// A logger numbering its frames without leading zeros (frame9.jpg, then frame10.jpg): by name,
// every frame from frame10 to frame89 sorted before frame9 and was dropped as a late arrival (9
// of 40 frames mapped). In the camera's order, none is.
TEST_F(LiveTest, FramesNumberedWithoutLeadingZerosAreTakenInTheirOrder) {
  const std::string store = dir_ / "unpadded.rolamos";
  std::thread logger([&] {
    Feed(dir_ / "survey/frames", dir_ / "incoming", 10, 0, 25, false,
         [](int i) { return "frame" + std::to_string(i + 1) + ".jpg"; });
  });
  auto r = MapIncoming(store, 3);
  logger.join();
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto st = Status(store);
  EXPECT_EQ(st["frames_received"], 25) << st.dump();
  EXPECT_EQ(st["frames_skipped"], 0) << st.dump();
  EXPECT_EQ(st["frames_registered"], 25) << st.dump();
}

// Frames arrive far faster than the engine takes them (large frames, 100 a second, without end):
// the signal is still honoured while they pour in, and the open patch is written.
TEST_F(LiveTest, SigintIsHonouredWhileFramesArriveFasterThanTheEngineTakesThem) {
  auto r = test::RunCli("synth -q -o " + (dir_ / "big") + " --frames 40 --width 1292 --height 964 --overlap 0.9");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::vector<fs::path> frames;
  for (const auto& e : fs::directory_iterator(dir_ / "big/frames")) frames.push_back(e.path());
  std::sort(frames.begin(), frames.end());
  const std::string store = dir_ / "fast.rolamos";
  const fs::path incoming = dir_ / "incoming";
  fs::create_directories(incoming);
  test::RunShell(std::string(ROLAMOS_CLI) + " mosaic " + incoming.string() + " -o " + store +
                 " --live > " + (dir_ / "run.log") + " 2>&1 & echo $! > " + (dir_ / "run.pid"));
  std::atomic<bool> stop_feed{false};
  std::atomic<int> fed{0};
  std::thread logger([&] {  // the survey over and over, under new names, until told to stop
    for (int i = 0; !stop_feed && i < 100000; ++i) {
      char name[32];
      std::snprintf(name, sizeof name, "f%06d.jpg", i);
      fs::copy_file(frames[size_t(i) % frames.size()], incoming / ".incoming");
      fs::rename(incoming / ".incoming", incoming / name);
      ++fed;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  });
  auto running = [&] { return test::RunShell("kill -0 $(cat " + (dir_ / "run.pid") + ") 2>/dev/null").exit_code == 0; };
  for (int i = 0; i < 500 && !fs::exists(fs::path(store) / "live/status.json"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // the engine falls behind the feed
  const int fed_at_signal = fed;
  test::RunShell("kill -INT $(cat " + (dir_ / "run.pid") + ")");
  // Frames keep arriving; the run must end anyway (a hang is caught after 2 minutes, not timed).
  for (int i = 0; i < 6000 && running(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  const bool ended = !running();
  if (!ended) test::RunShell("kill -9 $(cat " + (dir_ / "run.pid") + ")");
  stop_feed = true;
  logger.join();
  ASSERT_TRUE(ended) << "the run did not end while frames kept arriving";
  const std::string log = test::RunShell("cat " + (dir_ / "run.log")).output;
  EXPECT_NE(log.find("stopped by a signal"), std::string::npos) << log;
  const auto st = Status(store);
  EXPECT_GT(st["frames_skipped"].get<int>(), 0) << "the feed outran the engine: " << st.dump();
  EXPECT_LE(st["frames_received"].get<int>(), fed_at_signal + 100) << "frames taken after the signal: " << st.dump();
  EXPECT_LE(st["backlog_max"].get<int>(), st["backlog_bound"].get<int>()) << st.dump();
  r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int placed = 0;
  const auto info = nlohmann::json::parse(r.output);
  for (const auto& p : info["patches"]) placed += p.value("n_images", 0);
  EXPECT_GT(placed, 0) << "the open patch was written";
  // Every frame received is accounted for: mapped into a patch, rejected, or skipped and said so.
  EXPECT_EQ(placed + st["frames_rejected"].get<int>() + st["frames_skipped"].get<int>(),
            st["frames_received"].get<int>()) << st.dump() << "\n" << log;
}

}  // namespace
}  // namespace rolamos
