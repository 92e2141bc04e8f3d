#include "objects/fisher_codebook.h"

#include <cmath>

#include "rolamos/error.hpp"
#include "util/matrix_product.h"

namespace rolamos {

namespace {

constexpr float kMinVariance = 1e-4f;  // keeps a component from collapsing onto a few points

// Log-density (without the shared constant) of every row under every component, rows x K:
// -1/2 sum_d (x_d - m_kd)^2 / v_kd - 1/2 sum_d log v_kd + log w_k, by three products.
cv::Mat LogDensities(const cv::Mat& x, const cv::Mat& means, const cv::Mat& variances, const cv::Mat& weights) {
  cv::Mat inv_var = 1.0 / variances;
  cv::Mat x2 = x.mul(x);
  cv::Mat out = MatrixProduct(x, means.mul(inv_var), cv::GEMM_2_T) - 0.5 * MatrixProduct(x2, inv_var, cv::GEMM_2_T);
  cv::Mat log_var;
  cv::log(variances, log_var);
  for (int k = 0; k < means.rows; ++k) {
    const double c = -0.5 * means.row(k).dot(means.row(k).mul(inv_var.row(k))) - 0.5 * cv::sum(log_var.row(k))[0] +
                     std::log(std::max(1e-12f, weights.at<float>(k)));
    out.col(k) += c;
  }
  return out;
}

// Row-wise softmax in place; returns the sum of the rows' log normalisers (the log-likelihood).
double Softmax(cv::Mat& logp) {
  double ll = 0;
  for (int i = 0; i < logp.rows; ++i) {
    float* p = logp.ptr<float>(i);
    float m = p[0];
    for (int k = 1; k < logp.cols; ++k) m = std::max(m, p[k]);
    double s = 0;
    for (int k = 0; k < logp.cols; ++k) s += (p[k] = std::exp(p[k] - m));
    const float inv = static_cast<float>(1.0 / s);
    for (int k = 0; k < logp.cols; ++k) p[k] *= inv;
    ll += m + std::log(s);
  }
  return ll;
}

}  // namespace

bool FisherCodebook::IsValid(int descriptor_size, int appended) const {
  return pca.type() == CV_32F && pca.cols == descriptor_size && pca.rows >= 2 && gmm.type() == CV_32F &&
         gmm.rows >= 1 && gmm.cols == 2 * (dims() + appended) + 1;
}

cv::Mat FisherCodebook::Project(const cv::Mat& descriptors) const {
  cv::Mat centred = descriptors - cv::repeat(pca.row(0), descriptors.rows, 1);
  return MatrixProduct(centred, pca.rowRange(1, pca.rows), cv::GEMM_2_T);
}

cv::Mat FisherCodebook::Posteriors(const cv::Mat& projected) const {
  const int d = mixture_dims();
  CV_Assert(projected.cols == d);
  cv::Mat weights = gmm.col(2 * d).t();
  cv::Mat logp = LogDensities(projected, gmm.colRange(0, d), gmm.colRange(d, 2 * d), weights);
  Softmax(logp);
  return logp;
}

FisherCodebook BuildFisherCodebook(const cv::Mat& samples, int components, int dims, unsigned seed,
                                   const cv::Mat& appended) {
  if (samples.rows < 4 * components || dims < 1 || dims > samples.cols)
    Fail("fisher codebook", std::to_string(samples.rows) + " descriptors cannot fit " + std::to_string(components) +
                                " Gaussians in " + std::to_string(dims) + " dimensions (more training images needed)");
  FisherCodebook book;
  cv::PCA pca(samples, cv::noArray(), cv::PCA::DATA_AS_ROW, dims);
  book.pca.create(dims + 1, samples.cols, CV_32F);
  pca.mean.convertTo(book.pca.row(0), CV_32F);
  pca.eigenvectors.convertTo(book.pca.rowRange(1, dims + 1), CV_32F);
  cv::Mat x = book.Project(samples);
  if (!appended.empty()) {
    CV_Assert(appended.rows == samples.rows && appended.type() == CV_32F);
    cv::hconcat(x, appended, x);
    dims = x.cols;
  }

  // Start from k-means: means at the centres, each component's variance that of its points.
  cv::setRNGSeed(static_cast<int>(seed));
  cv::Mat labels, means;
  cv::kmeans(x, components, labels, cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 20, 1e-4), 1,
             cv::KMEANS_PP_CENTERS, means);
  cv::Mat variances(components, dims, CV_32F, cv::Scalar(0)), weights(1, components, CV_32F, cv::Scalar(0));
  for (int i = 0; i < x.rows; ++i) {
    const int k = labels.at<int>(i);
    cv::Mat diff = x.row(i) - means.row(k);
    variances.row(k) += diff.mul(diff);
    weights.at<float>(k) += 1;
  }
  for (int k = 0; k < components; ++k) {
    variances.row(k) /= std::max(1.0f, weights.at<float>(k));
    weights.at<float>(k) /= static_cast<float>(x.rows);
  }
  variances = cv::max(variances, kMinVariance);

  // EM with diagonal covariances, every step as matrix products.
  const cv::Mat x2 = x.mul(x);
  double previous = -1e300;
  for (int iteration = 0; iteration < 40; ++iteration) {
    cv::Mat post = LogDensities(x, means, variances, weights);
    const double ll = Softmax(post) / x.rows;
    cv::Mat nk;
    cv::reduce(post, nk, 0, cv::REDUCE_SUM, CV_32F);  // 1 x K
    const cv::Mat s1 = MatrixProduct(post, x, cv::GEMM_1_T);   // K x D
    const cv::Mat s2 = MatrixProduct(post, x2, cv::GEMM_1_T);  // K x D
    for (int k = 0; k < components; ++k) {
      const float n = std::max(nk.at<float>(k), 1e-3f);
      means.row(k) = s1.row(k) / n;
      cv::Mat v = s2.row(k) / n - means.row(k).mul(means.row(k));
      v = cv::max(v, kMinVariance);
      v.copyTo(variances.row(k));
      weights.at<float>(k) = n / static_cast<float>(x.rows);
    }
    if (std::abs(ll - previous) < 1e-4 * std::abs(ll)) break;
    previous = ll;
  }
  book.gmm.create(components, 2 * dims + 1, CV_32F);
  means.copyTo(book.gmm.colRange(0, dims));
  variances.copyTo(book.gmm.colRange(dims, 2 * dims));
  cv::Mat(weights.t()).copyTo(book.gmm.col(2 * dims));
  return book;
}

}  // namespace rolamos
