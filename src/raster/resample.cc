#include "raster/resample.h"

#include <opencv2/imgproc.hpp>

namespace rolamos {

cv::Mat WarpRespectingAlpha(const cv::Mat& src, const cv::Mat& dst_to_src, cv::Size size,
                            bool has_alpha, double prefilter_sigma) {
  const int flags = cv::INTER_LINEAR | cv::WARP_INVERSE_MAP;
  const bool blur = prefilter_sigma > 0.2;
  cv::Mat out;
  if (!has_alpha) {
    cv::Mat in = src;
    if (blur) cv::GaussianBlur(src, in, cv::Size(), prefilter_sigma, prefilter_sigma, cv::BORDER_REPLICATE);
    cv::warpAffine(in, out, dst_to_src, size, flags, cv::BORDER_REPLICATE);
    return out;
  }
  const int cn = src.channels();
  cv::Mat f;
  src.convertTo(f, CV_32F);
  std::vector<cv::Mat> ch;
  cv::split(f, ch);
  for (int c = 0; c < cn - 1; ++c) ch[c] = ch[c].mul(ch[cn - 1]);
  cv::merge(ch, f);
  if (blur) cv::GaussianBlur(f, f, cv::Size(), prefilter_sigma, prefilter_sigma, cv::BORDER_REPLICATE);
  cv::warpAffine(f, f, dst_to_src, size, flags, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  cv::split(f, ch);
  cv::Mat safe = cv::max(ch[cn - 1], 1e-3);
  for (int c = 0; c < cn - 1; ++c) cv::divide(ch[c], safe, ch[c]);
  cv::merge(ch, f);
  f.convertTo(out, src.type());  // rounds and saturates
  return out;
}

}  // namespace rolamos
