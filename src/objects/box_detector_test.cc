#include "rolamos/box_detector.hpp"

#include <filesystem>
#include <fstream>
#include <random>
#include <set>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "objects/box_evaluation.h"
#include "objects/linear_svm.h"
#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "rolamos/tiff_writer.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

using test::BurrowFrame;

std::vector<BoxedImage> WriteBoxedFolder(const std::string& dir, int first, int count, int per_station = 100) {
  test::WriteBurrowFrames(dir, first, count, per_station);
  return ReadBoxedFolder(dir);
}

BoxDetectorOptions FastOptions(const std::string& features = "cells") {
  BoxDetectorOptions o;
  o.label = "burrow";
  o.features = features;
  o.min_box = 24;
  o.max_box = 100;
  return o;
}

std::vector<std::vector<BoxDetection>> DetectAll(const BoxDetector& m, const std::vector<BoxedImage>& images) {
  std::vector<std::vector<BoxDetection>> out;
  for (const auto& b : images) out.push_back(m.Detect(cv::imread(b.path), kBoxCurveScore));
  return out;
}

std::vector<std::vector<cv::Rect2d>> Truth(const std::vector<BoxedImage>& images) {
  std::vector<std::vector<cv::Rect2d>> out;
  for (const auto& b : images) out.push_back(b.boxes);
  return out;
}

TEST(LinearSvm, SeparatesTwoCloudsAndWeighsClasses) {
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0, 1);
  auto sample = [&](int n, float shift, cv::Mat* x, std::vector<bool>* y, bool label) {
    for (int i = 0; i < n; ++i) {
      cv::Mat row(1, 20, CV_32F);
      for (int j = 0; j < 20; ++j) row.at<float>(j) = noise(rng) + (j < 3 ? shift : 0);
      x->push_back(row);
      y->push_back(label);
    }
  };
  cv::Mat x;
  std::vector<bool> y;
  sample(300, 2.f, &x, &y, true);
  sample(600, -2.f, &x, &y, false);
  LinearSvmOptions o;
  o.c_positive = o.c_negative = 1;
  const LinearSvm svm = TrainLinearSvm(x, y, o);
  cv::Mat tx;
  std::vector<bool> ty;
  sample(200, 2.f, &tx, &ty, true);
  sample(200, -2.f, &tx, &ty, false);
  int right = 0;
  for (int i = 0; i < tx.rows; ++i) right += (svm.Decision(tx.ptr<float>(i)) > 0) == ty[static_cast<size_t>(i)];
  EXPECT_GT(right, 0.97 * tx.rows);
  EXPECT_LT(svm.epochs, o.max_epochs);
  // On overlapping clouds, a far higher cost on the positives moves the boundary toward the negatives.
  cv::Mat ox;
  std::vector<bool> oy;
  sample(300, 0.4f, &ox, &oy, true);
  sample(600, -0.4f, &ox, &oy, false);
  LinearSvmOptions w = o;
  w.c_positive = 10;
  w.c_negative = 0.1;
  const LinearSvm balanced = TrainLinearSvm(ox, oy, o), biased = TrainLinearSvm(ox, oy, w);
  int positive_balanced = 0, positive_biased = 0;
  for (int i = 0; i < ox.rows; ++i) {
    positive_balanced += balanced.Decision(ox.ptr<float>(i)) > 0;
    positive_biased += biased.Decision(ox.ptr<float>(i)) > 0;
  }
  EXPECT_GT(positive_biased, positive_balanced + 100);
}

TEST(BoxEvaluation, CountsMatchesOnceAndAveragesPrecision) {
  // Image 0: two boxes; image 1: one box.
  const std::vector<std::vector<cv::Rect2d>> truth = {{{0, 0, 10, 10}, {50, 50, 10, 10}}, {{20, 20, 10, 10}}};
  // Scores 0.9 (hit), 0.8 (the same box again: false), 0.7 (miss), 0.6 (hit in image 1).
  const std::vector<std::vector<BoxDetection>> found = {
      {{{1, 1, 10, 10}, 0.9}, {{0, 1, 10, 10}, 0.8}, {{200, 200, 10, 10}, 0.7}}, {{{21, 20, 10, 10}, 0.6}}};
  const BoxEvaluation e = EvaluateBoxes(found, truth, 0.65);
  // Precision at the ranks: 1, 1/2, 1/3, 2/4; recall 1/3, 1/3, 1/3, 2/3. Envelope: 1 then 0.5.
  EXPECT_NEAR(e.ap50, 1.0 / 3 + 0.5 / 3, 1e-9);
  EXPECT_EQ(e.true_boxes, 3);
  EXPECT_EQ(e.detections, 3);      // scores >= 0.65
  EXPECT_EQ(e.true_positives, 1);
  EXPECT_NEAR(e.precision, 1.0 / 3, 1e-9);
  EXPECT_NEAR(e.recall, 1.0 / 3, 1e-9);
  // Best F1: all four (2 hits of 3 boxes, 4 detections: 4/7) against the first (1/3 and 1: 0.5).
  EXPECT_DOUBLE_EQ(BestF1Threshold(found, truth), 0.6);
}

TEST(BoxEvaluation, SuppressionKeepsTheBestOfOverlappingBoxes) {
  const auto kept = SuppressBoxes({{{0, 0, 10, 10}, 0.5}, {{1, 1, 10, 10}, 0.9}, {{30, 0, 10, 10}, 0.1},
                                   {{2, 0, 10, 10}, 0.7}}, 0.35);
  ASSERT_EQ(kept.size(), 2u);
  EXPECT_DOUBLE_EQ(kept[0].score, 0.9);
  EXPECT_DOUBLE_EQ(kept[1].score, 0.1);
  // A dark opening found inside the burrow found around it (IoU 0.16, wholly inside): one object.
  const std::vector<BoxDetection> nested = {{{0, 0, 50, 50}, 0.9}, {{10, 10, 20, 20}, 0.5}};
  EXPECT_EQ(SuppressBoxes(nested, 0.35).size(), 2u);
  EXPECT_EQ(SuppressBoxes(nested, 0.35, 0.7).size(), 1u);
}

TEST(BoxedFolder, ReadsYoloBoxesAndGroupsStations) {
  test::ScratchDir dir;
  const auto images = WriteBoxedFolder(dir / "set", 0, 6, 2);
  ASSERT_EQ(images.size(), 6u);
  std::vector<cv::Rect2d> boxes;
  BurrowFrame(0, &boxes);
  // Names sort by station here (the day comes first); frame 0 is the first.
  ASSERT_EQ(images[0].boxes.size(), boxes.size());
  EXPECT_NEAR(images[0].boxes[0].x, boxes[0].x, 0.01);
  EXPECT_NEAR(images[0].boxes[0].width, boxes[0].width, 0.01);
  std::set<std::string> stations;
  for (const auto& b : images) stations.insert(b.station);
  EXPECT_EQ(stations.size(), 3u);
  const std::vector<int> folds = StationFolds(images, 2);
  for (size_t i = 0; i < images.size(); ++i)
    for (size_t j = 0; j < images.size(); ++j)
      if (images[i].station == images[j].station) EXPECT_EQ(folds[i], folds[j]);
  EXPECT_NE(*std::min_element(folds.begin(), folds.end()), *std::max_element(folds.begin(), folds.end()));

  // A malformed line is named with its file and line.
  const std::string label = std::filesystem::path(images[1].path).stem().string();
  std::ofstream(dir / "set/labels_gt/" + label + ".txt", std::ios::app) << "0 0.5 0.5\n";
  try {
    ReadBoxedFolder(dir / "set");
    FAIL() << "a short label line was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(label + ".txt:" + std::to_string(images[1].boxes.size() + 1)), std::string::npos) << e.what();
  }
  EXPECT_THROW(ReadBoxedFolder(dir / "nothing"), Error);
}

class TrainedDetector : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::ScratchDir();
    train_ = new std::vector<BoxedImage>(WriteBoxedFolder(*dir_ / "train", 0, 12));
    test_ = new std::vector<BoxedImage>(WriteBoxedFolder(*dir_ / "test", 100, 4));
    model_ = new BoxDetector(BoxDetector::Train(*train_, FastOptions()));
  }
  static void TearDownTestSuite() {
    delete model_;
    delete train_;
    delete test_;
    delete dir_;
  }
  static test::ScratchDir* dir_;
  static std::vector<BoxedImage>*train_, *test_;
  static BoxDetector* model_;
};
test::ScratchDir* TrainedDetector::dir_ = nullptr;
std::vector<BoxedImage>* TrainedDetector::train_ = nullptr;
std::vector<BoxedImage>* TrainedDetector::test_ = nullptr;
BoxDetector* TrainedDetector::model_ = nullptr;

TEST_F(TrainedDetector, FindsBurrowsOnFramesItNeverSaw) {
  const BoxEvaluation e = EvaluateBoxes(DetectAll(*model_, *test_), Truth(*test_), model_->threshold());
  EXPECT_GT(e.ap50, 0.8);
  EXPECT_GT(e.precision, 0.75);
  EXPECT_GT(e.recall, 0.75);
  // No detection on the laser dots or the timestamp.
  for (const auto& b : *test_) {
    const cv::Mat frame = cv::imread(b.path);
    for (const auto& d : model_->Detect(frame)) {
      const cv::Point2d c(d.box.x + d.box.width / 2, d.box.y + d.box.height / 2);
      EXPECT_FALSE(c.x < 200 && c.y < 20) << b.path << " " << d.box;
      for (const cv::Point2d dot : {cv::Point2d(frame.cols / 4, frame.rows / 2), cv::Point2d(3 * frame.cols / 4, frame.rows / 2)})
        EXPECT_GT(cv::norm(c - dot), 8) << b.path << " " << d.box;
    }
  }
}

TEST_F(TrainedDetector, HogPeerTrainsThroughTheSamePipeline) {
  const BoxDetector hog = BoxDetector::Train(*train_, FastOptions("hog"));
  const BoxEvaluation e = EvaluateBoxes(DetectAll(hog, *test_), Truth(*test_), hog.threshold());
  EXPECT_GT(e.ap50, 0.3);
  EXPECT_EQ(hog.Describe()["features"], "hog");
}

TEST_F(TrainedDetector, SavedModelDetectsTheSameAndForeignFilesAreRefused) {
  const std::string path = *dir_ / "burrows.yml.gz";
  model_->Save(path);
  EXPECT_TRUE(IsBoxDetectorFile(path));
  const BoxDetector loaded = BoxDetector::Load(path);
  EXPECT_EQ(loaded.options().label, "burrow");
  EXPECT_DOUBLE_EQ(loaded.threshold(), model_->threshold());
  const cv::Mat frame = cv::imread((*test_)[0].path);
  const auto a = model_->Detect(frame), b = loaded.Detect(frame);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].box, b[i].box);
    EXPECT_NEAR(a[i].score, b[i].score, 1e-4);
  }
  std::ofstream(*dir_ / "foreign.yml") << "%YAML:1.0\n---\nformat: something-else\n";
  EXPECT_FALSE(IsBoxDetectorFile(*dir_ / "foreign.yml"));
  EXPECT_THROW(BoxDetector::Load(*dir_ / "foreign.yml"), Error);
  EXPECT_THROW(BoxDetector::Load(*dir_ / "missing.yml"), Error);
}

TEST_F(TrainedDetector, SearchesAMosaicThroughTheCacheAndWritesADensityLayer) {
  // A 1600 x 1200 mosaic of four frames side by side (with their burrows) and a corner without data.
  cv::Mat mosaic(1200, 1600, CV_8UC3);
  std::vector<cv::Rect2d> truth;
  for (int k = 0; k < 4; ++k) {
    std::vector<cv::Rect2d> boxes;
    const cv::Mat frame = BurrowFrame(200 + k, &boxes, 800, 600);
    const cv::Point at((k % 2) * 800, (k / 2) * 600);
    frame.copyTo(mosaic(cv::Rect(at, frame.size())));
    for (auto b : boxes) truth.push_back(b + cv::Point2d(at));
  }
  cv::Mat bgra;
  cv::cvtColor(mosaic, bgra, cv::COLOR_BGR2BGRA);
  const cv::Rect empty(1300, 0, 300, 300);
  bgra(empty).setTo(cv::Scalar(0, 0, 0, 0));
  test::ScratchDir dir;
  Store store = Store::Create(dir / "store");
  Georef g;
  g.crs = CrsToWkt("EPSG:32755");
  g.geotransform = {500000, 0.002, 0, 6000000, 0, -0.002};  // 2 mm pixels
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(store.MosaicPath(), bgra, o, &g);
  BoxSearchOptions so;
  so.block = 512;  // several blocks, so boxes cross their borders
  so.density_cell = 0.8;  // metres: 400 pixels
  const BoxSearchSummary r = DetectBoxesInStore(Store::Open(dir / "store"), *model_, so);
  EXPECT_TRUE(r.georeferenced);
  std::ifstream in(r.output);
  const nlohmann::json doc = nlohmann::json::parse(in);
  int found = 0, in_empty = 0;
  std::vector<cv::Rect2d> boxes;
  for (const auto& f : doc["features"]) {
    const auto& b = f["properties"]["pixel_bbox"];
    boxes.emplace_back(b[0].get<double>(), b[1].get<double>(), b[2].get<double>(), b[3].get<double>());
    EXPECT_EQ(f["properties"]["class"], "burrow");
    in_empty += (cv::Rect2d(empty) & boxes.back()).area() > 0.6 * boxes.back().area();
  }
  for (const auto& t : truth) {
    if ((cv::Rect2d(empty) & t).area() > 0) continue;
    for (const auto& b : boxes)
      if ((b & t).area() / (b | t).area() >= 0.5) {
        ++found;
        break;
      }
  }
  const int reachable = static_cast<int>(std::count_if(truth.begin(), truth.end(), [&](const cv::Rect2d& t) { return (cv::Rect2d(empty) & t).area() == 0; }));
  EXPECT_GT(found, 0.7 * reachable) << found << " of " << reachable;
  EXPECT_EQ(in_empty, 0);
  EXPECT_EQ(r.detections, static_cast<int>(boxes.size()));

  // The density layer: per square metre, cells of 0.8 m (400 px), counts adding up.
  std::ifstream din(r.density_output);
  const nlohmann::json density = nlohmann::json::parse(din);
  EXPECT_EQ(density["rolamos"]["density_unit"], "per_m2");
  int counted = 0;
  double area = 0;
  for (const auto& f : density["features"]) {
    counted += f["properties"]["count"].get<int>();
    area += f["properties"]["area"].get<double>();
    const double a = f["properties"]["area"].get<double>();
    EXPECT_NEAR(f["properties"]["density"].get<double>(), f["properties"]["count"].get<int>() / a, 1e-9);
  }
  EXPECT_EQ(counted, r.detections);
  // 1600 x 1200 px of 2 mm, less the empty corner: 7.32 m^2.
  EXPECT_NEAR(area, (1600.0 * 1200 - 300 * 300) * 0.002 * 0.002, 0.1);
  EXPECT_EQ(r.density_cells, 12);  // 4 x 3 cells, none under a quarter empty
}

TEST(BoxValidation, NeverSplitsAStation) {
  test::ScratchDir dir;
  const auto images = WriteBoxedFolder(dir / "set", 300, 6, 2);
  BoxDetectorOptions o = FastOptions();
  o.hard_negative_rounds = 0;
  const BoxValidation v = CrossValidateBoxes(images, o, 3);
  ASSERT_EQ(v.folds.size(), 3u);
  EXPECT_EQ(v.pooled.images, 6);
  std::set<std::string> seen;
  for (const auto& stations : v.fold_stations) {
    EXPECT_EQ(stations.size(), 1u);
    for (const auto& s : stations) EXPECT_TRUE(seen.insert(s).second);
  }
  EXPECT_GT(v.pooled.ap50, 0.5);
  // Frames of a single station cannot be validated by station.
  EXPECT_THROW(CrossValidateBoxes(WriteBoxedFolder(dir / "one", 400, 2, 10), o, 3), Error);
}

}  // namespace
}  // namespace rolamos
