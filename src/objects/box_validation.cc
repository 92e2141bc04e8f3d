// Station-wise cross-validation of the box detector.
#include <chrono>
#include <map>
#include <set>

#include <opencv2/imgcodecs.hpp>

#include "rolamos/box_detector.hpp"
#include "rolamos/error.hpp"
#include "util/parallel_for.h"

namespace rolamos {

BoxEvaluation EvaluateBoxDetector(const BoxDetector& detector, const std::vector<BoxedImage>& images,
                                  const ProgressFn& progress) {
  std::vector<std::vector<BoxDetection>> found(images.size());
  std::vector<std::vector<cv::Rect2d>> truth(images.size());
  ParallelForOptions po;
  po.threads = detector.options().threads;
  if (progress) po.on_progress = [&](long long done) { progress(double(done) / double(images.size())); };
  ParallelFor(static_cast<long long>(images.size()), [&](long long i, int) {
    const BoxedImage& b = images[static_cast<size_t>(i)];
    const cv::Mat image = cv::imread(b.path, cv::IMREAD_GRAYSCALE | cv::IMREAD_ANYDEPTH);
    if (image.empty()) Fail(b.path, "cannot be decoded as an image");
    found[static_cast<size_t>(i)] = detector.Detect(image, kBoxCurveScore);
    truth[static_cast<size_t>(i)] = b.boxes;
  }, po);
  return EvaluateBoxes(found, truth, detector.threshold());
}

BoxValidation CrossValidateBoxes(const std::vector<BoxedImage>& images, const BoxDetectorOptions& options,
                                 int folds, const ProgressFn& progress) {
  const std::vector<int> fold = StationFolds(images, folds);
  const int k = images.empty() ? 0 : *std::max_element(fold.begin(), fold.end()) + 1;
  if (k < 2) Fail("station-wise validation", "needs frames of two stations at least (all frames are of one station)");
  BoxValidation v;
  v.fold_stations.resize(static_cast<size_t>(k));
  std::vector<std::vector<BoxDetection>> found(images.size());
  std::vector<std::vector<cv::Rect2d>> truth(images.size());
  for (int f = 0; f < k; ++f) {
    std::vector<BoxedImage> train;
    std::vector<size_t> held;
    std::set<std::string> stations;
    for (size_t i = 0; i < images.size(); ++i) {
      if (fold[i] == f) {
        held.push_back(i);
        stations.insert(images[i].station);
      } else {
        train.push_back(images[i]);
      }
    }
    v.fold_stations[static_cast<size_t>(f)].assign(stations.begin(), stations.end());
    auto t0 = std::chrono::steady_clock::now();
    const BoxDetector model = BoxDetector::Train(train, options, SubProgress(progress, double(f) / k, (f + 0.8) / k));
    auto t1 = std::chrono::steady_clock::now();
    v.seconds_train += std::chrono::duration<double>(t1 - t0).count();
    std::vector<std::vector<BoxDetection>> fold_found(held.size());
    std::vector<std::vector<cv::Rect2d>> fold_truth(held.size());
    std::vector<double> megapixels(held.size(), 0);
    ParallelForOptions po;
    po.threads = options.threads;
    ParallelFor(static_cast<long long>(held.size()), [&](long long j, int) {
      const BoxedImage& b = images[held[static_cast<size_t>(j)]];
      const cv::Mat image = cv::imread(b.path, cv::IMREAD_GRAYSCALE | cv::IMREAD_ANYDEPTH);
      if (image.empty()) Fail(b.path, "cannot be decoded as an image");
      // Every detection above the lowest score the curve needs; counted at the model's threshold.
      fold_found[static_cast<size_t>(j)] = model.Detect(image, kBoxCurveScore);
      fold_truth[static_cast<size_t>(j)] = b.boxes;
      megapixels[static_cast<size_t>(j)] = double(image.total()) / 1e6;
    }, po);
    v.seconds_detect += std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    // Pooled, each detection is counted at its own fold model's threshold.
    for (size_t j = 0; j < held.size(); ++j) {
      auto& d = fold_found[j];
      for (auto& x : d) x.score -= model.threshold();
      found[held[j]] = d;
      truth[held[j]] = fold_truth[j];
      v.megapixels += megapixels[j];
    }
    v.folds.push_back(EvaluateBoxes(fold_found, fold_truth, 0.0));
    v.folds.back().threshold = model.threshold();
    if (progress) progress(double(f + 1) / k);
  }
  v.pooled = EvaluateBoxes(found, truth, 0.0);
  return v;
}

nlohmann::json ToJson(const BoxValidation& v) {
  nlohmann::json j = ToJson(v.pooled);
  j["validation"] = "by station";
  j["folds"] = nlohmann::json::array();
  for (size_t f = 0; f < v.folds.size(); ++f) {
    j["folds"].push_back(ToJson(v.folds[f]));
    j["folds"].back()["stations"] = v.fold_stations[f];
  }
  j["seconds_train"] = v.seconds_train;
  j["seconds_detect"] = v.seconds_detect;
  j["megapixels_per_second"] = v.seconds_detect > 0 ? v.megapixels / v.seconds_detect : 0;
  return j;
}

}  // namespace rolamos
