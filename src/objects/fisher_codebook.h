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
  // K x (2M + 1), CV_32F: each component's mean (M), variance (M), weight (1). M is D, or more
  // when the encoder appends values of its own to the projected descriptors (their positions).
  cv::Mat gmm;

  int dims() const { return pca.rows - 1; }            // D, after PCA
  int mixture_dims() const { return (gmm.cols - 1) / 2; }  // M
  int components() const { return gmm.rows; }
  // `appended`: the values the encoder appends after projection (M = D + appended).
  bool IsValid(int descriptor_size, int appended = 0) const;
  // Descriptors (rows) -> PCA space (rows of D).
  cv::Mat Project(const cv::Mat& descriptors) const;
  // Posterior of every component for every row of M values (rows x K, CV_32F).
  cv::Mat Posteriors(const cv::Mat& projected) const;
};

// PCA to `dims`, then EM (diagonal covariances, started from k-means) with `components`
// Gaussians over the rows of `samples`, with the columns of `appended` (rows x A, CV_32F) joined
// after projection when given. Deterministic for a seed.
FisherCodebook BuildFisherCodebook(const cv::Mat& samples, int components, int dims, unsigned seed,
                                   const cv::Mat& appended = {});

}  // namespace rolamos
