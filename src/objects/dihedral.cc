#include "objects/dihedral.h"

#include "rolamos/error.hpp"

namespace rolamos {

namespace {

cv::Mat Permute(const cv::Mat& in, const std::vector<int>& to) {
  const int block = static_cast<int>(to.size());
  CV_Assert(in.type() == CV_32F && in.cols % block == 0);
  cv::Mat out(in.rows, in.cols, CV_32F);
  for (int i = 0; i < in.rows; ++i) {
    const float* a = in.ptr<float>(i);
    float* b = out.ptr<float>(i);
    for (int base = 0; base < in.cols; base += block)
      for (int k = 0; k < block; ++k) b[base + to[static_cast<size_t>(k)]] = a[base + k];
  }
  return out;
}

}  // namespace

DihedralTransform::DihedralTransform(int t) : t_(t), sift_(128), colour_(96) {
  if (t < 0 || t > 7) Fail("orientation", std::to_string(t) + " is not in 0..7");
  const int turns = t & 3;
  const bool mirror = (t & 4) != 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      // The cell's place after the turns (row, column -> column, 3 - row each) and the mirror.
      int rr = r, cc = c;
      for (int k = 0; k < turns; ++k) {
        const int next_r = cc, next_c = 3 - rr;
        rr = next_r;
        cc = next_c;
      }
      if (mirror) cc = 3 - cc;
      // OpenCV measures gradient angles counter-clockwise in 8 bins: a clockwise quarter turn
      // moves a bin by 6 (-2); a mirror reflects the angle about the vertical (bin 4 - o).
      for (int o = 0; o < 8; ++o) {
        int oo = (o + 6 * turns) % 8;
        if (mirror) oo = (12 - oo) % 8;
        sift_[static_cast<size_t>((r * 4 + c) * 8 + o)] = (rr * 4 + cc) * 8 + oo;
      }
      for (int v = 0; v < 6; ++v) colour_[static_cast<size_t>((r * 4 + c) * 6 + v)] = (rr * 4 + cc) * 6 + v;
    }
}

cv::Mat DihedralTransform::Sift(const cv::Mat& descriptors) const {
  return t_ == 0 ? descriptors : Permute(descriptors, sift_);
}

cv::Mat DihedralTransform::ColourStatistics(const cv::Mat& statistics) const {
  return t_ == 0 ? statistics : Permute(statistics, colour_);
}

cv::Point2f DihedralTransform::Point(cv::Point2f p, float side) const {
  for (int k = 0; k < (t_ & 3); ++k) p = cv::Point2f(side - p.y, p.x);
  if (t_ & 4) p.x = side - p.x;
  return p;
}

}  // namespace rolamos
