// The image description of the object classifier: dense SIFT (as RootSIFT) quantised against a
// visual vocabulary, counted in a spatial pyramid, plus a hue/saturation histogram per pyramid
// cell (deep-sea biota differ as much by colour as by shape). Every part is L1-normalised, so
// the vector suits a chi-square kernel.
#pragma once

#include <random>
#include <vector>

#include <opencv2/core.hpp>

#include "objects/fisher_codebook.h"
#include "rolamos/objects.hpp"

namespace rolamos {

// Any image as BGR 8-bit.
cv::Mat ToBgr8(const cv::Mat& image);
// The sample as the descriptors see it: resized to image_size square, BGR 8-bit.
cv::Mat NormaliseSample(const cv::Mat& image, int image_size);

// 128 (gray SIFT) or 384 (opponent colour SIFT).
int DescriptorSize(const ObjectFeatureOptions& o);

// Dense RootSIFT descriptors (rows, CV_32F) of a normalised sample, with each descriptor's
// position (pixels) in `positions` when given.
cv::Mat DenseDescriptors(const cv::Mat& sample, const ObjectFeatureOptions& o,
                         std::vector<cv::Point2f>* positions = nullptr);

// k-means over the rows of `samples` (k-means++ seeding, deterministic for a seed).
cv::Mat BuildVocabulary(const cv::Mat& samples, int words, unsigned seed);

class BowEncoder {
 public:
  // bow and vlad: `vocabulary` is the k-means words; fisher: the codebook's mixture, with `pca`.
  BowEncoder(const ObjectFeatureOptions& options, cv::Mat vocabulary, cv::Mat pca = {});
  int dims() const;
  // One row (CV_32F) describing `image` (any size, BGR/BGRA/gray).
  cv::Mat Encode(const cv::Mat& image) const;
  const cv::Mat& vocabulary() const { return vocabulary_; }
  const cv::Mat& pca() const { return fisher_.pca; }

 private:
  struct Cell {
    cv::Rect2f rect;  // in sample pixels
    float weight;
    int view;         // 0: the whole sample; 1: the square around its object
  };
  static std::vector<Cell> Cells(const ObjectFeatureOptions& o);
  int WordDims() const;  // per cell, before colour
  void FisherStatistics(const cv::Mat& desc, const std::vector<cv::Point2f>& where, int view, float* v) const;

  ObjectFeatureOptions options_;
  cv::Mat vocabulary_;  // words x DescriptorSize, CV_32F (fisher: the mixture, as fisher_.gmm)
  FisherCodebook fisher_;
  std::vector<Cell> cells_;
};

}  // namespace rolamos
