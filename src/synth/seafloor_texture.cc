#include "synth/seafloor_texture.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

uint32_t Hash(long long i, long long j, uint32_t seed) {
  uint64_t h = static_cast<uint64_t>(i) * 0x9E3779B97F4A7C15ull ^
               (static_cast<uint64_t>(j) + 0x632BE59BD9B4E019ull) * 0xC2B2AE3D27D4EB4Full ^
               (uint64_t(seed) << 32);
  h ^= h >> 33;
  h *= 0xff51afd7ed558ccdull;
  h ^= h >> 33;
  h *= 0xc4ceb9fe1a85ec53ull;
  h ^= h >> 33;
  return static_cast<uint32_t>(h);
}

// Value noise with lattice spacing `cell` pixels, in [-1, 1], sampled over the window. The
// lattice point (i, j) sits at pixel (i*cell + cell/2 - 0.5, ...) whatever the window, so
// neighbouring windows join exactly (the same mapping cv::resize would use).
cv::Mat ValueNoise(long long x, long long y, int cols, int rows, int cell, uint32_t seed) {
  const int margin = 2;
  auto floor_div = [](long long a, long long b) { return a >= 0 ? a / b : (a - b + 1) / b; };
  const long long i0 = floor_div(x, cell) - margin;
  const long long j0 = floor_div(y, cell) - margin;
  const int ni = static_cast<int>(floor_div(x + cols, cell) - i0 + margin + 1);
  const int nj = static_cast<int>(floor_div(y + rows, cell) - j0 + margin + 1);
  cv::Mat lattice(nj, ni, CV_32F);
  for (int j = 0; j < nj; ++j) {
    float* row = lattice.ptr<float>(j);
    for (int i = 0; i < ni; ++i)
      row[i] = static_cast<float>(Hash(i0 + i, j0 + j, seed) & 0xffff) / 32767.5f - 1.0f;
  }
  const double k = 1.0 / cell;
  cv::Mat m = (cv::Mat_<double>(2, 3) << k, 0, (x + 0.5) * k - 0.5 - i0, 0, k,
               (y + 0.5) * k - 0.5 - j0);
  cv::Mat dense;
  cv::warpAffine(lattice, dense, m, cv::Size(cols, rows), cv::INTER_CUBIC | cv::WARP_INVERSE_MAP,
                 cv::BORDER_REPLICATE);
  return dense;
}

}  // namespace

cv::Mat RenderSeafloor(long long x, long long y, int cols, int rows,
                       const SeafloorTextureOptions& options) {
  // OpenCV's warps take at most 32767 pixels a side: wider areas are rendered in pieces (the
  // texture is a function of position, so the pieces join without seams).
  constexpr int kPiece = 16384;
  if (cols > kPiece || rows > kPiece) {
    cv::Mat out(rows, cols, CV_8UC3);
    for (int r = 0; r < rows; r += kPiece)
      for (int c = 0; c < cols; c += kPiece) {
        const int w = std::min(kPiece, cols - c), h = std::min(kPiece, rows - r);
        RenderSeafloor(x + c, y + r, w, h, options).copyTo(out(cv::Rect(c, r, w, h)));
      }
    return out;
  }
  const double s = options.feature_scale;
  auto cell = [&](double c) { return std::max(2, static_cast<int>(std::lround(c * s))); };
  const uint32_t seed = options.seed;
  cv::Mat sand = ValueNoise(x, y, cols, rows, cell(2), seed) * 0.35f +
                 ValueNoise(x, y, cols, rows, cell(6), seed + 1) * 0.35f +
                 ValueNoise(x, y, cols, rows, cell(24), seed + 2) * 0.3f;
  cv::Mat large = ValueNoise(x, y, cols, rows, cell(160), seed + 3) * 0.6f +
                  ValueNoise(x, y, cols, rows, cell(640), seed + 4) * 0.4f;
  cv::Mat warp = ValueNoise(x, y, cols, rows, cell(96), seed + 5);
  cv::Mat rockiness = ValueNoise(x, y, cols, rows, cell(300), seed + 6) * 0.7f +
                      ValueNoise(x, y, cols, rows, cell(48), seed + 7) * 0.3f;
  cv::Mat pebbles = ValueNoise(x, y, cols, rows, cell(10), seed + 8);

  cv::Mat out(rows, cols, CV_8UC3);
  const double ripple_period = 22.0 * s;
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
  for (int r = range.start; r < range.end; ++r) {
    const float* sd = sand.ptr<float>(r);
    const float* lg = large.ptr<float>(r);
    const float* wp = warp.ptr<float>(r);
    const float* rk = rockiness.ptr<float>(r);
    const float* pb = pebbles.ptr<float>(r);
    cv::Vec3b* o = out.ptr<cv::Vec3b>(r);
    for (int c = 0; c < cols; ++c) {
      const double px = double(x + c), py = double(y + r);
      const double phase = (px * 0.8 + py * 0.6) / ripple_period * 2 * CV_PI + wp[c] * 6.0;
      const double ripple = std::sin(phase) * 0.5 + 0.5;
      double v = 0.55 + 0.18 * sd[c] + 0.12 * lg[c] + 0.12 * (ripple - 0.5);
      // Rock where the low-frequency field is high: darker, rougher, with a soft edge.
      const double rock = std::clamp((rk[c] - 0.25) * 4.0, 0.0, 1.0);
      v = v * (1 - rock) + rock * (0.32 + 0.25 * sd[c] + 0.2 * pb[c]);
      // Scattered pebbles on the sand.
      if (pb[c] > 0.72 && rock < 0.5) v *= 0.6;
      v = std::clamp(v, 0.0, 1.0);
      // Sand is beige; rock takes a greener cast; the water column tints everything blue-green.
      const double b = 0.62 * v + 0.05 * rock, g = 0.82 * v + 0.06 * rock, red = 0.78 * v - 0.1 * rock;
      o[c] = cv::Vec3b(cv::saturate_cast<uchar>(b * 255), cv::saturate_cast<uchar>(g * 255),
                       cv::saturate_cast<uchar>(red * 255));
    }
  }
  });
  return out;
}

}  // namespace rolamos
