#include "util/principal_axes.h"

#include <algorithm>

#include <Eigen/Dense>

#include "rolamos/error.hpp"
#include "util/matrix_product.h"

namespace rolamos {

namespace {

using RowMajorF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// An orthonormal basis of `m`'s columns (thin Q of its QR factorisation, in double).
cv::Mat Orthonormal(const cv::Mat& m) {
  CV_Assert(m.type() == CV_32F && m.isContinuous());
  const Eigen::MatrixXd a = Eigen::Map<const RowMajorF>(m.ptr<float>(), m.rows, m.cols).cast<double>();
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(a);
  cv::Mat out(m.rows, m.cols, CV_32F);
  Eigen::Map<RowMajorF>(out.ptr<float>(), m.rows, m.cols) =
      (qr.householderQ() * Eigen::MatrixXd::Identity(m.rows, m.cols)).cast<float>();
  return out;
}

PrincipalAxes Exact(const cv::Mat& rows, int dims) {
  cv::PCA pca(rows, cv::Mat(), cv::PCA::DATA_AS_ROW, dims);
  PrincipalAxes p;
  pca.mean.convertTo(p.mean, CV_32F);
  pca.eigenvectors.convertTo(p.axes, CV_32F);
  return p;
}

}  // namespace

cv::Mat PrincipalAxes::Project(const cv::Mat& rows) const {
  CV_Assert(rows.type() == CV_32F && rows.cols == mean.cols);
  // rows x axes^T - mean x axes^T: no centred copy of the rows.
  cv::Mat out = MatrixProduct(rows, axes, cv::GEMM_2_T);
  const cv::Mat offset = MatrixProduct(mean, axes, cv::GEMM_2_T);
  for (int r = 0; r < out.rows; ++r) out.row(r) -= offset;
  return out;
}

PrincipalAxes FindPrincipalAxes(const cv::Mat& rows, int dims, int iterations) {
  if (rows.type() != CV_32F || rows.rows < 2)
    Fail("principal axes", "a sample of " + std::to_string(rows.rows) + " rows of type " + cv::typeToString(rows.type()) +
                               " (at least 2 rows of CV_32F needed)");
  const int rank = std::min(rows.rows, rows.cols);
  if (dims < 1 || dims > rank)
    Fail("principal axes", std::to_string(dims) + " axes asked of a sample of rank at most " + std::to_string(rank));
  // Oversampled by half (at least 16): the axes near the last kept converge with it.
  const int width = dims + std::max(16, dims / 2);
  // Up to ~1,000 rows the exact analysis takes under a second: kept there, so a survey of that
  // size retrieves the candidates it always did.
  constexpr int kExactRows = 1024;
  if (rank <= kExactRows || width * 2 > rank || iterations < 1) return Exact(rows, dims);
  PrincipalAxes p;
  cv::reduce(rows, p.mean, 0, cv::REDUCE_AVG, CV_32F);
  cv::Mat centred(rows.size(), CV_32F);
  for (int r = 0; r < rows.rows; ++r) centred.row(r) = rows.row(r) - p.mean;
  cv::Mat start(rows.cols, width, CV_32F);
  cv::RNG rng(0x5eed);
  rng.fill(start, cv::RNG::NORMAL, 0.0, 1.0);
  // Range of X (X^T X)^q from the random start, re-orthonormalised at each product.
  cv::Mat range = Orthonormal(MatrixProduct(centred, start));
  for (int i = 0; i < iterations; ++i) {
    const cv::Mat back = Orthonormal(MatrixProduct(centred, range, cv::GEMM_1_T));
    range = Orthonormal(MatrixProduct(centred, back));
  }
  // X within that range, B = Q^T X (width x d): its leading right singular vectors are the axes.
  const cv::Mat b = MatrixProduct(range, centred, cv::GEMM_1_T);
  const cv::Mat gram = MatrixProduct(b, b, cv::GEMM_2_T);
  Eigen::MatrixXd g(width, width);
  for (int r = 0; r < width; ++r)
    for (int c = 0; c < width; ++c) g(r, c) = 0.5 * (double(gram.at<float>(r, c)) + gram.at<float>(c, r));
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(g);  // ascending eigenvalues
  cv::Mat u(dims, width, CV_32F);
  for (int k = 0; k < dims; ++k) {
    const int col = width - 1 - k;
    const double s = std::sqrt(std::max(eig.eigenvalues()(col), 1e-30));
    for (int r = 0; r < width; ++r) u.at<float>(k, r) = static_cast<float>(eig.eigenvectors()(r, col) / s);
  }
  p.axes = MatrixProduct(u, b);
  for (int k = 0; k < dims; ++k) {
    const double n = cv::norm(p.axes.row(k));
    if (n > 0) p.axes.row(k) /= n;
  }
  return p;
}

}  // namespace rolamos
