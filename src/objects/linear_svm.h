// A linear SVM with the squared hinge loss, trained by dual coordinate descent (Hsieh et al.,
// "A dual coordinate descent method for large-scale linear SVM", ICML 2008, as LIBLINEAR's
// L2R_L2LOSS_SVC_DUAL). Sliding-window detectors train on tens of thousands of windows with
// hundreds of dimensions: a kernel solver (OpenCV's SMO) would take minutes for what this does
// in seconds.
#pragma once

#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

struct LinearSvmOptions {
  double c_positive = 0.01, c_negative = 0.01;  // per-class costs (class weights)
  double bias = 1.0;        // value of the constant feature the bias is learnt on
  int max_epochs = 300;
  double tolerance = 0.05;  // stop when the projected gradient's spread falls below it
  unsigned seed = 1;
};

struct LinearSvm {
  std::vector<float> weights;  // one per feature
  double bias = 0;             // decision = weights . x + bias
  int epochs = 0;
  double Decision(const float* x) const;
};

// `samples`: one row per sample (CV_32F); `positive`: its label.
LinearSvm TrainLinearSvm(const cv::Mat& samples, const std::vector<bool>& positive, const LinearSvmOptions& options);
// The same over rows held elsewhere (`dims` floats each), without copying them.
LinearSvm TrainLinearSvm(const std::vector<const float*>& rows, int dims, const std::vector<bool>& positive,
                         const LinearSvmOptions& options);

}  // namespace rolamos
