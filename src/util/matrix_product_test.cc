#include "util/matrix_product.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

cv::Mat Random(int rows, int cols, int seed) {
  cv::Mat m(rows, cols, CV_32F);
  cv::RNG(seed).fill(m, cv::RNG::UNIFORM, -1, 1);
  return m;
}

// Every transposition, small and large (the large ones are split over the cores), and views
// into bigger matrices (rows with a stride), against OpenCV's own product.
TEST(MatrixProduct, AgreesWithOpenCvGemm) {
  for (const cv::Size size : {cv::Size(3, 5), cv::Size(300, 700)}) {
    const int n = size.width, m = size.height, k = 37;
    const cv::Mat a = Random(n, k, 1), b = Random(k, m, 2), bt = Random(m, k, 3), at = Random(k, n, 4);
    struct Case {
      cv::Mat a, b;
      int flags;
    };
    for (const Case& c : {Case{a, b, 0}, Case{a, bt, cv::GEMM_2_T}, Case{at, b, cv::GEMM_1_T},
                          Case{at, bt, cv::GEMM_1_T | cv::GEMM_2_T}}) {
      cv::Mat expected;
      cv::gemm(c.a, c.b, 1.0, cv::noArray(), 0, expected, c.flags);
      const cv::Mat got = MatrixProduct(c.a, c.b, c.flags);
      ASSERT_EQ(got.size(), expected.size());
      EXPECT_LT(cv::norm(got, expected, cv::NORM_INF), 1e-4) << size << " flags " << c.flags;
    }
  }
  const cv::Mat big = Random(50, 60, 5);
  const cv::Mat view = big(cv::Rect(10, 5, 20, 30));  // 30 x 20, stride 60
  cv::Mat expected;
  cv::gemm(view, view, 1.0, cv::noArray(), 0, expected, cv::GEMM_2_T);
  EXPECT_LT(cv::norm(MatrixProduct(view, view, cv::GEMM_2_T), expected, cv::NORM_INF), 1e-4);
}

}  // namespace
}  // namespace rolamos
