// The image description of the object classifier: dense SIFT (as RootSIFT) in one or two views
// (the whole sample, the square around its object), encoded against a visual vocabulary (word
// counts, VLAD or Fisher vectors) per spatial cell, with colour (local colour statistics in
// their own Fisher vectors, or hue/saturation histograms), averaged over the sample's
// orientations. Word counts and histograms are L1-normalised (chi-square kernel); VLAD and
// Fisher parts are power- and L2-normalised (linear or RBF).
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

// Dense RootSIFT descriptors (rows, CV_32F) of a normalised sample at `keypoints`.
cv::Mat DenseDescriptors(const cv::Mat& sample, const ObjectFeatureOptions& o, const std::vector<cv::KeyPoint>& keypoints);

// One view of an image as the encoder reads it: its local descriptions on the dense grid.
struct SampleView {
  cv::Mat descriptors;              // RootSIFT, one row per grid point
  cv::Mat colour;                   // colour statistics per grid point (colour_statistics only)
  cv::Mat hsv;                      // the sample in HSV (hue_bins > 0 only)
  std::vector<cv::Point2f> where;   // grid points, sample pixels
};
// The views described: the whole sample, and (object_view) the square around its object.
std::vector<SampleView> DescribeViews(const cv::Mat& image, const ObjectFeatureOptions& o);

// Grid points as the columns spatial_coordinates appends to projected descriptors: x and y in
// -0.5..0.5 of the sample (rows x 2, CV_32F).
cv::Mat PlaceColumns(const std::vector<cv::Point2f>& where, int image_size);

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
  // The description of `views` (extracted once for every orientation) turned by `turn`,
  // normalised, into v (zeroed, dims() long).
  void EncodeInto(const std::vector<SampleView>& views, const DihedralTransform& turn, float* v) const;
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
