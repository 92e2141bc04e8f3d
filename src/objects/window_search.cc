#include "objects/window_search.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {

std::vector<double> WindowSearch::Scales() const {
  std::vector<double> s;
  const double first = kBoxPixels / min_box, step = std::pow(2.0, -1.0 / scales_per_octave);
  for (double scale = first; kBoxPixels / scale <= max_box * 1.0001; scale *= step) s.push_back(scale);
  return s;
}

CellMap WindowSearch::Describe(const cv::Mat& gray, double scale) const {
  cv::Mat level;
  const cv::Size size(std::max(1, int(std::lround(gray.cols * scale))), std::max(1, int(std::lround(gray.rows * scale))));
  cv::resize(gray, level, size, 0, 0, scale < 1 ? cv::INTER_AREA : cv::INTER_LINEAR);
  return features == "hog" ? DescribeHogBlocks(level) : DescribeCells(level);
}

cv::Rect2d WindowSearch::Box(const CellMap& map, int r, int c, double scale) {
  const double x = double(c * map.cell - map.origin + (kWindowPixels - kBoxPixels) / 2);
  const double y = double(r * map.cell - map.origin + (kWindowPixels - kBoxPixels) / 2);
  return {x / scale, y / scale, kBoxPixels / scale, kBoxPixels / scale};
}

void WindowSearch::Vector(const CellMap& map, int r, int c, float* out) const {
  const int n = WindowCells(), row = n * map.dims;
  for (int i = 0; i < n; ++i) std::copy(map.at(r + i, c), map.at(r + i, c) + row, out + i * row);
}

cv::Mat WindowSearch::Scores(const CellMap& map, const std::vector<float>& weights, double bias) const {
  const int n = WindowCells(), rows = map.rows - n + 1, cols = map.cols - n + 1;
  if (rows <= 0 || cols <= 0) return {};
  // Every cell's response to every place in the window at once (one matrix product), then each
  // window adds its cells' responses at their places.
  const cv::Mat cells(map.rows * map.cols, map.dims, CV_32F, const_cast<float*>(map.data.data()));
  cv::Mat w(n * n, map.dims, CV_32F, const_cast<float*>(weights.data()));
  cv::Mat response;
  cv::gemm(cells, w, 1.0, cv::noArray(), 0.0, response, cv::GEMM_2_T);
  cv::Mat s(rows, cols, CV_32F, cv::Scalar(bias));
  for (int i = 0; i < n; ++i)
    for (int r = 0; r < rows; ++r) {
      float* out = s.ptr<float>(r);
      for (int j = 0; j < n; ++j) {
        const float* in = response.ptr<float>((r + i) * map.cols + j) + (i * n + j);
        for (int c = 0; c < cols; ++c) out[c] += in[static_cast<size_t>(c) * n * n];
      }
    }
  return s;
}

double BoxIou(const cv::Rect2d& a, const cv::Rect2d& b) {
  const double inter = (a & b).area();
  return inter > 0 ? inter / (a.area() + b.area() - inter) : 0;
}

cv::Mat ToGray(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat g;
  cv::cvtColor(image, g, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  return g;
}

}  // namespace rolamos
