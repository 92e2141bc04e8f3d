// The image description of the object classifier: dense SIFT (as RootSIFT) quantised against a
// visual vocabulary, counted in a spatial pyramid, plus a hue/saturation histogram per pyramid
// cell (deep-sea biota differ as much by colour as by shape). Every part is L1-normalised, so
// the vector suits a chi-square kernel.
#pragma once

#include <random>
#include <vector>

#include <opencv2/core.hpp>

#include "objects/colour_statistics.h"
#include "objects/dihedral.h"
#include "objects/fisher_codebook.h"
#include "rolamos/objects.hpp"

namespace rolamos {

// Any image as BGR 8-bit.
cv::Mat ToBgr8(const cv::Mat& image);
// The sample as the descriptors see it: resized to image_size square, BGR 8-bit.
cv::Mat NormaliseSample(const cv::Mat& image, int image_size);

// 128 (gray SIFT) or 384 (opponent colour SIFT).
int DescriptorSize(const ObjectFeatureOptions& o);

// The dense grid: every patch size at every grid step that fits (size = patch diameter / 6,
// OpenCV's SIFT convention).
std::vector<cv::KeyPoint> DenseKeypoints(cv::Size sample, const ObjectFeatureOptions& o);

// Dense RootSIFT descriptors (rows, CV_32F) of a normalised sample, with each descriptor's
// position (pixels) in `positions` when given.
cv::Mat DenseDescriptors(const cv::Mat& sample, const ObjectFeatureOptions& o,
                         std::vector<cv::Point2f>* positions = nullptr);


// k-means over the rows of `samples` (k-means++ seeding, deterministic for a seed).
cv::Mat BuildVocabulary(const cv::Mat& samples, int words, unsigned seed);

class BowEncoder {
 public:
  // bow and vlad: `vocabulary` is the k-means words; fisher: the codebook's mixture, with `pca`,
  // and (colour_statistics) the colour statistics' own codebook.
  BowEncoder(const ObjectFeatureOptions& options, cv::Mat vocabulary, cv::Mat pca = {}, FisherCodebook colour = {});
  int dims() const;
  // One row (CV_32F) describing `image` (any size, BGR/BGRA/gray).
  cv::Mat Encode(const cv::Mat& image) const;
  const cv::Mat& vocabulary() const { return vocabulary_; }
  const cv::Mat& pca() const { return fisher_.pca; }
  const FisherCodebook& colour_codebook() const { return colour_; }

 private:
  struct Cell {
    cv::Rect2f rect;  // in sample pixels
    float weight;
    int view;         // 0: the whole sample; 1: the square around its object
  };
  static std::vector<Cell> Cells(const ObjectFeatureOptions& o);
  int WordDims() const;    // per cell, the SIFT part
  int ColourFisherDims() const;  // per cell, the colour statistics' Fisher vector (0 without)
  // Accumulates the Fisher statistics of `projected` descriptors (the codebook's space) into the
  // cells of `view`; a cell's block is at v + cell * stride.
  void FisherStatistics(const FisherCodebook& book, const cv::Mat& projected, const std::vector<cv::Point2f>& where,
                        int view, float* v, int stride) const;
  // One view's local descriptions, extracted once for every orientation.
  struct View {
    cv::Mat descriptors, colour, hsv;
    std::vector<cv::Point2f> where;
  };
  // The description of `views` turned by `turn`, normalised, into v (zeroed, dims() long).
  void EncodeInto(const std::vector<View>& views, const DihedralTransform& turn, float* v) const;
  std::vector<int> Orientations() const;  // the dihedral transforms described
  // Projected descriptors with their positions appended (spatial_coordinates), else as given.
  cv::Mat Spatial(const cv::Mat& projected, const std::vector<cv::Point2f>& where) const;

  ObjectFeatureOptions options_;
  cv::Mat vocabulary_;  // words x DescriptorSize, CV_32F (fisher: the mixture, as fisher_.gmm)
  FisherCodebook fisher_;
  FisherCodebook colour_;
  std::vector<Cell> cells_;
};

}  // namespace rolamos
