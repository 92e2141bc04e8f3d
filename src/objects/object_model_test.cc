#include "rolamos/objects.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/error.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

ObjectTrainOptions SmallOptions() {
  ObjectTrainOptions o;
  o.features.image_size = 96;
  o.features.patch_sizes = {12, 24};
  o.vocabulary = 48;
  o.kmeans_samples = 20000;
  o.folds = 3;
  return o;
}

// Trained on one draw of the generated shapes, judged on another: each class must be told
// from the others (the data has what the classes differ by: shape and colour).
TEST(ObjectModel, TrainsSavesLoadsAndIdentifiesHeldOutShapes) {
  test::ScratchDir dir;
  test::WriteShapesDataset(dir / "train", 24, 1);
  test::WriteShapesDataset(dir / "validation", 10, 2);
  // The last: Fisher vectors with every addition (object view, colour statistics, places; the
  // defaults) in all eight orientations.
  for (const std::string variant : {"bow", "vlad", "fisher", "fisher-all"}) {
    ObjectTrainOptions o = SmallOptions();
    const std::string encoding = variant.substr(0, variant.find('-'));
    o.features.encoding = encoding;
    if (encoding == "fisher") o.vocabulary = 16, o.features.pca_dims = 32;
    if (variant == "fisher-all") {
      o.features.colour_pca_dims = 24;
      o.features.orientations = 8;
    } else {  // the plain encodings, with colour histograms
      o.features.object_view = o.features.colour_statistics = o.features.spatial_coordinates = false;
      o.features.orientations = 1;
      o.features.hue_bins = 12, o.features.saturation_bins = 4;
    }
    o.kernel = encoding == "bow" ? "chi2" : "linear";
    const ObjectModel model = ObjectModel::Train(dir / "train", o);
    EXPECT_EQ(model.classes(), test::kShapeClasses);
    const ObjectEvaluation e = EvaluateObjects(model, dir / "validation");
    EXPECT_EQ(e.images, 30);
    EXPECT_GE(e.accuracy, 0.9) << variant << "\n" << FormatEvaluation(e);
    EXPECT_NE(FormatEvaluation(e).find("accuracy: "), std::string::npos);
    // The file holds everything: a loaded model scores exactly as the trained one.
    const std::string path = dir / ("model-" + variant + ".yml.gz");
    model.Save(path);
    const ObjectModel loaded = ObjectModel::Load(path);
    EXPECT_EQ(loaded.classes(), model.classes());
    const cv::Mat probe = test::ShapeSample("disc", 99);
    const auto a = model.Classify(probe), b = loaded.Classify(probe);
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) {
      EXPECT_EQ(a[i].label, b[i].label);
      EXPECT_NEAR(a[i].score, b[i].score, 1e-5);
    }
    EXPECT_EQ(a.front().label, "disc");
    const auto d = loaded.Describe();
    EXPECT_EQ(d["version"], kObjectModelVersion);
    EXPECT_EQ(d["features"]["encoding"], encoding);
    EXPECT_GT(d["svm"]["cv_accuracy"].get<double>(), 0.8);
  }
}

// With a background class, the SVMs learn what is not an object: bare seafloor scores below
// zero for every class, and the background is never reported as a class.
TEST(ObjectModel, BackgroundClassTeachesWhatIsNotAnObject) {
  test::ScratchDir dir;
  test::WriteShapesDataset(dir / "train", 24, 3, /*background=*/true);
  const ObjectModel model = ObjectModel::Train(dir / "train", SmallOptions());
  EXPECT_EQ(model.classes(), test::kShapeClasses);
  int quiet = 0;
  for (uint32_t s = 0; s < 10; ++s) quiet += model.Classify(test::ShapeSample("background", 500 + s)).front().score < 0;
  EXPECT_GE(quiet, 8);
  EXPECT_GT(model.Classify(test::ShapeSample("star", 77)).front().score, 0);
}

TEST(ObjectModel, BadDataAndBadModelFilesAreClearErrors) {
  test::ScratchDir dir;
  const ObjectTrainOptions o = SmallOptions();
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Train(dir / "missing", o); }).find("is not a folder"), std::string::npos);
  fs::create_directories(dir / "empty");
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Train(dir / "empty", o); }).find("no class folders"), std::string::npos);
  test::WriteShapesDataset(dir / "data", 6, 4);
  fs::create_directories(dir / "data/crab");
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Train(dir / "data", o); }).find("crab: class folder holds no images"),
            std::string::npos);
  fs::remove(dir / "data/crab");
  std::ofstream(dir / "data/disc/999.png") << "not an image";
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Train(dir / "data", o); }).find("999.png: cannot be read"), std::string::npos);
  fs::remove(dir / "data/disc/999.png");
  ObjectTrainOptions bad = o;
  bad.kernel = "sigmoid";
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Train(dir / "data", bad); }).find("sigmoid"), std::string::npos);

  const ObjectModel model = ObjectModel::Train(dir / "data", o);
  const std::string good = dir / "m.yml.gz";
  model.Save(good);
  // Truncated.
  const std::string bytes = [&] {
    std::ifstream in(good, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }();
  std::ofstream(dir / "cut.yml.gz", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Load(dir / "cut.yml.gz"); }), "");
  // Another format version.
  model.Save(dir / "m.yml");
  std::ifstream in(dir / "m.yml");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  const size_t at = text.find("version: " + std::to_string(kObjectModelVersion));
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 10, "version: 7");
  std::ofstream(dir / "v7.yml") << text;
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Load(dir / "v7.yml"); }).find("format version 7"), std::string::npos);
  // Not a model at all, and no file.
  std::ofstream(dir / "other.yml") << "%YAML:1.0\n---\nanswer: 42\n";
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Load(dir / "other.yml"); }).find("not a rolamos object model"), std::string::npos);
  EXPECT_NE(test::ErrorOf([&] { ObjectModel::Load(dir / "none.yml.gz"); }).find("no such model file"), std::string::npos);
  // Evaluating on classes the model does not know.
  fs::create_directories(dir / "eval/whale");
  cv::imwrite(dir / "eval/whale/1.png", test::ShapeSample("bar", 1));
  EXPECT_NE(test::ErrorOf([&] { EvaluateObjects(model, dir / "eval"); }).find("does not know"), std::string::npos);
}

// Two folders joined by class name, dealt into stratified folds, each judged by a model that
// never saw it; the figures add up.
TEST(ObjectValidation, StratifiedFoldsOverJoinedFolders) {
  test::ScratchDir dir;
  test::WriteShapesDataset(dir / "a", 10, 3);
  test::WriteShapesDataset(dir / "b", 5, 4);
  const LabelledImages data = ReadLabelledFolders({dir / "a", dir / "b"});
  ASSERT_EQ(data.files.size(), 45u);
  ASSERT_EQ(data.classes.size(), 3u);
  const std::vector<int> folds = StratifiedFolds(data, 4, 9);
  for (int c = 0; c < 3; ++c) {
    std::vector<int> per_fold(4, 0);
    for (size_t i = 0; i < folds.size(); ++i)
      if (data.labels[i] == c) ++per_fold[static_cast<size_t>(folds[i])];
    EXPECT_LE(*std::max_element(per_fold.begin(), per_fold.end()) - *std::min_element(per_fold.begin(), per_fold.end()), 1);
  }
  EXPECT_NE(StratifiedFolds(data, 4, 10), folds);  // another repeat, another split

  ObjectTrainOptions o = SmallOptions();
  o.features.encoding = "vlad";
  o.features.object_view = o.features.colour_statistics = o.features.spatial_coordinates = false;
  o.features.orientations = 1;
  o.features.hue_bins = 12, o.features.saturation_bins = 4;
  const ObjectValidation v = CrossValidateObjects(data, o, 3, 1);
  ASSERT_EQ(v.fold_accuracy.size(), 3u);
  EXPECT_GT(v.mean, 0.8);
  double mean = 0, ss = 0;
  for (double a : v.fold_accuracy) mean += a / 3;
  for (double a : v.fold_accuracy) ss += (a - mean) * (a - mean);
  EXPECT_NEAR(v.mean, mean, 1e-12);
  EXPECT_NEAR(v.spread, std::sqrt(ss / 2), 1e-12);  // the sample standard deviation of the folds
  int total = 0;
  for (const auto& row : v.confusion)
    for (int n : row) total += n;
  EXPECT_EQ(total, 45);
  EXPECT_EQ(v.recall.size(), 3u);
  EXPECT_THROW(CrossValidateObjects(data, o, 1, 1), Error);
}

}  // namespace
}  // namespace rolamos
