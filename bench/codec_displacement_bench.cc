// How far a video codec moves the texture of a synthetic survey's frames: each decoded frame of
// SURVEY/video.mp4 against its original, SURVEY/frames/*.jpg, by Lucas-Kanade at points over the
// frame (both contrast-normalised by the engine's tracker, at `scale` of the frame size).
// A codec predicts blocks from other frames by its own motion vectors and, where it spends no
// bits on the difference (dark, flat ground), leaves the texture where its prediction put it:
// the points of a region then move together, and no tracker can tell. Prints one JSON line:
//   cell_rms_px   RMS over frames and 4 x 4 cells of each cell's mean displacement (full-size
//                 pixels): what moves regions of a frame, the part a homography cannot average out;
//   point_median_px  the median displacement of single points (this includes the matching noise);
//   by_contrast   the median displacement in each quarter of the points by raw local contrast;
//   by_frame      each frame's cell RMS (a codec's intra frames, every 12th for OpenCV's MPEG-4,
//                 are where its displacement starts again).
//   codec_displacement_bench SURVEY_DIR [frames=60] [scale=0.5]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <opencv2/videoio.hpp>

#include "engine/tracker.h"

namespace {

cv::Mat Grey(const cv::Mat& image, double scale) {
  cv::Mat g, out;
  if (image.channels() == 3) cv::cvtColor(image, g, cv::COLOR_BGR2GRAY);
  else g = image;
  cv::resize(g, out, cv::Size(), scale, scale, cv::INTER_AREA);
  return out;
}

// The local standard deviation around each pixel (a Gaussian of `sigma`).
cv::Mat LocalDeviation(const cv::Mat& grey, double sigma) {
  cv::Mat f, mean, square, var;
  grey.convertTo(f, CV_32F);
  cv::GaussianBlur(f, mean, cv::Size(), sigma);
  cv::GaussianBlur(f.mul(f), square, cv::Size(), sigma);
  cv::sqrt(cv::max(square - mean.mul(mean), 0.0), var);
  return var;
}

// The image the engine's tracker follows: contrast-normalised by FrameTracker::Prepare (at the
// size given: the tracker is asked not to shrink it).
cv::Mat Normalised(const rolamos::FrameTracker& tracker, const cv::Mat& grey) {
  return tracker.Prepare(grey)->pyramid[0];
}

double Median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: codec_displacement_bench SURVEY_DIR [frames=60] [scale=0.5]\n");
    return 2;
  }
  const std::string dir = argv[1];
  const int frames = argc > 2 ? std::atoi(argv[2]) : 60;
  const double scale = argc > 3 ? std::atof(argv[3]) : 0.5;
  cv::VideoCapture video(dir + "/video.mp4");
  std::vector<cv::String> originals;
  cv::glob(dir + "/frames/*.jpg", originals);
  if (!video.isOpened() || originals.empty()) {
    std::fprintf(stderr, "%s: needs video.mp4 and frames/*.jpg (a survey written by rolamos synth --video)\n",
                 dir.c_str());
    return 1;
  }
  rolamos::TrackerOptions options;
  options.track_pixels = 1e8;  // followed at the size given
  const rolamos::FrameTracker tracker(options);
  constexpr int kCells = 4;
  double cell_sse = 0;
  int cell_count = 0, used = 0;
  std::vector<double> points;
  std::vector<std::pair<float, double>> by_contrast;
  std::string by_frame;
  for (int i = 0; i < frames && i < int(originals.size()); ++i) {
    cv::Mat decoded;
    if (!video.read(decoded)) break;
    const cv::Mat a = Grey(cv::imread(originals[size_t(i)]), scale), b = Grey(decoded, scale);
    const cv::Mat contrast = LocalDeviation(b, 4);
    const cv::Mat na = Normalised(tracker, a), nb = Normalised(tracker, b);
    std::vector<cv::Point2f> from, to;
    cv::goodFeaturesToTrack(na, from, 600, 0.001, 4);
    if (from.empty()) continue;
    to = from;
    std::vector<uchar> ok;
    std::vector<float> err;
    cv::calcOpticalFlowPyrLK(na, nb, from, to, ok, err, cv::Size(21, 21), 2,
                             cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 20, 0.01),
                             cv::OPTFLOW_USE_INITIAL_FLOW);
    cv::Vec2d sum[kCells * kCells];
    int count[kCells * kCells] = {0};
    for (size_t k = 0; k < from.size(); ++k) {
      if (!ok[k]) continue;
      const cv::Vec2d d((to[k].x - from[k].x) / scale, (to[k].y - from[k].y) / scale);
      if (cv::norm(d) > 4) continue;  // lost, not moved
      const int c = std::min(kCells - 1, int(kCells * from[k].y / na.rows)) * kCells +
                    std::min(kCells - 1, int(kCells * from[k].x / na.cols));
      sum[c] += d;
      ++count[c];
      points.push_back(cv::norm(d));
      by_contrast.emplace_back(contrast.at<float>(from[k]), cv::norm(d));
    }
    double frame_sse = 0;
    int frame_cells = 0;
    for (int c = 0; c < kCells * kCells; ++c) {
      if (count[c] < 6) continue;
      const cv::Vec2d mean = sum[c] / count[c];
      frame_sse += mean.dot(mean);
      ++frame_cells;
    }
    cell_sse += frame_sse;
    cell_count += frame_cells;
    char part[32];
    std::snprintf(part, sizeof part, "%s%.3f", by_frame.empty() ? "" : ", ",
                  frame_cells ? std::sqrt(frame_sse / frame_cells) : NAN);
    by_frame += part;
    ++used;
  }
  if (cell_count == 0) {
    std::fprintf(stderr, "%s: no frame could be compared\n", dir.c_str());
    return 1;
  }
  std::sort(by_contrast.begin(), by_contrast.end());
  std::string quarters;
  for (int q = 0; q < 4; ++q) {
    const size_t lo = by_contrast.size() * size_t(q) / 4, hi = by_contrast.size() * size_t(q + 1) / 4;
    std::vector<double> d;
    for (size_t k = lo; k < hi; ++k) d.push_back(by_contrast[k].second);
    char part[96];
    std::snprintf(part, sizeof part, "%s{\"contrast_from\": %.2f, \"median_px\": %.3f}", q ? ", " : "",
                  by_contrast[lo].first, Median(d));
    quarters += part;
  }
  std::printf("{\"survey\": \"%s\", \"frames\": %d, \"scale\": %.3f, \"cell_rms_px\": %.3f, \"point_median_px\": %.3f, "
              "\"by_contrast\": [%s], \"by_frame\": [%s]}\n",
              dir.c_str(), used, scale, std::sqrt(cell_sse / cell_count), Median(points), quarters.c_str(),
              by_frame.c_str());
  return 0;
}
