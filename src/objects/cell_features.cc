#include "objects/cell_features.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/objdetect.hpp>

namespace rolamos {

namespace {

constexpr int kCell = 8;
constexpr int kBins = 9;

cv::Mat ToFloat01(const cv::Mat& gray) {
  cv::Mat f;
  const double scale = gray.depth() == CV_8U ? 1.0 / 255 : gray.depth() == CV_16U ? 1.0 / 65535 : 1.0;
  gray.convertTo(f, CV_32F, scale);
  return f;
}

// A wide Gaussian, cheaply: blurred at a quarter of the size, then enlarged.
cv::Mat WideBlur(const cv::Mat& f, double sigma) {
  cv::Mat small, blurred, out;
  const cv::Size reduced(std::max(1, f.cols / 4), std::max(1, f.rows / 4));
  cv::resize(f, small, reduced, 0, 0, cv::INTER_AREA);
  cv::GaussianBlur(small, blurred, cv::Size(), sigma / 4, sigma / 4, cv::BORDER_REFLECT);
  cv::resize(blurred, out, f.size(), 0, 0, cv::INTER_LINEAR);
  return out;
}

// (f - local mean) / local spread, clipped to +-4; in place, so a level costs two images.
void NormaliseLocally(cv::Mat& f) {
  const double sigma = 3.0 * kCell;
  f -= WideBlur(f, sigma);
  cv::Mat spread = WideBlur(f.mul(f), sigma);
  cv::sqrt(spread, spread);
  spread += 0.01;
  cv::divide(f, spread, f);
  spread.release();
  cv::min(f, 4.0, f);
  cv::max(f, -4.0, f);
}

}  // namespace

CellMap DescribeCells(const cv::Mat& gray) {
  cv::Mat n;
  cv::copyMakeBorder(ToFloat01(gray), n, kCell, kCell, kCell, kCell, cv::BORDER_REFLECT_101);
  NormaliseLocally(n);
  CellMap map;
  map.cell = kCell;
  map.origin = kCell;
  map.rows = n.rows / kCell;
  map.cols = n.cols / kCell;
  map.dims = kCellDims;
  const int cells = map.rows * map.cols;
  // Gradients and their polar form, vectorised by OpenCV, a strip of cells at a time so that
  // memory holds the image and one strip (signed orientation in 18 bins).
  constexpr int kSigned = 2 * kBins;
  std::vector<float> hist(static_cast<size_t>(cells) * kSigned, 0.f), sum(static_cast<size_t>(cells), 0.f),
      sum2(static_cast<size_t>(cells), 0.f);
  const int h = map.rows * kCell, w = map.cols * kCell;
  const float to_bin = float(kSigned / (2 * CV_PI));
  constexpr int kStrip = 8 * kCell;
  cv::Mat gx, gy, mag, angle;
  for (int y0 = 0; y0 < h; y0 += kStrip) {
    const int y1 = std::min(h, y0 + kStrip);
    // One row of context above and below (mirrored at the image's edge, as Sobel does).
    const int top = std::max(0, y0 - 1), bottom = std::min(n.rows, y1 + 1);
    const cv::Mat strip = n.rowRange(top, bottom);
    cv::Sobel(strip, gx, CV_32F, 1, 0, 1);
    cv::Sobel(strip, gy, CV_32F, 0, 1, 1);
    if (top == y0) gy.row(0).setTo(0);  // the image's first row: no row above
    if (bottom == y1 && y1 == n.rows) gy.row(gy.rows - 1).setTo(0);
    cv::cartToPolar(gx, gy, mag, angle);  // radians, 0..2 pi
    for (int y = y0; y < y1; ++y) {
      const float* row = n.ptr<float>(y);
      const float* m = mag.ptr<float>(y - top);
      const float* a = angle.ptr<float>(y - top);
      float* hrow = hist.data() + static_cast<size_t>(y / kCell) * map.cols * kSigned;
      float* srow = sum.data() + static_cast<size_t>(y / kCell) * map.cols;
      float* s2row = sum2.data() + static_cast<size_t>(y / kCell) * map.cols;
      for (int x = 0; x < w; ++x) {
        const int c = x / kCell;
        srow[c] += row[x];
        s2row[c] += row[x] * row[x];
        // Shared linearly between the two nearest bin centres.
        const float b = a[x] * to_bin - 0.5f;
        const int b0 = static_cast<int>(std::floor(b));
        const float t = b - float(b0);
        float* hc = hrow + c * kSigned;
        hc[(b0 + kSigned) % kSigned] += m[x] * (1 - t);
        hc[(b0 + 1) % kSigned] += m[x] * t;
      }
    }
  }
  // Energy of the unsigned histogram (opposite directions folded), for the normalisers.
  std::vector<float> energy(static_cast<size_t>(cells));
  for (int i = 0; i < cells; ++i) {
    const float* hc = hist.data() + static_cast<size_t>(i) * kSigned;
    float e = 0;
    for (int b = 0; b < kBins; ++b) e += (hc[b] + hc[b + kBins]) * (hc[b] + hc[b + kBins]);
    energy[static_cast<size_t>(i)] = e;
  }
  auto E = [&](int r, int c) {
    r = std::clamp(r, 0, map.rows - 1);
    c = std::clamp(c, 0, map.cols - 1);
    return energy[static_cast<size_t>(r) * map.cols + c];
  };
  map.data.assign(static_cast<size_t>(cells) * kCellDims, 0.f);
  const float pixels = float(kCell * kCell);
  for (int r = 0; r < map.rows; ++r)
    for (int c = 0; c < map.cols; ++c) {
      const size_t i = static_cast<size_t>(r) * map.cols + c;
      // The four 2 x 2 neighbourhoods the cell belongs to: up-left, up-right, down-left, down-right.
      float norm[4];
      int k = 0;
      for (int dr : {-1, 1})
        for (int dc : {-1, 1})
          norm[k++] = 1.f / std::sqrt(E(r, c) + E(r + dr, c) + E(r, c + dc) + E(r + dr, c + dc) + 1e-4f);
      const float* hc = hist.data() + i * kSigned;
      float* out = map.data.data() + i * kCellDims;
      // Felzenszwalb's 31: 18 signed bins, 9 unsigned, 4 energies (each summed over normalisers).
      for (int b = 0; b < kSigned; ++b) {
        float s = 0;
        for (int q = 0; q < 4; ++q) {
          const float u = std::min(hc[b] * norm[q], 0.2f);
          s += u;
          out[27 + q] += u * 0.2357f;
        }
        out[b] = 0.5f * s;
      }
      for (int b = 0; b < kBins; ++b) {
        float s = 0;
        for (int q = 0; q < 4; ++q) s += std::min((hc[b] + hc[b + kBins]) * norm[q], 0.2f);
        out[kSigned + b] = 0.5f * s;
      }
      const float mean = sum[i] / pixels;
      out[31] = mean * 0.25f;
      out[32] = std::sqrt(std::max(sum2[i] / pixels - mean * mean, 0.f)) * 0.25f;
    }
  return map;
}

CellMap DescribeHogBlocks(const cv::Mat& gray8) {
  cv::Mat g = gray8;
  if (g.depth() != CV_8U) {
    const double scale = g.depth() == CV_16U ? 1.0 / 257 : g.depth() == CV_32F ? 255.0 : 1.0;
    g.convertTo(g, CV_8U, scale);
  }
  cv::Mat padded;
  cv::copyMakeBorder(g, padded, kCell, kCell, kCell, kCell, cv::BORDER_REFLECT_101);
  cv::HOGDescriptor hog(cv::Size(16, 16), cv::Size(16, 16), cv::Size(8, 8), cv::Size(8, 8), kBins);
  std::vector<float> d;
  hog.compute(padded, d, cv::Size(kCell, kCell), cv::Size(0, 0));
  CellMap map;
  map.cell = kCell;
  map.origin = kCell;
  map.rows = (padded.rows - 16) / kCell + 1;
  map.cols = (padded.cols - 16) / kCell + 1;
  map.dims = 36;
  map.data = std::move(d);
  map.data.resize(static_cast<size_t>(map.rows) * map.cols * map.dims, 0.f);
  return map;
}

}  // namespace rolamos
