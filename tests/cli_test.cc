// The rolamos binary as a user runs it: each subcommand's happy path and its bad-input errors
// (clear message naming the file, non-zero exit, nothing half-written).
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/store.hpp"
#include "rolamos/tiled_image.hpp"
#include "store/writer_lock.h"
#include "util/files.h"
#include "test_support.h"

namespace rolamos {
namespace {

using test::RunCli;
using test::ScratchDir;
namespace fs = std::filesystem;

TEST(Cli, DemoInfoExport) {
  ScratchDir dir;
  const std::string store = dir / "d.rolamos";
  auto r = RunCli("demo -q --size 1500 -o " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("wrote a 1500 x 1500"), std::string::npos) << r.output;
  r = RunCli("info " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("patch 1: 1500 x 1500"), std::string::npos) << r.output;
  r = RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  auto j = nlohmann::json::parse(r.output);
  EXPECT_EQ(j["patches"][0]["levels"], 4);
  r = RunCli("export -q " + store + " --region 100,200,300,250 -o " + (dir / "r.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(cv::imread(dir / "r.png").size(), cv::Size(300, 250));
  r = RunCli("export -q " + store + " --scale 0.1 -o " + (dir / "o.jpg"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(cv::imread(dir / "o.jpg").size(), cv::Size(150, 150));
  r = RunCli("export -q " + store + " --level 2 --region 0,0,1500,1500 -o " + (dir / "l2.tif") +
             " --compression deflate");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(TiledImage::Open(dir / "l2.tif").width(), 375);
}

TEST(Cli, ConvertFromOiioAndFromGdalOnlyFormats) {
  ScratchDir dir;
  cv::Mat image = test::MakeImage(1400, 900);
  cv::imwrite(dir / "in.png", image);
  auto r = RunCli("convert -q " + (dir / "in.png") + " -o " + (dir / "a.tif") + " --compression zstd");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(cv::norm(TiledImage::Open(dir / "a.tif").ReadRegion(0, cv::Rect(0, 0, 1400, 900)),
                     image, cv::NORM_INF),
            0.0);
  if (!test::HaveCommand("gdal_translate")) GTEST_SKIP() << "gdal_translate not installed";
  // ENVI: a raster only GDAL reads; georeferenced, so the output must carry it.
  r = test::RunShell("gdal_translate -q -of ENVI -a_srs EPSG:32755 -a_ullr 500000 5200100 500140 5200010 " +
                     (dir / "in.png") + " " + (dir / "in.envi"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = RunCli("convert -q " + (dir / "in.envi") + " -o " + (dir / "b.tif") + " --compression deflate");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  TiledImage b = TiledImage::Open(dir / "b.tif");
  EXPECT_EQ(cv::norm(b.ReadRegion(0, cv::Rect(0, 0, 1400, 900)), image, cv::NORM_INF), 0.0);
  ASSERT_TRUE(b.info().georef.has_value());
  EXPECT_DOUBLE_EQ(b.info().georef->geotransform[0], 500000);
  EXPECT_NEAR(b.info().georef->geotransform[1], 0.1, 1e-9);
}

TEST(Cli, ConvertStreamsTiledTiffsOfAnyTiling) {
  if (!test::HaveCommand("gdal_translate")) GTEST_SKIP() << "gdal_translate not installed";
  ScratchDir dir;
  cv::Mat image = test::MakeImage(1700, 1100);
  cv::imwrite(dir / "in.png", image);
  struct Input {
    std::string options;
    double min_psnr;  // 0: must be exact
  };
  const std::vector<Input> inputs = {
      {"-co TILED=YES -co BLOCKXSIZE=128 -co BLOCKYSIZE=384 -co COMPRESS=ZSTD", 0},
      {"-co TILED=YES -co BLOCKXSIZE=512 -co BLOCKYSIZE=512 -co COMPRESS=JPEG -co PHOTOMETRIC=YCBCR", 36},
      {"-co TILED=NO -co COMPRESS=DEFLATE", 0},  // strips: read through the tile cache
  };
  for (const auto& in : inputs) {
    auto r = test::RunShell("gdal_translate -q " + in.options + " " + (dir / "in.png") + " " +
                            (dir / "src.tif"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = RunCli("convert -q " + (dir / "src.tif") + " -o " + (dir / "out.tif") + " --compression zstd");
    ASSERT_EQ(r.exit_code, 0) << in.options << "\n" << r.output;
    cv::Mat back = TiledImage::Open(dir / "out.tif", std::make_shared<TileCache>())
                       .ReadRegion(0, cv::Rect(0, 0, 1700, 1100));
    if (in.min_psnr == 0)
      EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0) << in.options;
    else
      EXPECT_GE(test::Psnr(back, image), in.min_psnr) << in.options;
  }
}

TEST(Cli, CogExportValidates) {
  if (test::RunShell("/usr/bin/python3 -c 'import osgeo_utils.samples.validate_cloud_optimized_geotiff'")
          .exit_code != 0)
    GTEST_SKIP() << "python3-gdal not installed";
  ScratchDir dir;
  ASSERT_EQ(RunCli("demo -q --size 1200 -o " + (dir / "d.rolamos")).exit_code, 0);
  auto r = RunCli("export -q " + (dir / "d.rolamos") + " --cog -o " + (dir / "c.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::RunShell("/usr/bin/python3 -m osgeo_utils.samples.validate_cloud_optimized_geotiff " +
                     (dir / "c.tif"));
  EXPECT_EQ(r.exit_code, 0) << r.output;
}

TEST(Cli, StepsThatChangeAStoreWaitForItsWriter) {
  // While an engine writes the store (here this test process holds its lock, as a running
  // `mosaic` does), compose (links, placements, georeference) and a COG exported into the store
  // (recorded in its manifest) are refused before any work, naming the writer; the store keeps
  // what it held.
  ScratchDir dir;
  const std::string store = dir / "d.rolamos";
  ASSERT_EQ(RunCli("demo -q --size 1200 -o " + store).exit_code, 0);
  const std::string manifest = ReadSmallFile(store + "/store.json");
  {
    const StoreWriterLock engine(Store::Open(store), "a rolamos mosaic engine");
    auto r = RunCli("compose -q " + store + "");
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("is being written by a rolamos mosaic engine (pid "), std::string::npos) << r.output;
    r = RunCli("export -q " + store + " --cog -o " + store + "/exports/map.tif");
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("is being written by a rolamos mosaic engine (pid "), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(store + "/exports/map.tif"));
    EXPECT_EQ(ReadSmallFile(store + "/store.json"), manifest);
  }
  // Once it has ended, both go in, and the export is recorded.
  auto r = RunCli("compose -q " + store + "");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = RunCli("export -q " + store + " --cog -o " + store + "/exports/map.tif");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(Store::Open(store).exports().size(), 1u);
}

struct BadCase {
  std::string args;      // {dir} is replaced
  std::string expected;  // in the message
};

TEST(Cli, BadInputGivesAClearErrorAndNonZeroExit) {
  ScratchDir dir;
  ASSERT_EQ(RunCli("demo -q --size 700 -o " + (dir / "d.rolamos")).exit_code, 0);
  std::ofstream(dir / "junk.tif") << "junk";
  fs::create_directories(dir / "plain");
  fs::copy_file(dir / "d.rolamos/patches/000001.tif", dir / "cut.tif");
  fs::resize_file(dir / "cut.tif", fs::file_size(dir / "cut.tif") / 2);
  const std::vector<BadCase> cases = {
      {"convert {dir}/missing.png -o {dir}/x.tif", "missing.png: no such file"},
      {"convert {dir}/junk.tif -o {dir}/x.tif", "junk.tif"},
      {"convert {dir}/d.rolamos/patches/000001.tif -o {dir}/x.tif --compression lzw9",
       "unknown codec \"lzw9\""},
      {"convert {dir}/d.rolamos/patches/000001.tif -o {dir}/x.tif --tile 100", "tile size 100"},
      {"info {dir}/plain", "is a directory"},
      {"info {dir}/cut.tif", "truncated"},
      {"export {dir}/d.rolamos --region 600,600,200,200 -o {dir}/x.png", "outside the image"},
      {"export {dir}/d.rolamos --region 1,2,3 -o {dir}/x.png", "four numbers"},
      {"export {dir}/d.rolamos --scale 0 -o {dir}/x.png", "scale"},
      {"export {dir}/d.rolamos --patch 7 -o {dir}/x.png", "has no patch 7"},
      {"export {dir}/d.rolamos -o {dir}/x.gif", "unknown extension"},
      {"demo -q --size 700 -o {dir}/d.rolamos", "already a store"},
      {"demo -q --size 0 -o {dir}/new.rolamos", "demo size 0"},
      {"mosaic -q {dir}/no-such-frames -o {dir}/new.rolamos", "no-such-frames: no such folder, list or video"},
      {"mosaic -q {dir}/cut.tif -o {dir}/new.rolamos", "cut.tif"},
  };
  for (const auto& c : cases) {
    std::string args = c.args;
    for (size_t p; (p = args.find("{dir}")) != std::string::npos;) args.replace(p, 5, dir.path());
    auto r = RunCli(args);
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_LT(r.exit_code, 3) << args << "\n" << r.output;  // 3 = internal error, 128+ = crash
    EXPECT_NE(r.output.find(c.expected), std::string::npos) << args << "\n" << r.output;
  }
  EXPECT_FALSE(fs::exists(dir / "x.tif"));
  EXPECT_FALSE(fs::exists(dir / "x.png"));
  // Usage errors: exit 2 and say what is missing.
  auto r = RunCli("export " + (dir / "d.rolamos"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--output"), std::string::npos) << r.output;
  EXPECT_EQ(RunCli("frobnicate").exit_code, 2);
  EXPECT_EQ(RunCli("--version").exit_code, 0);
  EXPECT_FALSE(fs::exists(dir / "new.rolamos/store.json"));
}

// The program restarts itself once with glibc's heap on huge pages (util/heap_tuning.h): seen in
// the environment of a running `mosaic --live` (same pid), the user's own tunables kept, a choice
// the user made left alone, SIGINT honoured as before.
TEST(Cli, RestartsOnceWithHugePageHeapKeepingTheUsersTunables) {
  std::ifstream mode_file("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string mode;
  std::getline(mode_file, mode);
  const bool on_request = mode.find("[madvise]") != std::string::npos;
  ScratchDir dir;
  fs::create_directories(dir / "in");
  // The environment of the run, one entry a line (glibc's parsing may have cut GLIBC_TUNABLES at
  // its colons), then its log.
  auto live_run = [&](const std::string& tunables, const std::string& name) {
    const std::string store = dir / (name + ".rolamos"), log = dir / (name + ".log");
    return test::RunShell("GLIBC_TUNABLES=" + tunables + " " + ROLAMOS_CLI + " mosaic -q " + (dir / "in") + " -o " +
                          store + " --live > " + log + " 2>&1 & pid=$!; for i in $(seq 600); do [ -e " + store +
                          "/store.json ] && break; sleep 0.05; done; tr '\\0' '\\n' < /proc/$pid/environ; "
                          "kill -INT $pid; wait $pid; cat " + log);
  };
  auto r = live_run("glibc.malloc.check=0", "added");
  EXPECT_NE(r.output.find("GLIBC_TUNABLES=glibc.malloc.check=0"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("glibc.malloc.hugetlb=1") != std::string::npos, on_request) << "THP: " << mode << r.output;
  EXPECT_NE(r.output.find("stopped by a signal"), std::string::npos) << r.output;
  r = live_run("glibc.malloc.hugetlb=0", "kept");
  EXPECT_NE(r.output.find("GLIBC_TUNABLES=glibc.malloc.hugetlb=0"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("hugetlb=1"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("stopped by a signal"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace rolamos

namespace rolamos {
namespace {

// The small survey of the workflow tests: 40 frames of 480 x 360 in two lanes.
test::CommandResult TwoLaneSurvey(const std::string& dir) {
  return test::RunCli("synth -q -o " + dir + " --frames 40 --width 480 --height 360 --focal 420 --lanes 2");
}

// The frames a run rejected are named with their reasons, not only counted: where a patch was
// written the sidecars hold them too; where none was (every frame unreadable), the summary is all
// the user gets.
TEST(Cli, MosaicNamesTheFramesItRejected) {
  ScratchDir dir;
  ASSERT_EQ(RunCli("synth -q -o " + (dir / "survey") + " --frames 12 --width 480 --height 360 --focal 420 --lanes 1")
                .exit_code, 0);
  std::ofstream(dir / "survey/frames/frame_00003.jpg") << "not a jpeg";
  auto r = RunCli("mosaic -q " + (dir / "survey/frames") + " -o " + (dir / "s.rolamos"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("rejected: frame 3 frame_00003.jpg, unreadable"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("(all in the patches' sidecars)"), std::string::npos) << r.output;
  fs::create_directories(dir / "junk");
  for (const char* name : {"/a.jpg", "/b.jpg", "/c.jpg"}) std::ofstream((dir / "junk") + name) << "not a jpeg";
  r = RunCli("mosaic -q " + (dir / "junk") + " -o " + (dir / "j.rolamos"));
  EXPECT_EQ(r.exit_code, 1) << r.output;  // nothing placed
  EXPECT_NE(r.output.find("rejected: frame 0 a.jpg, unreadable"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("frame 2 c.jpg"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("sidecar"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no frame placed"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("Look at it"), std::string::npos) << r.output;
}

// The launcher maps JPEG frames by itself: alone in a folder, without the full module beside it
// (tools/main.cc). What needs OpenCV's codecs (PNG frames, a video) or another command loads the
// module, and maps the same; without the module, such a run says what is missing.
TEST(Cli, TheLauncherMapsJpegFramesWithoutTheFullModule) {
  ScratchDir dir;
  ASSERT_EQ(RunCli("synth -q -o " + (dir / "survey") + " --frames 12 --width 480 --height 360 --focal 420 --lanes 1 "
                   "--video survey.avi --video-fps 10").exit_code, 0);
  fs::create_directories(dir / "lone");
  fs::copy_file(ROLAMOS_CLI, dir / "lone/rolamos");
  const std::string lone = dir / "lone/rolamos";
  auto jpeg = test::RunShell(lone + " mosaic -q " + (dir / "survey/frames") + " -o " + (dir / "jpeg.rolamos"));
  ASSERT_EQ(jpeg.exit_code, 0) << jpeg.output;
  EXPECT_NE(jpeg.output.find("12 frames, 12 stitched"), std::string::npos) << jpeg.output;
  // Nor does it load the libraries the module brings (the dynamic loader names what it loads).
  const auto loaded = test::RunShell("{ LD_DEBUG=files " + lone + " mosaic -q " + (dir / "survey/frames") + " -o " +
                                     (dir / "again.rolamos") + " >/dev/null; }");
  ASSERT_NE(loaded.output.find("file=libopencv_core"), std::string::npos) << loaded.output.substr(0, 2000);
  for (const char* heavy : {"file=libgdal", "file=libOpenImageIO", "file=libopencv_imgcodecs", "file=libopencv_videoio"})
    EXPECT_EQ(loaded.output.find(heavy), std::string::npos) << heavy;

  auto r = test::RunShell(lone + " info " + (dir / "jpeg.rolamos"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("lone/librolamos_full.so: cannot be loaded"), std::string::npos) << r.output;
  fs::create_directories(dir / "png");
  for (const auto& e : fs::directory_iterator(dir / "survey/frames"))
    cv::imwrite((dir / "png") + "/" + e.path().stem().string() + ".png", cv::imread(e.path().string()));
  r = test::RunShell(lone + " mosaic -q " + (dir / "png") + " -o " + (dir / "lone.rolamos"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("librolamos_full.so: cannot be loaded"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "lone.rolamos")) << "said before the store is made";

  // With the module: the PNG frames (the JPEGs' pixels) map as the JPEGs did; the video maps.
  auto png = RunCli("mosaic -q " + (dir / "png") + " -o " + (dir / "png.rolamos"));
  ASSERT_EQ(png.exit_code, 0) << png.output;
  const Store a = Store::Open(dir / "jpeg.rolamos"), b = Store::Open(dir / "png.rolamos");
  ASSERT_EQ(a.patches().size(), b.patches().size());
  for (const PatchEntry& p : a.patches()) {
    const auto fa = a.ReadSidecar(p.id).frames, fb = b.ReadSidecar(p.id).frames;
    ASSERT_EQ(fa.size(), fb.size());
    for (size_t i = 0; i < fa.size(); ++i) EXPECT_EQ(fa[i].frame_to_patch, fb[i].frame_to_patch) << p.id << " " << i;
  }
  r = RunCli("mosaic -q " + (dir / "survey/survey.avi") + " -o " + (dir / "video.rolamos"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("12 frames, 12 stitched"), std::string::npos) << r.output;
}

// Ctrl-C on a long `rolamos mosaic LIST` (a vehicle that held still over one frame for 3,000
// frames): the run ends as at the end of its input, says so, and the store holds every frame read.
// A 90-degree lens that distorts, uncalibrated: no patch fits flat ground seen through a pinhole,
// and the map drifts hundreds of pixels. The summary says so and what to do; with the lens
// calibrated (`auto`) it fits, and says nothing.
TEST(Cli, MosaicSaysWhenTheFramesFitNoPinholeCamera) {
  ScratchDir dir;
  ASSERT_EQ(RunCli("synth -q -o " + (dir / "survey") + " --width 480 --height 360 --fov 90 --k1 -0.08 --frames 40 "
                   "--lanes 1 --overlap 0.9").exit_code, 0);
  auto r = RunCli("mosaic -q " + (dir / "survey/frames") + " -o " + (dir / "raw.rolamos"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("the adjustment did not fit them (patch 1: transfer error"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("a lens that distorts? Give its calibration"), std::string::npos) << r.output;
  r = RunCli("mosaic -q " + (dir / "survey/frames") + " -o " + (dir / "auto.rolamos") + " --calibration auto");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("calibration auto: k1 = -0.2"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("did not fit"), std::string::npos) << r.output;
}

TEST(Cli, MosaicStoppedByCtrlCWritesTheOpenPatch) {
  test::ScratchDir dir;
  auto r = TwoLaneSurvey(dir / "survey");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  {
    std::ofstream list(dir / "frames.txt");
    char name[64];
    for (int i = 0; i < 40; ++i) {
      std::snprintf(name, sizeof name, "frame_%05d.jpg", i);
      for (int k = 0; k < (i == 10 ? 3000 : 1); ++k) list << (dir / "survey/frames/") << name << "\n";
    }
  }
  const std::string store = dir / "s.rolamos";
  r = test::RunShell("timeout --preserve-status -s INT 2 " + std::string(ROLAMOS_CLI) + " mosaic -q " + (dir / "frames.txt") + " -o " +
                     store + " --compression zstd 2>&1");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  const size_t at = r.output.find("stopped by a signal after ");
  ASSERT_NE(at, std::string::npos) << r.output;
  const int read = std::stoi(r.output.substr(at + std::strlen("stopped by a signal after ")));
  EXPECT_NE(r.output.find(std::to_string(read) + " frames of 3039: the open patch written"), std::string::npos)
      << r.output;
  EXPECT_GT(read, 10);
  EXPECT_LT(read, 3039);
  r = test::RunCli("info --json " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int placed = 0;
  const auto info = nlohmann::json::parse(r.output);
  for (const auto& p : info["patches"]) placed += p.value("n_images", 0);
  EXPECT_EQ(placed, read) << r.output;  // every frame read is in a patch (none is rejected here)
}

// mosaic, align, compose as a user runs them; then an align killed (kill -9) at random moments
// leaves a store that opens, with every sidecar from before or every one from after.
TEST(Cli, MosaicAlignComposeAndAnAlignKilledMidway) {
  test::ScratchDir dir;
  auto r = TwoLaneSurvey(dir / "survey");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string store = dir / "s.rolamos";
  r = test::RunCli("mosaic -q " + (dir / "survey/frames") + " -o " + store + " --patch-megapixels 0.5 --compression zstd");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const double after : {0.3, 0.8, 1.5}) {
    char cmd[512];
    std::snprintf(cmd, sizeof cmd, "timeout -s KILL %.1f %s align -q %s", after, ROLAMOS_CLI, store.c_str());
    test::RunShell(cmd);
    r = test::RunCli("info --json " + store);
    ASSERT_EQ(r.exit_code, 0) << "after a kill at " << after << " s: " << r.output;
    const auto j = nlohmann::json::parse(r.output);
    int aligned = 0, total = 0;
    for (const auto& p : j["patches"]) {
      EXPECT_FALSE(p.contains("problem")) << p.dump();
      ++total;
      aligned += p.contains("component");
    }
    EXPECT_TRUE(aligned == 0 || aligned == total) << aligned << " of " << total << " patches aligned";
  }
  r = test::RunCli("align -q " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("40 frames in 1 part"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("stages: graph "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(" MiB (reached in "), std::string::npos) << r.output;
  r = test::RunCli("compose -q " + store + " --compression zstd");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("left out"), std::string::npos) << r.output;
  r = test::RunCli("info " + store);
  EXPECT_NE(r.output.find("map: 1 part"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace rolamos

namespace rolamos {
namespace {

// Two dives (the two lanes of one survey, mosaicked into two stores) merged and aligned: one map.
TEST(Cli, MergeTwoDivesThenAlignMakesOneMap) {
  test::ScratchDir dir;
  auto r = TwoLaneSurvey(dir / "survey");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::vector<fs::path> frames;
  for (const auto& e : fs::directory_iterator(dir / "survey/frames")) frames.push_back(e.path());
  std::sort(frames.begin(), frames.end());
  ASSERT_EQ(frames.size(), 40u);
  for (size_t i = 0; i < frames.size(); ++i) {
    const fs::path d = dir / (i < 20 ? "dive1" : "dive2");
    fs::create_directories(d);
    fs::create_symlink(frames[i], d / frames[i].filename());
  }
  for (const char* dive : {"dive1", "dive2"}) {
    r = test::RunCli("mosaic -q " + (dir / dive) + " -o " + (dir / (std::string(dive) + ".rolamos")) + " --compression zstd");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  const std::string merged = dir / "all.rolamos";
  // Bad input first: a store that does not exist is named, and nothing is written.
  r = test::RunCli("merge " + (dir / "dive1.rolamos") + " " + (dir / "nowhere.rolamos") + " -o " + merged);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("nowhere.rolamos"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(merged));

  r = test::RunCli("merge -q " + (dir / "dive1.rolamos") + " " + (dir / "dive2.rolamos") + " -o " + merged);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("40 frames from 2 stores"), std::string::npos) << r.output;
  // The output exists now: a second merge into it refuses.
  r = test::RunCli("merge " + (dir / "dive1.rolamos") + " " + (dir / "dive2.rolamos") + " -o " + merged);
  EXPECT_NE(r.exit_code, 0) << r.output;

  r = test::RunCli("align -q " + merged);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("40 frames in 1 part"), std::string::npos) << r.output;
  r = test::RunCli("compose -q " + merged + " --compression zstd");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(r.output.find("left out"), std::string::npos) << r.output;
  // The inputs are untouched by the merged store's alignment.
  r = test::RunCli("info --json " + (dir / "dive1.rolamos"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto info = nlohmann::json::parse(r.output);  // kept: the loop must not walk a temporary
  for (const auto& p : info["patches"]) EXPECT_FALSE(p.contains("component")) << p.dump();
}

}  // namespace
}  // namespace rolamos
