// One SVM per class against all the others (the paper's one-vs-all). The kernel (chi-square,
// RBF or linear) is computed once for every pair of training samples; OpenCV's SMO solver then
// trains on it through a lookup kernel, so the cross-validation of C and gamma (stratified
// k-fold, scored by the one-vs-all decision over every class) costs table lookups, not kernel
// evaluations. The model keeps the support vectors once, shared by the classes, with each
// class's coefficients: a score is one kernel row and a dot product per class.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

namespace rolamos {

struct OneVsAllOptions {
  std::string kernel = "chi2";  // chi2, rbf or linear
  int folds = 5;
  std::vector<double> c_grid = {0.125, 0.5, 2, 8, 32, 128};
  std::vector<double> gamma_factors = {0.5, 1, 2};  // times 1 / mean pairwise distance
  unsigned seed = 1;
  // What the folds choose C (and gamma) by: "accuracy" (share of samples right) or "balanced"
  // (the mean of the classes' recalls, so a class of 20 images weighs as much as one of 300;
  // each class's decision then also gets an offset, fitted on the same held-out scores to raise
  // the mean recall).
  std::string select_by = "accuracy";
};

class OneVsAll {
 public:
  // `features`: one row per sample (CV_32F, non-negative for chi2); `labels`: class per row.
  // Classes flagged in `negatives_only` get no SVM (they are every SVM's "others").
  void Train(const cv::Mat& features, const std::vector<int>& labels, int classes,
             const std::vector<bool>& negatives_only, const OneVsAllOptions& options,
             const std::function<void(int, int)>& progress = {});
  // Each class's decision value for one row (> 0: that class); -infinity without an SVM.
  std::vector<double> Scores(const cv::Mat& row) const;
  int classes() const { return static_cast<int>(trained_.size()); }
  // Kernel, C, gamma, cross-validated accuracy, support vectors.
  nlohmann::json Describe() const;

  void Write(cv::FileStorage& fs) const;
  void Read(const cv::FileNode& node, const std::string& where);

 private:
  int kernel_ = 0;               // cv::ml::SVM kernel type
  double c_ = 1, gamma_ = 1;
  double cv_accuracy_ = 0;
  cv::Mat support_;              // support vectors, one per row (CV_32F); linear: one weight vector per class
  cv::Mat coefficients_;         // classes x support (CV_64F); zero rows for negatives-only; linear: identity
  std::vector<int> support_counts_;  // support vectors per class, as trained
  int support_total_ = 0;
  std::vector<double> rho_;      // per class, its offset included
  std::vector<double> offsets_;  // per class, added to its decision (select_by "balanced")
  double cv_balanced_after_offsets_ = 0;  // mean recall of the held-out scores with the offsets
  std::vector<bool> trained_;
};

}  // namespace rolamos
