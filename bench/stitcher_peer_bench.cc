// The peer: OpenCV's cv::Stitcher in SCANS mode on the frames of a survey, for comparison with
// `rolamos mosaic` on the same frames. Prints one JSON line: status, seconds, peak RSS, size.
//   stitcher_peer_bench FRAMES_DIR [max_frames]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/stitching.hpp>

#include "util/memory.h"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: stitcher_peer_bench FRAMES_DIR [max_frames]\n");
    return 2;
  }
  const size_t max_frames = argc > 2 ? static_cast<size_t>(std::stoul(argv[2])) : 1000000;
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(argv[1])) files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  if (files.size() > max_frames) files.resize(max_frames);
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<cv::Mat> images;
  for (const auto& f : files) images.push_back(cv::imread(f));
  auto stitcher = cv::Stitcher::create(cv::Stitcher::SCANS);
  cv::Mat pano;
  cv::Stitcher::Status status = cv::Stitcher::ERR_NEED_MORE_IMGS;
  std::string error;
  try {
    status = stitcher->stitch(images, pano);
  } catch (const cv::Exception& e) {
    error = e.what();
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const char* names[] = {"ok", "need_more_images", "homography_estimation_failed",
                         "camera_parameters_adjustment_failed"};
  // SCANS keeps only the largest group of images it could link: how many made it in.
  const size_t used = status == cv::Stitcher::OK ? stitcher->component().size() : 0;
  std::printf("{\"frames\": %zu, \"used\": %zu, \"status\": \"%s\", \"seconds\": %.2f, "
              "\"peak_rss_mb\": %.0f, \"width\": %d, \"height\": %d, \"exception\": %s}\n",
              images.size(), used, error.empty() ? names[static_cast<int>(status)] : "exception", seconds,
              rolamos::PeakRssMb(), pano.cols, pano.rows, error.empty() ? "false" : "true");
  return 0;
}
