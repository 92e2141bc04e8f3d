// Appearance retrieval over every frame of a survey: each frame's SIFT descriptors as one VLAD
// vector (a small vocabulary learnt from the survey itself, signed square roots, reduced by PCA),
// and for each frame the most similar others. A patch whose start was lost finds its place
// anywhere in the survey this way, not only among the first frames of earlier patches.
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct RetrievalOptions {
  int words = 32;             // vocabulary size
  int dimensions = 128;       // after PCA
  int sample = 40000;         // descriptors the vocabulary and PCA learn from
  int candidates = 5;         // most similar frames per frame
  bool IsValid(std::string* error) const;
};

// Each frame's appearance as one unit vector (a row of CV_32F: VLAD over the survey's own
// vocabulary, reduced by PCA), from `descriptors[i]`, frame i's SIFT descriptors (CV_8U or CV_32F,
// n x 128; may be empty). Empty when the survey is too small to learn from (fewer than three
// frames, or fewer than four descriptors a word).
cv::Mat DescribeFrames(const std::vector<cv::Mat>& descriptors, const RetrievalOptions& options);
// For each frame (a row of DescribeFrames's) its `candidates` most similar others that `allowed`
// lets through: pairs (i, j), i < j, each at most once. Several searches over one survey
// describe it once. `allowed` is called from several threads at once, for the most similar
// others of each frame only.
std::vector<std::pair<int, int>> MostSimilarPairs(const cv::Mat& vectors, int candidates,
                                                  const std::function<bool(int, int)>& allowed);

// Both at once. `descriptors[i]`: frame i's SIFT descriptors (CV_8U or CV_32F, n x 128; may be empty).
// `allowed(i, j)` says whether the pair may be proposed (not the same frame, not neighbours in
// the sequence, not linked already). Returns pairs (i, j), i < j, each at most once.
std::vector<std::pair<int, int>> RetrieveSimilarFrames(const std::vector<cv::Mat>& descriptors,
                                                       const RetrievalOptions& options,
                                                       const std::function<bool(int, int)>& allowed);

}  // namespace rolamos
