#include "raster/downsample.h"

#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

template <typename T>
void AlphaWeighted(const cv::Mat& src, cv::Mat& dst) {
  const int cn = src.channels();
  const int ac = cn - 1;  // alpha is last
  cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const T* r0 = src.ptr<T>(2 * y);
      const T* r1 = src.ptr<T>(2 * y + 1);
      T* out = dst.ptr<T>(y);
      for (int x = 0; x < dst.cols; ++x) {
        const T* p[4] = {r0 + 2 * x * cn, r0 + (2 * x + 1) * cn, r1 + 2 * x * cn,
                         r1 + (2 * x + 1) * cn};
        const uint64_t a = uint64_t(p[0][ac]) + p[1][ac] + p[2][ac] + p[3][ac];
        T* o = out + x * cn;
        if (a == 0) {
          for (int c = 0; c < cn; ++c) o[c] = 0;
          continue;
        }
        for (int c = 0; c < ac; ++c) {
          const uint64_t s = uint64_t(p[0][c]) * p[0][ac] + uint64_t(p[1][c]) * p[1][ac] +
                             uint64_t(p[2][c]) * p[2][ac] + uint64_t(p[3][c]) * p[3][ac];
          o[c] = static_cast<T>((s + a / 2) / a);
        }
        o[ac] = static_cast<T>((a + 2) / 4);
      }
    }
  });
}

}  // namespace

cv::Mat Downsample2x(const cv::Mat& src, bool has_alpha) {
  CV_Assert(!src.empty());
  cv::Mat even = src;
  const int pad_x = src.cols & 1, pad_y = src.rows & 1;
  if (pad_x || pad_y) cv::copyMakeBorder(src, even, 0, pad_y, 0, pad_x, cv::BORDER_REPLICATE | cv::BORDER_ISOLATED);  // not the rows past a view
  cv::Mat dst(even.rows / 2, even.cols / 2, src.type());
  if (!has_alpha) {
    // Exact halving takes OpenCV's fast 2x2 box path.
    cv::resize(even, dst, dst.size(), 0, 0, cv::INTER_AREA);
  } else if (src.depth() == CV_8U) {
    AlphaWeighted<uint8_t>(even, dst);
  } else {
    AlphaWeighted<uint16_t>(even, dst);
  }
  return dst;
}

}  // namespace rolamos
