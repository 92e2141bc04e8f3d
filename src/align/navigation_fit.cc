#include "align/navigation_fit.h"

#include <algorithm>
#include <filesystem>

#include <opencv2/calib3d.hpp>

#include "util/homography.h"

namespace rolamos {

namespace fs = std::filesystem;

const FrameNavigation* FindFrameNavigation(const std::map<std::string, FrameNavigation>& nav,
                                           const std::string& source) {
  const fs::path src(source);
  auto it = nav.find(src.parent_path().filename().string() + "/" + src.filename().string());
  if (it == nav.end()) it = nav.find(src.filename().string());
  return it == nav.end() ? nullptr : &it->second;
}

void AddNavigationPoints(const FrameNavigation& nav, const cv::Matx33d& frame_to_global, cv::Size frame,
                         std::vector<cv::Point2d>* global, std::vector<cv::Point2d>* map) {
  const auto& g = nav.geotransform;
  for (const cv::Point2d p : {cv::Point2d(0.5, 0.5), cv::Point2d(0.35, 0.5), cv::Point2d(0.65, 0.5),
                              cv::Point2d(0.5, 0.35), cv::Point2d(0.5, 0.65)}) {
    const double col = p.x * (frame.width - 1), row = p.y * (frame.height - 1);
    global->push_back(ApplyHomography(frame_to_global, {col, row}));
    map->emplace_back(g[0] + col * g[1] + row * g[2], g[3] + col * g[4] + row * g[5]);
  }
}

std::optional<cv::Matx33d> FitSimilarity(const std::vector<cv::Point2d>& from, const std::vector<cv::Point2d>& to) {
  if (from.size() < 2 || from.size() != to.size()) return std::nullopt;
  cv::Point2d a(0, 0), b(0, 0);
  for (size_t i = 0; i < from.size(); ++i) a += from[i], b += to[i];
  a *= 1.0 / from.size();
  b *= 1.0 / to.size();
  // Image pixels run down where maps run north: the transform may be a mirror image as well as
  // a turn. Both are fitted (a mirror as a turn of the flipped points); the better one is kept:
  // by the mean residual, not the median, since a track mostly straight (a lane and the start of
  // a turn) fits both ways at its median, and only the frames off the line tell them apart.
  std::optional<cv::Matx33d> best;
  double best_mean = 0;
  for (const double flip : {1.0, -1.0}) {
    std::vector<cv::Point2f> x, y;
    for (size_t i = 0; i < from.size(); ++i) {
      const cv::Point2d d = from[i] - a;
      x.emplace_back(static_cast<float>(d.x), static_cast<float>(flip * d.y));
      y.emplace_back(to[i] - b);
    }
    std::vector<uchar> inliers;
    const cv::Mat A = cv::estimateAffinePartial2D(x, y, inliers, cv::LMEDS);
    if (A.empty()) continue;
    const cv::Matx23d T(A);
    const cv::Matx33d M = cv::Matx33d(1, 0, b.x, 0, 1, b.y, 0, 0, 1) *
                          cv::Matx33d(T(0, 0), T(0, 1), T(0, 2), T(1, 0), T(1, 1), T(1, 2), 0, 0, 1) *
                          cv::Matx33d(1, 0, 0, 0, flip, 0, 0, 0, 1) * cv::Matx33d(1, 0, -a.x, 0, 1, -a.y, 0, 0, 1);
    std::vector<double> residuals;
    for (size_t i = 0; i < from.size(); ++i) residuals.push_back(cv::norm(ApplyHomography(M, from[i]) - to[i]));
    double mean = 0;
    for (const double r : residuals) mean += r / static_cast<double>(residuals.size());
    if (!best || mean < best_mean) {
      best = M;
      best_mean = mean;
    }
  }
  return best;
}

}  // namespace rolamos
