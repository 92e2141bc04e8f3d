#include "objects/one_vs_all.h"

#include <random>

#include <gtest/gtest.h>

namespace rolamos {
namespace {

// Histograms (non-negative rows, for the chi-square kernel): two common classes and a rare one
// that looks like the second but for a weak mark of its own.
void MakeSamples(int per_common, int rare, unsigned seed, cv::Mat* features, std::vector<int>* labels) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> noise(0.0f, 1.0f);
  std::vector<cv::Mat> rows;
  labels->clear();
  auto add = [&](int cls) {
    cv::Mat r(1, 8, CV_32F);
    for (int k = 0; k < 8; ++k) r.at<float>(k) = 0.6f * noise(rng);
    if (cls == 0) r.at<float>(0) += 1.0f, r.at<float>(1) += 1.0f;
    if (cls >= 1) r.at<float>(2) += 1.0f, r.at<float>(3) += 1.0f;
    if (cls == 2) r.at<float>(4) += 0.35f;
    rows.push_back(r);
    labels->push_back(cls);
  };
  for (int i = 0; i < per_common; ++i) add(0), add(1);
  for (int i = 0; i < rare; ++i) add(2);
  cv::vconcat(rows, *features);
}

double RareRecall(const OneVsAll& svm, const cv::Mat& features, const std::vector<int>& labels, double* mean_recall) {
  int seen[3] = {0, 0, 0}, right[3] = {0, 0, 0};
  for (int i = 0; i < features.rows; ++i) {
    const std::vector<double> s = svm.Scores(features.row(i));
    const int winner = int(std::max_element(s.begin(), s.end()) - s.begin());
    ++seen[labels[size_t(i)]];
    right[labels[size_t(i)]] += winner == labels[size_t(i)];
  }
  *mean_recall = (double(right[0]) / seen[0] + double(right[1]) / seen[1] + double(right[2]) / seen[2]) / 3;
  return double(right[2]) / seen[2];
}

// Chosen by mean recall, each class's decision gets an offset fitted on the held-out scores:
// the rare class is found more often on samples the model never saw, and the classes' mean
// recall rises; chosen by accuracy, no offsets.
TEST(OneVsAll, BalancedSelectionOffsetsGiveTheRareClassAChance) {
  cv::Mat train, test;
  std::vector<int> train_labels, test_labels;
  MakeSamples(150, 14, 1, &train, &train_labels);
  MakeSamples(150, 40, 2, &test, &test_labels);
  const std::vector<bool> none(3, false);
  OneVsAllOptions o;
  o.c_grid = {0.5, 2, 8};
  o.gamma_factors = {1};
  OneVsAll by_accuracy, by_recall;
  by_accuracy.Train(train, train_labels, 3, none, o);
  o.select_by = "balanced";
  by_recall.Train(train, train_labels, 3, none, o);
  for (double offset : by_accuracy.Describe()["offsets"]) EXPECT_EQ(offset, 0.0);
  const auto offsets = by_recall.Describe()["offsets"];
  ASSERT_EQ(offsets.size(), 3u);
  EXPECT_GT(offsets[2].get<double>(), offsets[1].get<double>());  // the rare class raised against its look-alike
  double mean_accuracy = 0, mean_recall = 0;
  const double rare_accuracy = RareRecall(by_accuracy, test, test_labels, &mean_accuracy);
  const double rare_recall = RareRecall(by_recall, test, test_labels, &mean_recall);
  EXPECT_GT(rare_recall, rare_accuracy + 0.1) << rare_accuracy << " -> " << rare_recall;
  EXPECT_GT(mean_recall, mean_accuracy) << mean_accuracy << " -> " << mean_recall;
}

// The offsets live in the model file: a saved and reloaded model scores alike.
TEST(OneVsAll, OffsetsSurviveWriteAndRead) {
  cv::Mat train;
  std::vector<int> labels;
  MakeSamples(60, 10, 3, &train, &labels);
  OneVsAllOptions o;
  o.c_grid = {2};
  o.gamma_factors = {1};
  o.select_by = "balanced";
  OneVsAll svm;
  svm.Train(train, labels, 3, std::vector<bool>(3, false), o);
  cv::FileStorage out("one_vs_all.yml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY);
  svm.Write(out);
  const std::string text = out.releaseAndGetString();
  cv::FileStorage in(text, cv::FileStorage::READ | cv::FileStorage::MEMORY);
  OneVsAll back;
  back.Read(in.root(), "memory");
  EXPECT_EQ(back.Describe()["offsets"], svm.Describe()["offsets"]);
  for (int i = 0; i < train.rows; i += 7) {
    const auto a = svm.Scores(train.row(i)), b = back.Scores(train.row(i));
    for (size_t c = 0; c < a.size(); ++c) EXPECT_NEAR(a[c], b[c], 1e-9);
  }
}

}  // namespace
}  // namespace rolamos
