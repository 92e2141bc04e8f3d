// The floor under the online engine on this machine (issue 27): what one frame costs before any
// mosaicking (decode, undistort, the tracking pyramid), and what each of the engine's building
// blocks costs on the same frames, one core, medians over the frames given.
//
//   engine_floor_bench FRAMES_DIR|VIDEO [--frames N] [--window W --levels L --points P --track-pixels N --normalize-sigma S --iterations N --min-step PX]
//
// FRAMES_DIR holds consecutive JPEG (or PNG) frames, e.g. `rolamos synth ... -o DIR` then
// DIR/frames. The figures are milliseconds of one core; the engine spreads them over the cores.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <opencv2/videoio.hpp>

#include "engine/feather.h"
#include "engine/features.h"
#include "engine/patch_canvas.h"
#include "engine/preprocess.h"
#include "engine/sift_descriptor.h"
#include "engine/tracker.h"
#include "util/heap_tuning.h"

namespace fs = std::filesystem;
using namespace rolamos;

namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Milliseconds of `f`, once.
double Time(const std::function<void()>& f) {
  const auto t = std::chrono::steady_clock::now();
  f();
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

}  // namespace

int main(int argc, char** argv) {
  // The heap the `rolamos` program runs on (huge pages, one arena): without it a slow hour's page
  // faults, not the work, set the figures (the tracking pyramid 31 ms instead of 2).
  rolamos::RestartWithHugePageHeap(argv);
  rolamos::KeepOneHeap();
  const char* usage = "usage: engine_floor_bench FRAMES_DIR|VIDEO [--frames N] [--window W --levels L --points P --track-pixels N --normalize-sigma S --iterations N --min-step PX]\n";
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::fprintf(stderr, "%s", usage);
    return argc < 2 ? 2 : 0;
  }
  std::error_code ec;
  const bool video = fs::is_regular_file(argv[1], ec);
  if (!video && !fs::is_directory(argv[1], ec)) {
    std::fprintf(stderr, "engine_floor_bench: %s is neither a folder of frames nor a video\n%s", argv[1], usage);
    return 2;
  }
  int limit = 30;
  TrackerOptions to;
  for (int i = 2; i + 1 < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--frames") limit = std::atoi(argv[i + 1]);
    if (flag == "--window") to.window = std::atoi(argv[i + 1]);
    if (flag == "--levels") to.levels = std::atoi(argv[i + 1]);
    if (flag == "--points") to.max_points = std::atoi(argv[i + 1]);
    if (flag == "--track-pixels") to.track_pixels = std::atof(argv[i + 1]);
    if (flag == "--normalize-sigma") to.normalize_sigma = std::atof(argv[i + 1]);
    if (flag == "--iterations") to.max_iterations = std::atoi(argv[i + 1]);
    if (flag == "--min-step") to.min_step_px = std::atof(argv[i + 1]);
  }
  cv::setNumThreads(1);  // one core's cost
  std::vector<std::string> paths;
  std::vector<std::string> bytes;
  if (video) {
    // A video's decoded frames, kept losslessly (PNG), named as a synth survey names its frames:
    // its codec's artefacts are what the tracker is measured on.
    cv::VideoCapture cap(argv[1]);
    cv::Mat frame;
    std::vector<uchar> png;
    while (static_cast<int>(paths.size()) < limit && cap.read(frame)) {
      cv::imencode(".png", frame, png, {cv::IMWRITE_PNG_COMPRESSION, 1});
      bytes.emplace_back(png.begin(), png.end());
      char name[32];
      std::snprintf(name, sizeof name, "frame_%05zu.jpg", paths.size());
      paths.push_back(name);
    }
  } else {
    for (const auto& e : fs::directory_iterator(argv[1])) {
      const std::string ext = e.path().extension().string();
      if (ext == ".jpg" || ext == ".JPG" || ext == ".png" || ext == ".jpeg") paths.push_back(e.path().string());
    }
    std::sort(paths.begin(), paths.end());
    if (paths.size() > size_t(limit)) paths.resize(size_t(limit));
  }
  if (paths.size() < 2) {
    std::fprintf(stderr, "engine_floor_bench: %s: fewer than 2 frames\n", argv[1]);
    return 1;
  }
  // Ground truth beside the frames (a `rolamos synth` survey): the tracks' homography is scored.
  std::map<std::string, cv::Matx33d> truth;
  const fs::path gt_path = fs::path(argv[1]).parent_path() / "ground_truth.json";
  if (fs::exists(gt_path)) {
    const auto gt = nlohmann::json::parse(ReadBytes(gt_path.string()));
    for (const auto& f : gt["frames"]) {
      cv::Matx33d H;
      for (int k = 0; k < 9; ++k) H.val[k] = f["frame_to_world"][size_t(k)].get<double>();
      truth[fs::path(f["file"].get<std::string>()).filename().string()] = H;
    }
  }
  if (!video)
    for (const auto& p : paths) bytes.push_back(ReadBytes(p));

  std::vector<std::pair<std::string, std::vector<double>>> rows;
  auto row = [&](const std::string& name) -> std::vector<double>& {
    for (auto& r : rows)
      if (r.first == name) return r.second;
    rows.emplace_back(name, std::vector<double>());
    return rows.back().second;
  };

  // A plausible lens (k1 = -0.1) for the cost of undistortion; the synthetic frames have none.
  cv::Mat first = cv::imdecode(cv::Mat(1, int(bytes[0].size()), CV_8U, bytes[0].data()), cv::IMREAD_COLOR);
  const cv::Size size = first.size();
  const double f = 0.9 * size.width;
  const cv::Matx33d K(f, 0, size.width / 2.0, 0, f, size.height / 2.0, 0, 0, 1);
  const cv::Mat D = (cv::Mat_<double>(1, 5) << -0.1, 0.01, 0, 0, 0);
  cv::Mat map1, map2;
  cv::initUndistortRectifyMap(cv::Mat(K), D, cv::Mat(), cv::Mat(K), size, CV_16SC2, map1, map2);

  FrameTracker tracker(to);
  FeatureOptions fo;
  const FeatureExtractor extractor(fo);
  FeatureOptions fo_halved = fo;
  fo_halved.double_first_octave = false;
  const FeatureExtractor halved(fo_halved);
  const double detect_scale = fo.ScaleFor(size);
  PreprocessOptions po;
  Preprocessor pre(po);
  const cv::Mat weights_f = FeatherWeights(size, 0.2);
  const FeatherCode weights(weights_f);
  PatchCanvas full(1LL << 40, 1.0, false), half(1LL << 40, 0.5, true);

  std::shared_ptr<const TrackFrame> previous;
  cv::Matx33d guess = cv::Matx33d::eye();
  cv::Mat previous_colour;
  for (size_t i = 0; i < bytes.size(); ++i) {
    cv::Mat colour, undistorted, gray, small, detect, smoothed;
    const cv::Mat buffer(1, int(bytes[i].size()), CV_8U, bytes[i].data());
    row("decode (JPEG, full colour)").push_back(Time([&] { colour = cv::imdecode(buffer, cv::IMREAD_COLOR); }));
    row("decode, half size (IMREAD_REDUCED_COLOR_2)").push_back(
        Time([&] { small = cv::imdecode(buffer, cv::IMREAD_REDUCED_COLOR_2); }));
    row("undistort (remap, colour)").push_back(
        Time([&] { cv::remap(colour, undistorted, map1, map2, cv::INTER_LINEAR); }));
    std::shared_ptr<const TrackFrame> here;
    row("tracking image and pyramid").push_back(Time([&] { here = tracker.Prepare(colour); }));
    if (previous) {
      std::vector<cv::Point2f> points;
      row("corners (keyframes)").push_back(Time([&] { points = tracker.Corners(*previous, {}, to.max_points); }));
      TrackFlow flow;
      // The start: with ground truth, the true motion a few pixels off (what the engine's
      // Kalman prediction gives); otherwise the previous pair's motion.
      const auto a_truth = truth.find(fs::path(paths[i - 1]).filename().string());
      const auto b_truth = truth.find(fs::path(paths[i]).filename().string());
      if (a_truth != truth.end() && b_truth != truth.end())
        guess = cv::Matx33d(1, 0, 2.5, 0, 1, -1.5, 0, 0, 1) * b_truth->second.inv() * a_truth->second;
      row("follow the points (LK forward and backward)").push_back(
          Time([&] { flow = tracker.Follow(*previous, *here, points, guess); }));
      std::vector<cv::Point2f> a, b;
      for (size_t k = 0; k < points.size(); ++k)
        if (flow.ok[k]) {
          a.push_back(points[k]);
          b.push_back(flow.to[k]);
        }
      if (a.size() >= 8) {
        cv::Mat H;
        row("homography from the tracks (RANSAC)").push_back(
            Time([&] { H = cv::findHomography(a, b, cv::RANSAC, 1.0); }));
        if (!H.empty()) {
          const cv::Matx33d found(H);
          if (a_truth == truth.end() || b_truth == truth.end()) guess = found;
          if (a_truth != truth.end() && b_truth != truth.end()) {
            const cv::Matx33d true_H = b_truth->second.inv() * a_truth->second;  // previous -> this frame
            double sse = 0;
            int n = 0;
            for (int gy = 0; gy < 5; ++gy)
              for (int gx = 0; gx < 5; ++gx) {
                const cv::Vec3d p(gx * (size.width - 1) / 4.0, gy * (size.height - 1) / 4.0, 1);
                const cv::Vec3d u = found * p, v = true_H * p;
                sse += std::pow(u[0] / u[2] - v[0] / v[2], 2) + std::pow(u[1] / u[2] - v[1] / v[2], 2);
                ++n;
              }
            row("tracks' homography error against the truth (px RMS, not ms)").push_back(std::sqrt(sse / n));
          }
        }
      }
      row("points followed of those handed on (count, not ms)").push_back(flow.followed);
    }
    row("bilateral filter (keyframes)").push_back(Time([&] { smoothed = pre.Spatial(colour); }));
    row("detection image (gray, resize, CLAHE; keyframes)").push_back(
        Time([&] { detect = pre.DetectionImage(colour, detect_scale); }));
    Features feats;
    row("SIFT at the detection scale (keyframes)").push_back(
        Time([&] { feats = extractor.ExtractScaled(detect, detect_scale); }));
    row("  same, found on the detection image halved (--no-sift-upsample)").push_back(
        Time([&] { feats = halved.ExtractScaled(detect, detect_scale); }));
    {
      // The peer, and describing what SIFT found, pyramid included: OpenCV's compute, and DescribeSift.
      auto sift = cv::SIFT::create(1000, 3, 0.005);
      std::vector<cv::KeyPoint> found;
      sift->detect(detect, found);
      cv::Mat described;
      row("  OpenCV's cv::SIFT instead (detectAndCompute)").push_back(Time([&] {
        std::vector<cv::KeyPoint> again;
        cv::Mat d;
        sift->detectAndCompute(detect, cv::noArray(), again, d);
      }));
      row("  finding keypoints only, OpenCV (SIFT::detect)").push_back(Time([&] {
        std::vector<cv::KeyPoint> again;
        sift->detect(detect, again);
      }));
      row("  describing its keypoints, OpenCV (SIFT::compute)").push_back(Time([&] {
        std::vector<cv::KeyPoint> copy = found;
        sift->compute(detect, copy, described);
      }));
      row("  describing its keypoints, DescribeSift").push_back(
          Time([&] { DescribeSift(detect, found, 3, 1.6, &described); }));
    }
    const cv::Matx33d at(1, 0, 40.0 * double(i), 0, 1, 0, 0, 0, 1);
    row("blend into the half-size working canvas (keyframes)").push_back(Time([&] { half.Add(colour, weights, at); }));
    row("blend at full resolution (keyframes, writer)").push_back(Time([&] { full.Add(colour, weights, at); }));
    if (!previous_colour.empty())
      row("temporal filter (keyframes, writer)").push_back(
          Time([&] { pre.Temporal(colour, previous_colour, cv::Matx33d(1, 0, 40, 0, 1, 0, 0, 0, 1)); }));
    previous = here;
    previous_colour = colour;
  }
  std::printf("%zu frames of %dx%d from %s; milliseconds of one core, median\n", bytes.size(), size.width,
              size.height, argv[1]);
  const double floor = Median(row("decode (JPEG, full colour)")) + Median(row("tracking image and pyramid"));
  for (const auto& [name, ms] : rows) std::printf("  %-52s %7.2f\n", name.c_str(), Median(ms));
  std::printf("floor (decode + tracking pyramid): %.1f ms a frame, %.0f frames/s on one core, %.0f on %u\n", floor,
              1000.0 / floor, 1000.0 * std::max(1u, std::thread::hardware_concurrency()) / floor,
              std::max(1u, std::thread::hardware_concurrency()));
  return 0;
}
