// Appearance retrieval over every frame of a survey: each frame's SIFT descriptors as one VLAD
// vector (a small vocabulary learnt from the survey itself, signed square roots, reduced by PCA),
// and for each frame the most similar others. A patch whose start was lost finds its place
// anywhere in the survey this way, not only among the first frames of earlier patches.
#pragma once

#include <string>
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

// `descriptors[i]`: frame i's SIFT descriptors (CV_8U or CV_32F, n x 128; may be empty).
// `allowed(i, j)` says whether the pair may be proposed (not the same frame, not neighbours in
// the sequence, not linked already). Returns pairs (i, j), i < j, each at most once.
std::vector<std::pair<int, int>> RetrieveSimilarFrames(const std::vector<cv::Mat>& descriptors,
                                                       const RetrievalOptions& options,
                                                       const std::function<bool(int, int)>& allowed);

}  // namespace rolamos
