#include "objects/linear_svm.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include "rolamos/error.hpp"

namespace rolamos {

double LinearSvm::Decision(const float* x) const {
  double s = bias;
  for (size_t i = 0; i < weights.size(); ++i) s += double(weights[i]) * double(x[i]);
  return s;
}

LinearSvm TrainLinearSvm(const cv::Mat& samples, const std::vector<bool>& positive, const LinearSvmOptions& o) {
  if (samples.type() != CV_32F || samples.rows != static_cast<int>(positive.size()))
    Fail("linear SVM", "needs one CV_32F row per label");
  std::vector<const float*> rows;
  for (int i = 0; i < samples.rows; ++i) rows.push_back(samples.ptr<float>(i));
  return TrainLinearSvm(rows, samples.cols, positive, o);
}

LinearSvm TrainLinearSvm(const std::vector<const float*>& rows, int dims, const std::vector<bool>& positive,
                         const LinearSvmOptions& o) {
  if (rows.size() != positive.size()) Fail("linear SVM", "needs one row per label");
  const int n = static_cast<int>(rows.size()), d = dims;
  // w holds the bias as its last element, learnt on the constant feature o.bias.
  std::vector<double> w(static_cast<size_t>(d) + 1, 0.0), alpha(static_cast<size_t>(n), 0.0), diag(static_cast<size_t>(n)),
      qii(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const float* x = rows[static_cast<size_t>(i)];
    double q = o.bias * o.bias;
    for (int j = 0; j < d; ++j) q += double(x[j]) * double(x[j]);
    diag[static_cast<size_t>(i)] = 0.5 / (positive[static_cast<size_t>(i)] ? o.c_positive : o.c_negative);
    qii[static_cast<size_t>(i)] = q + diag[static_cast<size_t>(i)];
  }
  std::vector<int> order(static_cast<size_t>(n));
  std::iota(order.begin(), order.end(), 0);
  std::mt19937 rng(o.seed);
  LinearSvm out;
  for (out.epochs = 1; out.epochs <= o.max_epochs; ++out.epochs) {
    std::shuffle(order.begin(), order.end(), rng);
    double pg_max = -HUGE_VAL, pg_min = HUGE_VAL;
    for (int i : order) {
      const float* x = rows[static_cast<size_t>(i)];
      const double y = positive[static_cast<size_t>(i)] ? 1.0 : -1.0;
      double wx = w[static_cast<size_t>(d)] * o.bias;
      for (int j = 0; j < d; ++j) wx += w[static_cast<size_t>(j)] * double(x[j]);
      double& a = alpha[static_cast<size_t>(i)];
      const double g = y * wx - 1.0 + diag[static_cast<size_t>(i)] * a;
      const double pg = a == 0 ? std::min(g, 0.0) : g;
      pg_max = std::max(pg_max, pg);
      pg_min = std::min(pg_min, pg);
      if (std::abs(pg) < 1e-12) continue;
      const double next = std::max(a - g / qii[static_cast<size_t>(i)], 0.0);
      const double step = (next - a) * y;
      a = next;
      for (int j = 0; j < d; ++j) w[static_cast<size_t>(j)] += step * double(x[j]);
      w[static_cast<size_t>(d)] += step * o.bias;
    }
    if (pg_max - pg_min < o.tolerance) break;
  }
  out.weights.assign(w.begin(), w.end() - 1);
  out.bias = w.back() * o.bias;
  return out;
}

}  // namespace rolamos
