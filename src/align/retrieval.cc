#include "align/retrieval.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <set>

#include <Eigen/Dense>
#include <opencv2/core.hpp>

#include "rolamos/error.hpp"
#include "util/parallel_for.h"
#include "util/principal_axes.h"

namespace rolamos {

bool RetrievalOptions::IsValid(std::string* error) const {
  if (words < 2 || words > 1024 || dimensions < 8 || sample < 100 || candidates < 1) {
    *error = "retrieval settings are out of range (2..1024 words, at least 8 dimensions and 1 candidate)";
    return false;
  }
  return true;
}

namespace {

cv::Mat AsFloat(const cv::Mat& d) {
  if (d.type() == CV_32F) return d;
  cv::Mat f;
  d.convertTo(f, CV_32F);
  return f;
}

// VLAD of one frame: per word, the sum of its descriptors' residuals, each word's block
// normalised (burstiness), signed square roots, then the whole to unit length.
cv::Mat Vlad(const cv::Mat& descriptors, const cv::Mat& words) {
  cv::Mat v = cv::Mat::zeros(1, words.rows * words.cols, CV_32F);
  if (descriptors.empty()) return v;
  const cv::Mat d = AsFloat(descriptors);
  cv::Mat dist;
  cv::batchDistance(d, words, dist, CV_32F, cv::noArray(), cv::NORM_L2SQR);
  for (int i = 0; i < d.rows; ++i) {
    cv::Point best;
    cv::minMaxLoc(dist.row(i), nullptr, nullptr, &best, nullptr);
    float* block = v.ptr<float>() + best.x * words.cols;
    const float* x = d.ptr<float>(i);
    const float* c = words.ptr<float>(best.x);
    for (int k = 0; k < words.cols; ++k) block[k] += x[k] - c[k];
  }
  for (int w = 0; w < words.rows; ++w) {
    cv::Mat block = v.colRange(w * words.cols, (w + 1) * words.cols);
    const double n = cv::norm(block);
    if (n > 0) block /= n;
  }
  for (int k = 0; k < v.cols; ++k) {
    float& x = v.at<float>(k);
    x = std::copysign(std::sqrt(std::abs(x)), x);
  }
  const double n = cv::norm(v);
  if (n > 0) v /= n;
  return v;
}

}  // namespace

cv::Mat DescribeFrames(const std::vector<cv::Mat>& descriptors, const RetrievalOptions& o) {
  std::string error;
  if (!o.IsValid(&error)) Fail("retrieval", error);
  const int n = static_cast<int>(descriptors.size());
  long long total = 0;
  for (const auto& d : descriptors) total += d.rows;
  if (n < 2 || total < o.words * 4) return {};
  // 1. Vocabulary from a sample spread over the survey.
  const double keep = std::min(1.0, double(o.sample) / double(total));
  cv::Mat sample;
  for (int i = 0; i < n; ++i) {
    const cv::Mat& d = descriptors[size_t(i)];
    const int take = std::max(d.rows > 0 ? 1 : 0, static_cast<int>(std::lround(d.rows * keep)));
    for (int r = 0; r < take; ++r) {
      const int row = static_cast<int>((long long)r * d.rows / std::max(1, take));
      cv::Mat f = AsFloat(d.row(row));
      sample.push_back(f);
    }
  }
  cv::Mat labels, words;
  cv::theRNG().state = 0x5eed;  // the same vocabulary every run: align is repeatable
  cv::kmeans(sample, std::min(o.words, sample.rows), labels,
             cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 12, 1e-3), 1, cv::KMEANS_PP_CENTERS, words);
  // 2. VLAD of every frame, reduced by PCA learnt from a spread of frames.
  cv::Mat vlad(n, words.rows * words.cols, CV_32F);
  ParallelFor(n, [&](long long i, int) { Vlad(descriptors[size_t(i)], words).copyTo(vlad.row(static_cast<int>(i))); });
  const int learn = std::min(n, 3000);
  cv::Mat learn_rows;
  for (int k = 0; k < learn; ++k) learn_rows.push_back(vlad.row(static_cast<int>((long long)k * n / learn)));
  const int dims = std::min({o.dimensions, learn - 1, vlad.cols});
  if (dims < 2) return {};
  cv::Mat vectors(n, dims, CV_32F);
  const cv::Mat projected = FindPrincipalAxes(learn_rows, dims).Project(vlad);
  for (int i = 0; i < n; ++i) {
    const float* p = projected.ptr<float>(i);
    double norm = 0;
    for (int k = 0; k < dims; ++k) norm += double(p[k]) * p[k];
    norm = norm > 0 ? 1.0 / std::sqrt(norm) : 0.0;
    float* d = vectors.ptr<float>(i);
    for (int k = 0; k < dims; ++k) d[k] = static_cast<float>(p[k] * norm);
  }
  return vectors;
}

std::vector<std::pair<int, int>> MostSimilarPairs(const cv::Mat& vectors, int candidates,
                                                  const std::function<bool(int, int)>& allowed) {
  if (vectors.empty() || candidates <= 0) return {};
  CV_Assert(vectors.type() == CV_32F && vectors.isContinuous());
  const int n = vectors.rows;
  const Eigen::Map<const Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> D(
      vectors.ptr<float>(), vectors.rows, vectors.cols);
  // For every frame its most similar allowed others, block by block (memory stays small), the
  // rows of a block on every core. Each row's others are taken in order of similarity (ties by
  // the higher index, as a sort of (similarity, index) pairs) until `candidates` are allowed:
  // the most similar are mostly its neighbours in the sequence, a few dozen, so `allowed` is
  // asked of a few others per frame, not of all of them.
  std::vector<std::vector<int>> best(static_cast<size_t>(n));
  constexpr int kBlock = 512;
  for (int b0 = 0; b0 < n; b0 += kBlock) {
    const int rows = std::min(kBlock, n - b0);
    const Eigen::MatrixXf S = D.middleRows(b0, rows) * D.transpose();
    ParallelFor(rows, [&](long long r, int) {
      const int i = b0 + static_cast<int>(r);
      std::vector<std::pair<float, int>> order;
      order.reserve(static_cast<size_t>(n));
      for (int j = 0; j < n; ++j)
        if (j != i) order.emplace_back(S(r, j), j);
      std::vector<int>& kept = best[size_t(i)];
      size_t sorted = 0;
      for (size_t next = 0; next < order.size() && kept.size() < size_t(candidates); ++next) {
        if (next == sorted) {  // the next stretch of the order, twice as long as the last
          const size_t end = std::min(order.size(), std::max<size_t>(64, 2 * sorted));
          std::nth_element(order.begin() + long(sorted), order.begin() + long(end - 1), order.end(), std::greater<>());
          std::sort(order.begin() + long(sorted), order.begin() + long(end), std::greater<>());
          sorted = end;
        }
        if (allowed(i, order[next].second)) kept.push_back(order[next].second);
      }
    });
  }
  std::set<std::pair<int, int>> pairs;
  for (int i = 0; i < n; ++i)
    for (const int j : best[size_t(i)]) pairs.emplace(std::min(i, j), std::max(i, j));
  return {pairs.begin(), pairs.end()};
}

std::vector<std::pair<int, int>> RetrieveSimilarFrames(const std::vector<cv::Mat>& descriptors,
                                                       const RetrievalOptions& o,
                                                       const std::function<bool(int, int)>& allowed) {
  return MostSimilarPairs(DescribeFrames(descriptors, o), o.candidates, allowed);
}

}  // namespace rolamos
