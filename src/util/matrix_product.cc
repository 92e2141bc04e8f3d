#include "util/matrix_product.h"

#include <Eigen/Core>

namespace rolamos {

namespace {

using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using ConstMap = Eigen::Map<const RowMajor, 0, Eigen::OuterStride<>>;
using Map = Eigen::Map<RowMajor, 0, Eigen::OuterStride<>>;

ConstMap View(const cv::Mat& m) {
  return ConstMap(m.ptr<float>(), m.rows, m.cols, Eigen::OuterStride<>(static_cast<long>(m.step1())));
}

}  // namespace

cv::Mat MatrixProduct(const cv::Mat& a, const cv::Mat& b, int flags) {
  CV_Assert(a.type() == CV_32F && b.type() == CV_32F);
  const bool ta = (flags & cv::GEMM_1_T) != 0, tb = (flags & cv::GEMM_2_T) != 0;
  const int rows = ta ? a.cols : a.rows, inner = ta ? a.rows : a.cols;
  const int cols = tb ? b.rows : b.cols;
  CV_Assert(inner == (tb ? b.cols : b.rows));
  cv::Mat out(rows, cols, CV_32F);
  const ConstMap A = View(a), B = View(b);
  // Row blocks of the result on every core when the product is large enough to pay for it.
  const double work = double(rows) * cols * inner;
  const int blocks = work > 2e7 ? std::max(1, std::min(rows / 16, 4 * cv::getNumThreads())) : 1;
  cv::parallel_for_(cv::Range(0, blocks), [&](const cv::Range& range) {
    for (int k = range.start; k < range.end; ++k) {
      const int r0 = static_cast<int>(static_cast<long long>(rows) * k / blocks);
      const int r1 = static_cast<int>(static_cast<long long>(rows) * (k + 1) / blocks);
      if (r1 <= r0) continue;
      Map O(out.ptr<float>(r0), r1 - r0, cols, Eigen::OuterStride<>(static_cast<long>(out.step1())));
      if (ta && tb) O.noalias() = A.middleCols(r0, r1 - r0).transpose() * B.transpose();
      else if (ta) O.noalias() = A.middleCols(r0, r1 - r0).transpose() * B;
      else if (tb) O.noalias() = A.middleRows(r0, r1 - r0) * B.transpose();
      else O.noalias() = A.middleRows(r0, r1 - r0) * B;
    }
  });
  return out;
}

}  // namespace rolamos
