// The peer of object identification (issue 6): HOG + a linear SVM, trained on the train split and
// judged on the validation split of a folder-per-class dataset (../shared/data/objects_deepdive_biota).
// rolamos itself is measured through its CLI (bench/run_objects.py); this is the baseline.
//   objects_bench TRAIN_DIR VALIDATION_DIR
// Prints one JSON object: accuracy, per-class recall, train and test seconds.
#include <chrono>
#include <cmath>
#include <cstdio>

#include <CLI/CLI.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/ml.hpp>
#include <opencv2/objdetect.hpp>

#include "rolamos/objects.hpp"

namespace {

using Clock = std::chrono::steady_clock;
double Since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// The baseline: HOG of the sample resized to 128 x 128, one multi-class linear SVM (C by
// cross-validation), as a detector of shapes alone would do.
cv::Mat Hog(const std::string& file) {
  cv::Mat g = cv::imread(file, cv::IMREAD_GRAYSCALE);
  if (g.empty()) throw std::runtime_error(file + ": unreadable");
  cv::resize(g, g, {128, 128}, 0, 0, cv::INTER_AREA);
  cv::HOGDescriptor hog({128, 128}, {16, 16}, {8, 8}, {8, 8}, 9);
  std::vector<float> d;
  hog.compute(g, d);
  return cv::Mat(d, true).reshape(1, 1);
}

nlohmann::json HogBaseline(const rolamos::LabelledImages& train, const rolamos::LabelledImages& val) {
  const auto t0 = Clock::now();
  cv::Mat x(static_cast<int>(train.files.size()), 0, CV_32F);
  std::vector<cv::Mat> rows(train.files.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(rows.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) rows[static_cast<size_t>(i)] = Hog(train.files[static_cast<size_t>(i)]);
  });
  cv::vconcat(rows, x);
  auto svm = cv::ml::SVM::create();
  svm->setType(cv::ml::SVM::C_SVC);
  svm->setKernel(cv::ml::SVM::LINEAR);
  svm->trainAuto(cv::ml::TrainData::create(x, cv::ml::ROW_SAMPLE, cv::Mat(train.labels, true)), 5,
                 cv::ml::ParamGrid(0.01, 10.1, 4), cv::ml::ParamGrid(1, 1, 0), cv::ml::ParamGrid(1, 1, 0),
                 cv::ml::ParamGrid(1, 1, 0), cv::ml::ParamGrid(1, 1, 0), cv::ml::ParamGrid(1, 1, 0), true);
  const double train_s = Since(t0);
  const auto t1 = Clock::now();
  int correct = 0;
  std::vector<int> hits(train.classes.size(), 0), total(train.classes.size(), 0);
  for (size_t i = 0; i < val.files.size(); ++i) {
    const int truth = static_cast<int>(std::find(train.classes.begin(), train.classes.end(),
                                                 val.classes[static_cast<size_t>(val.labels[i])]) - train.classes.begin());
    const int p = static_cast<int>(svm->predict(Hog(val.files[i])));
    correct += p == truth;
    hits[static_cast<size_t>(truth)] += p == truth;
    ++total[static_cast<size_t>(truth)];
  }
  nlohmann::json recall = nlohmann::json::object();
  for (size_t c = 0; c < train.classes.size(); ++c) recall[train.classes[c]] = total[c] ? double(hits[c]) / total[c] : 0;
  return {{"model", "HOG + linear SVM"}, {"accuracy", double(correct) / val.files.size()},
          {"recall", recall}, {"train_seconds", train_s}, {"test_seconds", Since(t1)},
          {"C", svm->getC()}};
}

// The same folds as `rolamos objects validate` (StratifiedFolds, seed 1 + 1000 r).
nlohmann::json CrossValidated(const std::vector<std::string>& dirs, int folds, int repeats) {
  const rolamos::LabelledImages data = rolamos::ReadLabelledFolders(dirs);
  std::vector<double> accuracy;
  for (int rep = 0; rep < repeats; ++rep) {
    const std::vector<int> fold = rolamos::StratifiedFolds(data, folds, 1u + 1000u * static_cast<unsigned>(rep));
    for (int f = 0; f < folds; ++f) {
      std::vector<int> train, held;
      for (size_t i = 0; i < fold.size(); ++i) (fold[i] == f ? held : train).push_back(static_cast<int>(i));
      accuracy.push_back(HogBaseline(rolamos::Subset(data, train), rolamos::Subset(data, held))["accuracy"].get<double>());
    }
  }
  double mean = 0, ss = 0;
  for (double a : accuracy) mean += a / accuracy.size();
  for (double a : accuracy) ss += (a - mean) * (a - mean);
  return {{"model", "HOG + linear SVM"}, {"mean", mean}, {"spread", accuracy.size() > 1 ? std::sqrt(ss / (accuracy.size() - 1)) : 0.0},
          {"fold_accuracy", accuracy}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("objects_bench");
  std::vector<std::string> dirs;
  int folds = 0, repeats = 1;
  app.add_option("folders", dirs, "TRAIN VALIDATION, or with --cross-validate every folder joined")->required();
  app.add_option("--cross-validate", folds, "stratified folds (0: train on the first folder, judge on the second)");
  app.add_option("--repeats", repeats, "repeats of the cross-validation");
  CLI11_PARSE(app, argc, argv);
  if (folds > 1) {
    std::printf("%s\n", CrossValidated(dirs, folds, repeats).dump().c_str());
  } else {
    if (dirs.size() != 2) throw std::runtime_error("give TRAIN and VALIDATION folders");
    std::printf("%s\n", HogBaseline(rolamos::ReadLabelledFolder(dirs[0]), rolamos::ReadLabelledFolder(dirs[1])).dump().c_str());
  }
  return 0;
}
