#include "objects/one_vs_all.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <random>

#include <opencv2/ml.hpp>

#include "rolamos/error.hpp"
#include "util/matrix_product.h"

namespace rolamos {

namespace {

int KernelType(const std::string& kernel) {
  if (kernel == "chi2") return cv::ml::SVM::CHI2;
  if (kernel == "rbf") return cv::ml::SVM::RBF;
  if (kernel == "linear") return cv::ml::SVM::LINEAR;
  Fail("kernel", "\"" + kernel + "\" is not chi2, rbf or linear");
}

std::string KernelName(int type) {
  return type == cv::ml::SVM::CHI2 ? "chi2" : type == cv::ml::SVM::RBF ? "rbf" : "linear";
}

// The kernel's distance (chi2, squared L2) or, for linear, the dot product, of two rows.
double Pairwise(int type, const float* a, const float* b, int n) {
  double s = 0;
  if (type == cv::ml::SVM::CHI2) {
    for (int k = 0; k < n; ++k) {
      const double sum = a[k] + b[k];
      if (sum > 0) s += (a[k] - b[k]) * (a[k] - b[k]) / sum;
    }
  } else if (type == cv::ml::SVM::RBF) {
    for (int k = 0; k < n; ++k) s += (a[k] - b[k]) * (a[k] - b[k]);
  } else {
    for (int k = 0; k < n; ++k) s += a[k] * b[k];
  }
  return s;
}

double KernelValue(int type, double pairwise, double gamma) {
  return type == cv::ml::SVM::LINEAR ? pairwise : std::exp(-gamma * pairwise);
}

// Samples are one number, their row in a Gram matrix: the solver's kernel calls become lookups.
class GramKernel : public cv::ml::SVM::Kernel {
 public:
  explicit GramKernel(const cv::Mat* gram) : gram_(gram) {}
  int getType() const override { return cv::ml::SVM::CUSTOM; }
  void calc(int vcount, int n, const float* vecs, const float* another, float* results) override {
    const float* row = gram_->ptr<float>(static_cast<int>(another[0]));
    for (int i = 0; i < vcount; ++i) results[i] = row[static_cast<int>(vecs[static_cast<size_t>(i) * n])];
  }

 private:
  const cv::Mat* gram_;
};

struct Fit {
  std::vector<int> support;     // sample indices
  std::vector<double> alpha;    // oriented so that decision > 0 means the class
  double rho = 0;
};

// Trains one class against the rest on `rows` (sample indices) with a Gram-lookup kernel.
Fit TrainOne(const cv::Mat& gram, const std::vector<int>& rows, const std::vector<int>& labels, int cls, double c) {
  cv::Mat x(static_cast<int>(rows.size()), 1, CV_32F), y(static_cast<int>(rows.size()), 1, CV_32S);
  int positives = 0;
  for (size_t i = 0; i < rows.size(); ++i) {
    x.at<float>(static_cast<int>(i)) = static_cast<float>(rows[i]);
    const bool pos = labels[static_cast<size_t>(rows[i])] == cls;
    y.at<int>(static_cast<int>(i)) = pos ? 1 : -1;
    positives += pos;
  }
  const int negatives = static_cast<int>(rows.size()) - positives;
  Fit f;
  if (positives == 0 || negatives == 0) return f;
  auto svm = cv::ml::SVM::create();
  svm->setType(cv::ml::SVM::C_SVC);
  svm->setCustomKernel(cv::makePtr<GramKernel>(&gram));
  svm->setC(c);
  svm->setTermCriteria(cv::TermCriteria(cv::TermCriteria::MAX_ITER + cv::TermCriteria::EPS, 10000, 1e-4));
  // Balanced: each side weighs as much in total (weights follow the sorted labels -1, +1).
  svm->setClassWeights((cv::Mat_<double>(2, 1) << 0.5 * rows.size() / negatives, 0.5 * rows.size() / positives));
  svm->train(cv::ml::TrainData::create(x, cv::ml::ROW_SAMPLE, y));
  cv::Mat alpha, svidx;
  f.rho = svm->getDecisionFunction(0, alpha, svidx);
  const cv::Mat sv = svm->getSupportVectors();
  for (int k = 0; k < svidx.cols * svidx.rows; ++k) {
    f.support.push_back(static_cast<int>(sv.at<float>(svidx.at<int>(k), 0)));
    f.alpha.push_back(alpha.at<double>(k));
  }
  // OpenCV signs the decision by its internal label order: orient it on a positive sample.
  int probe = -1;
  for (int r : rows)
    if (labels[static_cast<size_t>(r)] == cls) {
      probe = r;
      break;
    }
  double raw = -f.rho;
  for (size_t k = 0; k < f.support.size(); ++k) raw += f.alpha[k] * gram.at<float>(probe, f.support[k]);
  const float predicted = svm->predict(cv::Mat(1, 1, CV_32F, cv::Scalar(static_cast<float>(probe))));
  if ((predicted > 0) != (raw > 0)) {
    for (auto& a : f.alpha) a = -a;
    f.rho = -f.rho;
  }
  return f;
}

double Decision(const Fit& f, const cv::Mat& gram, int sample) {
  double s = -f.rho;
  const float* row = gram.ptr<float>(sample);
  for (size_t k = 0; k < f.support.size(); ++k) s += f.alpha[k] * row[f.support[k]];
  return s;
}

// Out-of-fold decision values: one row per sample, one column per class with an SVM.
struct FoldScores {
  cv::Mat values;                      // n x scored (CV_64F)
  std::vector<int> scored;             // the class of each column
  std::vector<int> truth;              // per sample: its class, or -2 (background)
  bool with_background = false;
};

// The one-vs-all decision: the class whose SVM scores highest after its offset (background when
// none is positive and the data has a background class).
int Decide(const FoldScores& f, int sample, const std::vector<double>& offsets) {
  int winner = -1;
  double top = -std::numeric_limits<double>::infinity();
  const double* row = f.values.ptr<double>(sample);
  for (size_t s = 0; s < f.scored.size(); ++s) {
    const double d = row[s] + offsets[s];
    if (d > top) {
      top = d;
      winner = f.scored[s];
    }
  }
  return f.with_background && top < 0 ? -2 : winner;
}

// Share of samples right, or (balanced) the mean of the classes' recalls.
double Agreement(const FoldScores& f, const std::vector<double>& offsets, bool balanced) {
  std::map<int, std::pair<int, int>> per_class;  // truth -> (right, seen)
  int correct = 0;
  for (int i = 0; i < f.values.rows; ++i) {
    const int truth = f.truth[static_cast<size_t>(i)];
    const bool right = Decide(f, i, offsets) == truth;
    correct += right;
    per_class[truth].first += right;
    ++per_class[truth].second;
  }
  if (!balanced) return double(correct) / std::max(1, f.values.rows);
  double recall = 0;
  for (const auto& [truth, rs] : per_class) recall += double(rs.first) / rs.second;
  return recall / double(std::max<size_t>(1, per_class.size()));
}

// Offsets added to each class's decision, chosen on the out-of-fold decisions: SVMs trained one
// against all score on scales of their own, and a rare class (20 images among 1,400) rarely wins
// the argmax even when its SVM ranks its images first. The fit raises the mean of accuracy and
// mean recall: mean recall alone, fitted on 20 crabs a fold, called 88 images crab to find 8.
// Coordinate ascent over a grid of offsets, smallest change first on ties.
double OffsetObjective(const FoldScores& f, const std::vector<double>& offsets) {
  return 0.5 * (Agreement(f, offsets, false) + Agreement(f, offsets, true));
}

std::vector<double> FitOffsets(const FoldScores& f) {
  std::vector<double> offsets(f.scored.size(), 0.0), grid;
  for (int k = -20; k <= 20; ++k) grid.push_back(0.05 * k);
  std::sort(grid.begin(), grid.end(), [](double a, double b) { return std::abs(a) < std::abs(b); });
  double best = OffsetObjective(f, offsets);
  for (int round = 0; round < 3; ++round) {
    bool changed = false;
    for (size_t s = 0; s < offsets.size(); ++s) {
      const double was = offsets[s];
      double pick = was;
      for (double g : grid) {
        offsets[s] = g;
        const double score = OffsetObjective(f, offsets);
        if (score > best + 1e-12) {
          best = score;
          pick = g;
        }
      }
      offsets[s] = pick;
      changed |= pick != was;
    }
    if (!changed) break;
  }
  return offsets;
}

}  // namespace

void OneVsAll::Train(const cv::Mat& features, const std::vector<int>& labels, int classes,
                     const std::vector<bool>& negatives_only, const OneVsAllOptions& o,
                     const std::function<void(int, int)>& progress) {
  CV_Assert(features.rows == static_cast<int>(labels.size()) && features.type() == CV_32F);
  if (o.folds < 2 || o.c_grid.empty()) Fail("training", "cross-validation needs 2 or more folds and a C grid");
  kernel_ = KernelType(o.kernel);
  const int n = features.rows;
  // Pairwise distances (or dot products), once, on every core.
  cv::Mat pairwise(n, n, CV_32F);
  if (kernel_ == cv::ml::SVM::LINEAR) {
    pairwise = MatrixProduct(features, features, cv::GEMM_2_T);
  } else cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i)
      for (int j = 0; j <= i; ++j) {
        const float v = static_cast<float>(Pairwise(kernel_, features.ptr<float>(i), features.ptr<float>(j), features.cols));
        pairwise.at<float>(i, j) = v;
        pairwise.at<float>(j, i) = v;
      }
  });
  double mean = 0;
  if (kernel_ != cv::ml::SVM::LINEAR) mean = cv::mean(pairwise)[0] * n / std::max(1, n - 1);
  std::vector<double> gammas = {1.0};
  if (kernel_ != cv::ml::SVM::LINEAR) {
    gammas.clear();
    for (double f : o.gamma_factors) gammas.push_back(f / std::max(mean, 1e-12));
  }
  // Stratified folds: every class spread over the folds, shuffled by the seed.
  std::vector<int> fold(static_cast<size_t>(n));
  {
    std::mt19937 rng(o.seed);
    std::map<int, std::vector<int>> by_class;
    for (int i = 0; i < n; ++i) by_class[labels[static_cast<size_t>(i)]].push_back(i);
    for (auto& [c, members] : by_class) {
      std::shuffle(members.begin(), members.end(), rng);
      for (size_t k = 0; k < members.size(); ++k) fold[static_cast<size_t>(members[k])] = static_cast<int>(k % o.folds);
    }
  }
  std::vector<int> scored;  // classes that get an SVM
  for (int c = 0; c < classes; ++c)
    if (!negatives_only[static_cast<size_t>(c)]) scored.push_back(c);
  FoldScores folds_scored;
  folds_scored.scored = scored;
  folds_scored.with_background = static_cast<int>(scored.size()) < classes;
  for (int i = 0; i < n; ++i) {
    const int label = labels[static_cast<size_t>(i)];
    folds_scored.truth.push_back(negatives_only[static_cast<size_t>(label)] ? -2 : label);
  }
  const bool balanced = o.select_by == "balanced";
  const std::vector<double> no_offsets(scored.size(), 0.0);
  cv::Mat gram(n, n, CV_32F), best_values;
  double best = -1;
  const int steps = static_cast<int>(gammas.size() * o.c_grid.size()) + 1;
  int step = 0;
  for (double gamma : gammas) {
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) gram.at<float>(i, j) = static_cast<float>(KernelValue(kernel_, pairwise.at<float>(i, j), gamma));
    for (double c : o.c_grid) {
      if (progress) progress(step++, steps);
      // Each held-out fold scored by SVMs trained on the others.
      folds_scored.values.create(n, static_cast<int>(scored.size()), CV_64F);
      for (int k = 0; k < o.folds; ++k) {
        std::vector<int> train_rows, test_rows;
        for (int i = 0; i < n; ++i) (fold[static_cast<size_t>(i)] == k ? test_rows : train_rows).push_back(i);
        std::vector<Fit> fits(scored.size());
        cv::parallel_for_(cv::Range(0, static_cast<int>(scored.size())), [&](const cv::Range& r) {
          for (int s = r.start; s < r.end; ++s) fits[static_cast<size_t>(s)] = TrainOne(gram, train_rows, labels, scored[static_cast<size_t>(s)], c);
        });
        for (int t : test_rows)
          for (size_t s = 0; s < scored.size(); ++s)
            folds_scored.values.at<double>(t, static_cast<int>(s)) = Decision(fits[s], gram, t);
      }
      const double accuracy = Agreement(folds_scored, no_offsets, balanced);
      if (accuracy > best + 1e-12) {  // ties keep the smaller C, the earlier gamma
        best = accuracy;
        c_ = c;
        gamma_ = gamma;
        folds_scored.values.copyTo(best_values);
      }
    }
  }
  cv_accuracy_ = best;
  // Chosen by mean recall: offsets on the classes' decisions, fitted on the same held-out scores.
  offsets_.assign(static_cast<size_t>(classes), 0.0);
  if (balanced) {
    folds_scored.values = best_values;
    const std::vector<double> fitted = FitOffsets(folds_scored);
    for (size_t s = 0; s < scored.size(); ++s) offsets_[static_cast<size_t>(scored[s])] = fitted[s];
    cv_balanced_after_offsets_ = Agreement(folds_scored, fitted, true);
  }
  // The final SVMs on every sample with the chosen C and gamma.
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) gram.at<float>(i, j) = static_cast<float>(KernelValue(kernel_, pairwise.at<float>(i, j), gamma_));
  std::vector<int> all(static_cast<size_t>(n));
  std::iota(all.begin(), all.end(), 0);
  std::vector<Fit> fits(static_cast<size_t>(classes));
  cv::parallel_for_(cv::Range(0, static_cast<int>(scored.size())), [&](const cv::Range& r) {
    for (int s = r.start; s < r.end; ++s) fits[static_cast<size_t>(scored[static_cast<size_t>(s)])] = TrainOne(gram, all, labels, scored[static_cast<size_t>(s)], c_);
  });
  // Each class's coefficients over the samples (zero off its support vectors).
  cv::Mat alpha = cv::Mat::zeros(classes, n, CV_64F);
  rho_.assign(static_cast<size_t>(classes), 0);
  trained_.assign(static_cast<size_t>(classes), false);
  support_counts_.assign(static_cast<size_t>(classes), 0);
  std::vector<bool> is_support(static_cast<size_t>(n), false);
  for (int c = 0; c < classes; ++c) {
    const Fit& f = fits[static_cast<size_t>(c)];
    if (f.support.empty()) continue;
    trained_[static_cast<size_t>(c)] = true;
    rho_[static_cast<size_t>(c)] = f.rho - offsets_[static_cast<size_t>(c)];  // decision = ... - rho
    for (size_t k = 0; k < f.support.size(); ++k) {
      alpha.at<double>(c, f.support[k]) += f.alpha[k];
      is_support[static_cast<size_t>(f.support[k])] = true;
    }
    support_counts_[static_cast<size_t>(c)] = static_cast<int>(f.support.size());
  }
  support_total_ = static_cast<int>(std::count(is_support.begin(), is_support.end(), true));
  if (kernel_ == cv::ml::SVM::LINEAR) {
    // A linear SVM is one weight vector per class: keep those instead of the support vectors (the
    // model shrinks from every support vector to a row per class, and a score is one dot product).
    cv::Mat weights;
    alpha.convertTo(weights, CV_32F);
    support_ = MatrixProduct(weights, features);
    coefficients_ = cv::Mat::eye(classes, classes, CV_64F);
  } else {
    // The support vectors once, shared by the classes.
    std::vector<int> rows;
    for (int i = 0; i < n; ++i)
      if (is_support[static_cast<size_t>(i)]) rows.push_back(i);
    support_ = cv::Mat::zeros(std::max<int>(1, static_cast<int>(rows.size())), features.cols, CV_32F);
    coefficients_ = cv::Mat::zeros(classes, support_.rows, CV_64F);
    for (size_t k = 0; k < rows.size(); ++k) {
      features.row(rows[k]).copyTo(support_.row(static_cast<int>(k)));
      alpha.col(rows[k]).copyTo(coefficients_.col(static_cast<int>(k)));
    }
  }
  if (progress) progress(steps, steps);
}

std::vector<double> OneVsAll::Scores(const cv::Mat& row) const {
  CV_Assert(row.type() == CV_32F && row.rows == 1 && row.cols == support_.cols);
  std::vector<double> k(static_cast<size_t>(support_.rows));
  for (int s = 0; s < support_.rows; ++s)
    k[static_cast<size_t>(s)] = KernelValue(kernel_, Pairwise(kernel_, row.ptr<float>(), support_.ptr<float>(s), row.cols), gamma_);
  std::vector<double> out(trained_.size(), -std::numeric_limits<double>::infinity());
  for (size_t c = 0; c < trained_.size(); ++c) {
    if (!trained_[c]) continue;
    const double* a = coefficients_.ptr<double>(static_cast<int>(c));
    double s = -rho_[c];
    for (size_t j = 0; j < k.size(); ++j) s += a[j] * k[j];
    out[c] = s;
  }
  return out;
}

nlohmann::json OneVsAll::Describe() const {
  nlohmann::json per_class = nlohmann::json::array();
  for (size_t c = 0; c < trained_.size(); ++c) {
    if (!trained_[c]) {
      per_class.push_back(nullptr);
      continue;
    }
    per_class.push_back({{"support_vectors", support_counts_[c]}});
  }
  return {{"kernel", KernelName(kernel_)}, {"C", c_}, {"gamma", gamma_},
          {"cv_accuracy", cv_accuracy_}, {"support_vectors", support_total_}, {"classes", per_class},
          {"offsets", offsets_}, {"cv_balanced_after_offsets", cv_balanced_after_offsets_}};
}

void OneVsAll::Write(cv::FileStorage& fs) const {
  fs << "svm" << "{" << "kernel" << KernelName(kernel_) << "C" << c_ << "gamma" << gamma_
     << "cv_accuracy" << cv_accuracy_ << "support" << support_ << "coefficients" << coefficients_
     << "support_counts" << support_counts_ << "support_total" << support_total_
     << "rho" << rho_ << "offsets" << offsets_ << "cv_balanced_after_offsets" << cv_balanced_after_offsets_;
  std::vector<int> trained(trained_.begin(), trained_.end());
  fs << "trained" << trained << "}";
}

void OneVsAll::Read(const cv::FileNode& root, const std::string& where) {
  const cv::FileNode n = root["svm"];
  if (!n.isMap()) Fail(where, "holds no SVMs");
  kernel_ = KernelType(static_cast<std::string>(n["kernel"]));
  c_ = static_cast<double>(n["C"]);
  gamma_ = static_cast<double>(n["gamma"]);
  cv_accuracy_ = static_cast<double>(n["cv_accuracy"]);
  n["support"] >> support_;
  n["coefficients"] >> coefficients_;
  // Added later (linear models keep weight vectors, not support vectors): absent, counted here.
  if (!n["support_counts"].empty()) {
    n["support_counts"] >> support_counts_;
    support_total_ = static_cast<int>(n["support_total"]);
  } else {
    support_counts_.clear();
    for (int c = 0; c < coefficients_.rows; ++c) support_counts_.push_back(cv::countNonZero(coefficients_.row(c) != 0));
    support_total_ = support_.rows;
  }
  n["rho"] >> rho_;
  // Added later (already inside rho: informative only); absent in older models.
  offsets_.assign(rho_.size(), 0.0);
  if (!n["offsets"].empty()) n["offsets"] >> offsets_;
  cv_balanced_after_offsets_ = n["cv_balanced_after_offsets"].empty() ? 0.0 : static_cast<double>(n["cv_balanced_after_offsets"]);
  std::vector<int> trained;
  n["trained"] >> trained;
  trained_.assign(trained.begin(), trained.end());
  if (support_.empty() || support_.type() != CV_32F || coefficients_.type() != CV_64F ||
      coefficients_.rows != static_cast<int>(trained_.size()) || coefficients_.cols != support_.rows ||
      support_counts_.size() != trained_.size() ||
      rho_.size() != trained_.size())
    Fail(where, "holds SVMs whose sizes do not agree (damaged file)");
}

}  // namespace rolamos
