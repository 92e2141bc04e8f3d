// The codebook of Fisher-vector encoding (Perronnin et al., "improved" Fisher vectors): the
// descriptors are reduced by PCA, then modelled by a Gaussian mixture with diagonal covariances;
// an image is described by the gradients of the mixture's log-likelihood with respect to its
// means and variances (first and second order statistics of the descriptors per component), which
// carry more than a word count (BoW) or a residual sum (VLAD) for the same number of words.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

struct FisherCodebook {
  cv::Mat pca;   // (D + 1) x descriptor size, CV_32F: row 0 the mean, then D basis rows
  cv::Mat gmm;   // K x (2D + 1), CV_32F: each component's mean (D), variance (D), weight (1)

  int dims() const { return pca.rows - 1; }
  int components() const { return gmm.rows; }
  bool IsValid(int descriptor_size) const;
  // Descriptors (rows) -> PCA space (rows of D).
  cv::Mat Project(const cv::Mat& descriptors) const;
  // Posterior of every component for every projected row (rows x K, CV_32F).
  cv::Mat Posteriors(const cv::Mat& projected) const;
};

// PCA to `dims`, then EM (diagonal covariances, started from k-means) with `components`
// Gaussians over the rows of `samples`. Deterministic for a seed.
FisherCodebook BuildFisherCodebook(const cv::Mat& samples, int components, int dims, unsigned seed);

}  // namespace rolamos
