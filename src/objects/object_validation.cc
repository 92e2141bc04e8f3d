// Repeated stratified k-fold cross-validation of the class model: the figure an unseen split
// gives, with its spread, instead of one validation split that settings were chosen on.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <random>

#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"

namespace rolamos {

std::vector<int> StratifiedFolds(const LabelledImages& data, int folds, unsigned seed) {
  // Each class's images shuffled and dealt round the folds, from a random fold so that the
  // remainders of small classes do not all land in the first ones.
  std::vector<int> fold(data.files.size(), 0);
  std::mt19937 rng(seed);
  for (size_t c = 0; c < data.classes.size(); ++c) {
    std::vector<int> rows;
    for (size_t i = 0; i < data.labels.size(); ++i)
      if (data.labels[i] == static_cast<int>(c)) rows.push_back(static_cast<int>(i));
    std::shuffle(rows.begin(), rows.end(), rng);
    const int offset = std::uniform_int_distribution<int>(0, folds - 1)(rng);
    for (size_t j = 0; j < rows.size(); ++j) fold[static_cast<size_t>(rows[j])] = static_cast<int>((j + offset) % folds);
  }
  return fold;
}

ObjectValidation CrossValidateObjects(const LabelledImages& data, const ObjectTrainOptions& options, int folds,
                                      int repeats, const ProgressFn& progress) {
  if (folds < 2 || repeats < 1) Fail("cross-validation", "needs 2 folds or more and 1 repeat or more");
  const auto start = std::chrono::steady_clock::now();
  ObjectValidation v;
  v.folds = folds;
  v.repeats = repeats;
  v.images = static_cast<int>(data.files.size());
  const size_t k = data.classes.size();
  std::vector<std::vector<int>> confusion(k, std::vector<int>(k, 0));
  const int runs = folds * repeats;
  for (int rep = 0; rep < repeats; ++rep) {
    const std::vector<int> fold = StratifiedFolds(data, folds, options.seed + 1000u * static_cast<unsigned>(rep));
    for (int f = 0; f < folds; ++f) {
      std::vector<int> train, held;
      for (size_t i = 0; i < fold.size(); ++i) (fold[i] == f ? held : train).push_back(static_cast<int>(i));
      const int run = rep * folds + f;
      const ObjectModel model = ObjectModel::Train(Subset(data, train), options,
                                                   SubProgress(progress, double(run) / runs, (run + 0.85) / runs),
                                                   "fold " + std::to_string(f + 1) + " of repeat " + std::to_string(rep + 1));
      const ObjectEvaluation e = EvaluateObjects(model, Subset(data, held),
                                                 SubProgress(progress, (run + 0.85) / runs, double(run + 1) / runs));
      v.fold_accuracy.push_back(e.accuracy);
      if (v.classes.empty()) v.classes = e.classes;
      for (size_t i = 0; i < e.classes.size(); ++i)
        for (size_t j = 0; j < e.classes.size(); ++j) {
          if (i >= confusion.size() || j >= confusion.size()) continue;
          confusion[i][j] += e.confusion[i][j];
        }
    }
  }
  v.confusion = confusion;
  const double n = double(v.fold_accuracy.size());
  v.mean = std::accumulate(v.fold_accuracy.begin(), v.fold_accuracy.end(), 0.0) / n;
  double ss = 0;
  for (double a : v.fold_accuracy) ss += (a - v.mean) * (a - v.mean);
  v.spread = n > 1 ? std::sqrt(ss / (n - 1)) : 0;
  for (size_t i = 0; i < v.confusion.size(); ++i) {
    const int support = std::accumulate(v.confusion[i].begin(), v.confusion[i].end(), 0);
    v.recall.push_back(support ? double(v.confusion[i][i]) / support : 0);
  }
  v.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return v;
}

nlohmann::json ToJson(const ObjectValidation& v) {
  return {{"mean", v.mean},       {"spread", v.spread},       {"fold_accuracy", v.fold_accuracy},
          {"classes", v.classes}, {"recall", v.recall},       {"confusion", v.confusion},
          {"images", v.images},   {"folds", v.folds},         {"repeats", v.repeats},
          {"seconds", v.seconds}};
}

}  // namespace rolamos
