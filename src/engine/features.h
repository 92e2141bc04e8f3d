// Stage 2a: features and matching. SIFT by default (SURF, the paper's choice, is not in
// Debian's OpenCV); ORB and AKAZE for speed. Matching is kNN with Lowe's ratio test and a
// cross-check (a match must be mutual), the paper's "cross-matching approach".
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

namespace rolamos {

struct FeatureOptions {
  std::string type = "sift";  // sift | orb | akaze
  int max_features = 1000;
  // Features are found on the frame resized by this; 0 = by frame size, so that the detection
  // image holds about `detect_pixels` (small frames are not shrunk into uselessness, large ones
  // do not cost more than they bring).
  double detect_scale = 0;
  double detect_pixels = 0.16e6;
  // SIFT's contrast threshold: low, so that dark and hazy seafloor still yields features; the
  // strongest `max_features` are kept.
  double contrast_threshold = 0.005;
  double min_response = 0.008;  // what counts as a strong feature (SIFT's response)
  // SIFT's first octave on the detection image doubled in size (OpenCV's SIFT always does it):
  // four times the detection image's pixels, for the finest and best-placed features. Off: the
  // keypoints are found on the detection image halved (its doubled octave is the detection
  // image's own size) and described on the detection image: half the time, 30-60 % more error
  // within each patch; at twice the detection pixels still worse than doubled, and slower
  // (bench/RESULTS.md, session 36).
  bool double_first_octave = true;
  double ratio = 0.8;         // Lowe's ratio test
  bool cross_check = true;

  bool IsValid(std::string* error) const;
  // The scale of the detection image for frames of `frame`.
  double ScaleFor(cv::Size frame) const;
};

struct Features {
  std::vector<cv::Point2f> points;  // in full-resolution frame pixels
  cv::Mat descriptors;
  int norm = cv::NORM_L2;  // or cv::NORM_HAMMING (ORB, AKAZE: binary descriptors)
  // Features that stand out from sensor noise (SIFT response >= FeatureOptions::min_response):
  // a frame of open water or a black frame yields plenty of features at a low threshold, but no
  // strong ones.
  int strong = 0;
  bool empty() const { return points.empty(); }
};

class FeatureExtractor {
 public:
  explicit FeatureExtractor(const FeatureOptions& options);
  // `gray` is a frame's detection image (8-bit, contrast-normalised) at full resolution.
  Features Extract(const cv::Mat& gray) const;
  // The same, from a detection image already reduced to `scale` of the frame (ScaleFor), with
  // an optional mask of the pixels to use (same size, 0 = left out: static overlays).
  Features ExtractScaled(const cv::Mat& small, double scale, const cv::Mat& mask = cv::Mat()) const;
  const FeatureOptions& options() const { return options_; }

 private:
  // SIFT with a low contrast threshold finds thousands of candidates on textured ground and
  // keeps the strongest `max_features`; orienting the candidates it drops costs a third of its
  // time. Each extraction starts from a threshold under the weakest response the last one kept,
  // and goes down to the options' threshold when that leaves too few: the same features, found
  // once on steady ground, twice where the texture drops. (Where FindSift has its fast path, it
  // orients only the strongest candidates itself, and one extraction at the threshold suffices.)
  std::vector<cv::KeyPoint> DetectSift(const cv::Mat& image, const cv::Mat& mask, cv::Mat* descriptors) const;
  static constexpr float kStartMargin = 0.6f;

  FeatureOptions options_;
  // Shared by copies and by the threads that extract at once: a starting point only, which
  // changes how fast, not what, features are found.
  std::shared_ptr<std::atomic<float>> start_contrast_ = std::make_shared<std::atomic<float>>(0.0f);
};

struct Matches {
  std::vector<cv::Point2f> from, to;  // from[i] in the first set matches to[i] in the second
};

// kNN (k = 2) both ways, ratio test, and (optionally) mutual-best check. SIFT's descriptors may be
// float or bytes (as stored: no copy in float for every pair `align` tries), the same matches.
Matches MatchFeatures(const Features& a, const Features& b, const FeatureOptions& options);

// Float descriptors' squared distances, a's rows by b's (cv::batchDistance's NORM_L2SQR matrix;
// for SIFT's whole-number descriptors its values to the bit). SIFT's descriptors as stored, in
// bytes, give the same values as the same numbers in float.
cv::Mat SquaredDistanceMatrix(const Features& a, const Features& b);

// The distance of a's descriptor i from b's descriptor j, cv::norm(..., a.norm)'s value.
double DescriptorDistance(const Features& a, int i, const Features& b, int j);

}  // namespace rolamos
