#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <random>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "objects/box_evaluation.h"
#include "objects/linear_svm.h"
#include "objects/window_search.h"
#include "rolamos/box_detector.hpp"
#include "rolamos/error.hpp"
#include "util/files.h"
#include "util/parallel_for.h"

namespace rolamos {

bool BoxDetectorOptions::IsValid(std::string* error) const {
  if (label.empty()) {
    *error = "the class label cannot be empty";
    return false;
  }
  if (features != "cells" && features != "hog") {
    *error = "features must be cells or hog, not \"" + features + "\"";
    return false;
  }
  if (!(min_box >= 8 && max_box > min_box && max_box <= 4096)) {
    *error = "box sides must satisfy 8 <= min_box < max_box <= 4096 (got " + std::to_string(min_box) + ", " +
             std::to_string(max_box) + ")";
    return false;
  }
  if (scales_per_octave < 1 || scales_per_octave > 16) {
    *error = "scales per octave must be in 1..16";
    return false;
  }
  if (!(c > 0 && c < 1e6)) {
    *error = "SVM cost c must be positive";
    return false;
  }
  if (negatives_per_image < 1 || hard_negatives_per_image < 0 || hard_negative_rounds < 0 || hard_negative_rounds > 5) {
    *error = "negatives per image must be >= 1, hard negatives >= 0, rounds in 0..5";
    return false;
  }
  if (!(nms_containment > 0 && nms_containment <= 1)) {
    *error = "suppression containment must be in (0, 1]";
    return false;
  }
  if (!(nms_iou > 0 && nms_iou <= 1)) {
    *error = "non-maximum suppression overlap must be in (0, 1]";
    return false;
  }
  return true;
}

struct BoxDetector::Impl {
  BoxDetectorOptions options;
  std::vector<float> weights;
  double bias = 0, threshold = 0;
  nlohmann::json training;
  WindowSearch Search() const { return {options.features, options.min_box, options.max_box, options.scales_per_octave}; }
};

namespace {

constexpr double kNegativeIou = 0.3;   // a window overlapping every box less than this is background
constexpr double kPositiveIou = 0.6;   // windows this close to a box teach it

double MaxIou(const cv::Rect2d& r, const std::vector<cv::Rect2d>& boxes) {
  double best = 0;
  for (const auto& b : boxes) best = std::max(best, BoxIou(r, b));
  return best;
}

cv::Mat ReadGray(const std::string& path) {
  cv::Mat g = cv::imread(path, cv::IMREAD_GRAYSCALE | cv::IMREAD_ANYDEPTH);
  if (g.empty()) Fail(path, "cannot be decoded as an image");
  return g;
}

// Training samples of one frame: windows on its boxes (positives) and random background.
struct Samples {
  std::vector<float> data;  // rows of dims
  std::vector<bool> positive;
  void Add(const WindowSearch& s, const CellMap& m, int r, int c, bool pos) {
    const size_t at = data.size();
    data.resize(at + static_cast<size_t>(s.Dims()));
    s.Vector(m, r, c, data.data() + at);
    positive.push_back(pos);
  }
};

void SampleFrame(const WindowSearch& search, const cv::Mat& gray, const std::vector<cv::Rect2d>& boxes,
                 int negatives, std::mt19937* rng, Samples* out) {
  const std::vector<double> scales = search.Scales();
  const int n = search.WindowCells();
  // Per box: the level where it is closest to kBoxPixels, and its neighbours.
  std::vector<std::vector<size_t>> boxes_at(scales.size());
  for (size_t b = 0; b < boxes.size(); ++b) {
    const double side = std::sqrt(boxes[b].area());
    size_t best = 0;
    for (size_t l = 0; l < scales.size(); ++l)
      if (std::abs(std::log(kBoxPixels / scales[l] / side)) < std::abs(std::log(kBoxPixels / scales[best] / side))) best = l;
    for (size_t l = best > 0 ? best - 1 : 0; l <= std::min(best + 1, scales.size() - 1); ++l) boxes_at[l].push_back(b);
  }
  const int per_level = (negatives + int(scales.size()) - 1) / int(scales.size());
  for (size_t l = 0; l < scales.size(); ++l) {
    const CellMap m = search.Describe(gray, scales[l]);
    const int rows = m.rows - n + 1, cols = m.cols - n + 1;
    if (rows <= 0 || cols <= 0) break;
    for (size_t b : boxes_at[l]) {
      const cv::Rect2d& box = boxes[b];
      const double s = scales[l];
      const int c0 = int(std::lround((box.x + box.width / 2) * s - kWindowPixels / 2.0 + m.origin) / m.cell);
      const int r0 = int(std::lround((box.y + box.height / 2) * s - kWindowPixels / 2.0 + m.origin) / m.cell);
      for (int r = std::max(0, r0 - 1); r <= std::min(rows - 1, r0 + 1); ++r)
        for (int c = std::max(0, c0 - 1); c <= std::min(cols - 1, c0 + 1); ++c)
          if (BoxIou(WindowSearch::Box(m, r, c, s), box) >= kPositiveIou) out->Add(search, m, r, c, true);
    }
    for (int k = 0, tries = 0; k < per_level && tries < per_level * 20; ++tries) {
      const int r = std::uniform_int_distribution<int>(0, rows - 1)(*rng);
      const int c = std::uniform_int_distribution<int>(0, cols - 1)(*rng);
      if (MaxIou(WindowSearch::Box(m, r, c, scales[l]), boxes) >= kNegativeIou) continue;
      out->Add(search, m, r, c, false);
      ++k;
    }
  }
}

// The background windows the current model scores highest (above -1): its mistakes.
void MineFrame(const WindowSearch& search, const std::vector<float>& w, double bias, const cv::Mat& gray,
               const std::vector<cv::Rect2d>& boxes, int keep, Samples* out) {
  struct Hit {
    float score;
    size_t level;
    int r, c;
  };
  std::vector<Hit> hits;
  const std::vector<double> scales = search.Scales();
  std::vector<CellMap> maps;
  for (size_t l = 0; l < scales.size(); ++l) {
    maps.push_back(search.Describe(gray, scales[l]));
    const cv::Mat s = search.Scores(maps.back(), w, bias);
    for (int r = 0; r < s.rows; ++r)
      for (int c = 0; c < s.cols; ++c)
        if (s.at<float>(r, c) > -1.f) hits.push_back({s.at<float>(r, c), l, r, c});
  }
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return a.score > b.score; });
  int taken = 0;
  for (const Hit& h : hits) {
    if (taken >= keep) break;
    if (MaxIou(WindowSearch::Box(maps[h.level], h.r, h.c, scales[h.level]), boxes) >= kNegativeIou) continue;
    out->Add(search, maps[h.level], h.r, h.c, false);
    ++taken;
  }
}

LinearSvm FitSvm(const std::vector<Samples>& frames, int dims, const BoxDetectorOptions& o, nlohmann::json* facts) {
  // The solver reads the frames' samples where they are: no second copy of ~100,000 windows.
  std::vector<const float*> rows;
  std::vector<bool> positive;
  int positives = 0;
  for (const auto& f : frames)
    for (size_t i = 0; i < f.positive.size(); ++i) {
      rows.push_back(f.data.data() + i * static_cast<size_t>(dims));
      positive.push_back(f.positive[i]);
      positives += f.positive[i] ? 1 : 0;
    }
  if (positives == 0) Fail("box detector training", "found no box to learn from (are the label files empty?)");
  LinearSvmOptions so;
  so.c_positive = so.c_negative = o.c;
  so.seed = o.seed;
  const LinearSvm svm = TrainLinearSvm(rows, dims, positive, so);
  *facts = {{"positives", positives}, {"negatives", static_cast<long long>(rows.size()) - positives}, {"epochs", svm.epochs}};
  return svm;
}

}  // namespace

BoxDetector BoxDetector::Train(const std::vector<BoxedImage>& images, const BoxDetectorOptions& options,
                               const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("box detector options", error);
  if (images.empty()) Fail("box detector training", "has no frames");
  const auto start = std::chrono::steady_clock::now();
  auto impl = std::make_shared<Impl>();
  impl->options = options;
  const WindowSearch search = impl->Search();
  const int rounds = options.hard_negative_rounds;
  const double passes = 2.0 + rounds;  // sampling, each mining round, the threshold
  const long long n = static_cast<long long>(images.size());
  auto pass = [&](int k, const std::function<void(long long)>& work) {
    ParallelForOptions po;
    po.threads = options.threads;
    if (progress) po.on_progress = [&](long long done) { progress((k + double(done) / double(n)) / passes); };
    ParallelFor(n, [&](long long i, int) { work(i); }, po);
  };

  std::vector<Samples> frames(images.size());
  pass(0, [&](long long i) {
    std::mt19937 rng(options.seed + static_cast<unsigned>(i) * 7919u);
    SampleFrame(search, ReadGray(images[static_cast<size_t>(i)].path), images[static_cast<size_t>(i)].boxes,
                options.negatives_per_image, &rng, &frames[static_cast<size_t>(i)]);
    frames[static_cast<size_t>(i)].data.shrink_to_fit();
  });
  nlohmann::json facts;
  LinearSvm svm = FitSvm(frames, search.Dims(), options, &facts);
  for (int round = 0; round < rounds; ++round) {
    pass(1 + round, [&](long long i) {
      const BoxedImage& b = images[static_cast<size_t>(i)];
      MineFrame(search, svm.weights, svm.bias, ReadGray(b.path), b.boxes, options.hard_negatives_per_image,
                &frames[static_cast<size_t>(i)]);
      frames[static_cast<size_t>(i)].data.shrink_to_fit();
    });
    svm = FitSvm(frames, search.Dims(), options, &facts);
  }
  impl->weights = svm.weights;
  impl->bias = svm.bias;

  // The operating point: the threshold of the best F1 on the training frames.
  BoxDetector partial;
  partial.impl_ = impl;
  std::vector<std::vector<BoxDetection>> found(images.size());
  std::vector<std::vector<cv::Rect2d>> truth(images.size());
  pass(1 + rounds, [&](long long i) {
    found[static_cast<size_t>(i)] = partial.Detect(ReadGray(images[static_cast<size_t>(i)].path), kBoxCurveScore);
    truth[static_cast<size_t>(i)] = images[static_cast<size_t>(i)].boxes;
  });
  impl->threshold = BestF1Threshold(found, truth);
  const BoxEvaluation fit = EvaluateBoxes(found, truth, impl->threshold);
  long long boxes = 0;
  for (const auto& b : images) boxes += static_cast<long long>(b.boxes.size());
  facts["frames"] = static_cast<long long>(images.size());
  facts["boxes"] = boxes;
  facts["training_ap50"] = fit.ap50;
  facts["training_f1"] = fit.f1;
  facts["seconds"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  impl->training = facts;
  BoxDetector out;
  out.impl_ = impl;
  return out;
}

std::vector<BoxDetection> BoxDetector::Detect(const cv::Mat& image, double min_score) const {
  if (image.empty()) Fail("box detection", "was given an empty image");
  const cv::Mat gray = ToGray(image);
  const WindowSearch search = impl_->Search();
  std::vector<BoxDetection> candidates;
  for (double scale : search.Scales()) {
    const CellMap m = search.Describe(gray, scale);
    const cv::Mat s = search.Scores(m, impl_->weights, impl_->bias);
    if (s.empty()) break;
    // Only a window scoring at least as high as its 8 neighbours stands for an object.
    cv::Mat peak;
    cv::dilate(s, peak, cv::Mat());
    for (int r = 0; r < s.rows; ++r)
      for (int c = 0; c < s.cols; ++c)
        if (s.at<float>(r, c) > min_score && s.at<float>(r, c) >= peak.at<float>(r, c)) {
          cv::Rect2d box = WindowSearch::Box(m, r, c, scale) & cv::Rect2d(0, 0, image.cols, image.rows);
          if (box.area() > 0) candidates.push_back({box, s.at<float>(r, c)});
        }
  }
  return SuppressBoxes(std::move(candidates), impl_->options.nms_iou, impl_->options.nms_containment);
}

double BoxDetector::threshold() const { return impl_->threshold; }
const BoxDetectorOptions& BoxDetector::options() const { return impl_->options; }
double BoxDetector::max_box() const { return impl_->options.max_box; }

nlohmann::json BoxDetector::Describe() const {
  const auto& o = impl_->options;
  return {{"format", kBoxDetectorFormat},
          {"label", o.label},
          {"features", o.features},
          {"dims", impl_->weights.size()},
          {"min_box", o.min_box},
          {"max_box", o.max_box},
          {"scales_per_octave", o.scales_per_octave},
          {"c", o.c},
          {"nms_iou", o.nms_iou},
          {"nms_containment", o.nms_containment},
          {"threshold", impl_->threshold},
          {"training", impl_->training}};
}

void BoxDetector::Save(const std::string& path) const {
  const bool gz = path.size() > 3 && path.substr(path.size() - 3) == ".gz";
  const std::string tmp = TemporarySibling(path) + (gz ? ".yml.gz" : ".yml");
  {
    cv::FileStorage fs(tmp, cv::FileStorage::WRITE);
    if (!fs.isOpened()) Fail(path, "cannot be written");
    const auto& o = impl_->options;
    fs << "format" << kBoxDetectorFormat << "version" << kBoxDetectorVersion;
    fs << "label" << o.label << "features" << o.features << "min_box" << o.min_box << "max_box" << o.max_box
       << "scales_per_octave" << o.scales_per_octave << "c" << o.c << "nms_iou" << o.nms_iou
       << "nms_containment" << o.nms_containment;
    fs << "threshold" << impl_->threshold << "bias" << impl_->bias;
    fs << "weights" << cv::Mat(impl_->weights, true).reshape(1, 1);
    fs << "training" << impl_->training.dump();
    fs.release();
  }
  RenameFile(tmp, path);
}

bool IsBoxDetectorFile(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) return false;
  try {
    cv::FileStorage fs(path, cv::FileStorage::READ);
    return fs.isOpened() && static_cast<std::string>(fs["format"]) == kBoxDetectorFormat;
  } catch (const cv::Exception&) {
    return false;
  }
}

BoxDetector BoxDetector::Load(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) Fail(path, "no such model file");
  auto impl = std::make_shared<Impl>();
  try {
    cv::FileStorage fs(path, cv::FileStorage::READ);
    if (!fs.isOpened()) Fail(path, "is not a model file OpenCV can read");
    if (static_cast<std::string>(fs["format"]) != kBoxDetectorFormat)
      Fail(path, "is not a rolamos box detector (no \"format: " + std::string(kBoxDetectorFormat) + "\")");
    const int version = static_cast<int>(fs["version"]);
    if (version != kBoxDetectorVersion)
      Fail(path, "is a box detector of format version " + std::to_string(version) + "; this rolamos reads version " +
                     std::to_string(kBoxDetectorVersion) + " (train it again)");
    auto& o = impl->options;
    o.label = static_cast<std::string>(fs["label"]);
    o.features = static_cast<std::string>(fs["features"]);
    o.min_box = static_cast<double>(fs["min_box"]);
    o.max_box = static_cast<double>(fs["max_box"]);
    o.scales_per_octave = static_cast<int>(fs["scales_per_octave"]);
    o.c = static_cast<double>(fs["c"]);
    o.nms_iou = static_cast<double>(fs["nms_iou"]);
    if (!fs["nms_containment"].empty()) o.nms_containment = static_cast<double>(fs["nms_containment"]);
    impl->threshold = static_cast<double>(fs["threshold"]);
    impl->bias = static_cast<double>(fs["bias"]);
    cv::Mat w;
    fs["weights"] >> w;
    std::string error;
    if (!o.IsValid(&error)) Fail(path, "settings: " + error);
    if (w.type() != CV_32F || static_cast<int>(w.total()) != impl->Search().Dims())
      Fail(path, "holds " + std::to_string(w.total()) + " weights; its settings need " + std::to_string(impl->Search().Dims()));
    impl->weights.assign(w.ptr<float>(), w.ptr<float>() + w.total());
    impl->training = nlohmann::json::parse(static_cast<std::string>(fs["training"]), nullptr, false);
  } catch (const cv::Exception& e) {
    Fail(path, std::string("is truncated or damaged (") + e.err + ")");
  }
  BoxDetector out;
  out.impl_ = impl;
  return out;
}

}  // namespace rolamos
