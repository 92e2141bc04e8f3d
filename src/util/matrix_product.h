// Matrix products of CV_32F matrices by Eigen, split over the cores by row blocks. OpenCV's gemm
// hands products to the system BLAS, which on a stock Debian is the reference one (the Fisher
// encoding then spent most of its time in it); Eigen is already a dependency.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// op(a) x op(b), op transposing when cv::GEMM_1_T / cv::GEMM_2_T is in `flags`. CV_32F in and out.
cv::Mat MatrixProduct(const cv::Mat& a, const cv::Mat& b, int flags = 0);

}  // namespace rolamos
