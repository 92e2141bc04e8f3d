// `rolamos objects` as a user runs it: train, eval (the accuracy line), detect into a store, and
// the bad-input errors (exit 1, the file named).
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "test_support.h"

namespace rolamos {
namespace {

using test::RunCli;
namespace fs = std::filesystem;

TEST(CliObjects, TrainEvalDetect) {
  test::ScratchDir dir;
  test::WriteShapesDataset(dir / "train", 20, 5, /*background=*/true);
  test::WriteShapesDataset(dir / "validation", 8, 6);
  const std::string model = dir / "model.yml.gz";
  auto r = RunCli("objects train -q --data " + (dir / "train") + " -o " + model +
                  " --image-size 96 --vocabulary 40 --kmeans-samples 20000 --folds 3");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("3 classes (bar, disc, star)"), std::string::npos) << r.output;
  ASSERT_TRUE(fs::exists(model));
  r = RunCli("objects eval -q --data " + (dir / "validation") + " --model " + model);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("accuracy: "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("confusion"), std::string::npos) << r.output;
  r = RunCli("objects eval -q --json --data " + (dir / "validation") + " --model " + model);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_GE(nlohmann::json::parse(r.output)["accuracy"].get<double>(), 0.85) << r.output;
  // The paper's word histograms: the Fisher-only defaults step aside without being asked to.
  r = RunCli("objects train -q --data " + (dir / "train") + " -o " + (dir / "bow.yml.gz") +
             " --encoding bow --kernel chi2 --image-size 96 --vocabulary 40 --kmeans-samples 20000 --folds 3");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("chi2 kernel"), std::string::npos) << r.output;
  // Settings chosen by cross-validation over both folders, then the final model on both.
  r = RunCli("objects validate -q --json --data " + (dir / "train") + " --data " + (dir / "validation") +
             " --validation-folds 3 --encoding vlad --image-size 96 --vocabulary 24 --kmeans-samples 8000 --folds 3");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto cv = nlohmann::json::parse(r.output);
  EXPECT_EQ(cv["fold_accuracy"].size(), 3u);
  EXPECT_GE(cv["mean"].get<double>(), 0.7) << r.output;
  r = RunCli("objects train -q --data " + (dir / "train") + " --data " + (dir / "validation") + " -o " + (dir / "both.yml.gz") +
             " --image-size 96 --vocabulary 40 --kmeans-samples 20000 --folds 3");
  ASSERT_EQ(r.exit_code, 0) << r.output;

  const std::string store = dir / "d.rolamos";
  r = RunCli("demo -q --size 1200 -o " + store);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The demo store has one patch and no global mosaic yet.
  r = RunCli("objects detect -q " + store + " --model " + model);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("rolamos compose"), std::string::npos) << r.output;
  r = RunCli("objects detect -q " + store + " --model " + model + " --patch 1 --window 160");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("detections from"), std::string::npos) << r.output;
  std::ifstream in(store + "/objects/detections.geojson");
  EXPECT_EQ(nlohmann::json::parse(in)["type"], "FeatureCollection");
}

// A box detector as a surveyor runs one: train on boxed frames, evaluate (the JSON the issue
// names), validate by station, detect over frames and over a store's mosaic with its density layer.
TEST(CliObjects, BoxDetectorTrainEvalValidateDetect) {
  test::ScratchDir dir;
  test::WriteBurrowFrames(dir / "train", 0, 8, 4);
  test::WriteBurrowFrames(dir / "test", 50, 3);
  const std::string model = dir / "burrows.yml.gz";
  auto r = RunCli("objects train -q --boxes " + (dir / "train") + " -o " + model + " --label burrow --max-box 100");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("box detector of burrow"), std::string::npos) << r.output;
  r = RunCli("objects eval -q --json --boxes " + (dir / "test") + " --model " + model);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto e = nlohmann::json::parse(r.output);
  EXPECT_GT(e["ap50"].get<double>(), 0.7) << r.output;
  EXPECT_GT(e["precision"].get<double>(), 0.6) << r.output;
  EXPECT_GT(e["recall"].get<double>(), 0.6) << r.output;
  r = RunCli("objects validate -q --json --boxes " + (dir / "train") + " --validation-folds 2 --max-box 100 --hard-negative-rounds 1");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto v = nlohmann::json::parse(r.output);
  EXPECT_EQ(v["validation"], "by station");
  ASSERT_EQ(v["folds"].size(), 2u);
  EXPECT_EQ(v["folds"][0]["stations"].size(), 1u);
  EXPECT_EQ(v["images"], 8);

  r = RunCli("objects detect -q --frames " + (dir / "test") + " --model " + model + " -o " + (dir / "found.json"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream found(dir / "found.json");
  const auto frames = nlohmann::json::parse(found);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_GT(frames[0]["detections"].size(), 3u);
  EXPECT_EQ(frames[0]["detections"][0]["class"], "burrow");

  // Over a store's mosaic: detections and the density layer beside them.
  const std::string store = dir / "d.rolamos";
  ASSERT_EQ(RunCli("demo -q --size 1200 -o " + store).exit_code, 0);
  r = RunCli("objects detect -q " + store + " --model " + model + " --patch 1 --density-cell 300");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Mpx/s"), std::string::npos) << r.output;
  std::ifstream density(store + "/objects/density.geojson");
  const auto d = nlohmann::json::parse(density);
  EXPECT_EQ(d["name"], "rolamos_density");
  EXPECT_GT(d["features"].size(), 0u);

  // Bad input: a label line that is not YOLO, and a class model where a box detector belongs.
  std::ofstream(dir / "train/labels_gt/extra.txt") << "0 0.5\n";
  cv::imwrite(dir / "train/images/extra.jpg", cv::Mat(64, 64, CV_8UC3, cv::Scalar(90, 90, 90)));
  r = RunCli("objects train -q --boxes " + (dir / "train") + " -o " + (dir / "x.yml.gz"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("extra.txt:1"), std::string::npos) << r.output;
  r = RunCli("objects eval -q --boxes " + (dir / "test") + " --model " + (dir / "missing.yml.gz"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("missing.yml.gz"), std::string::npos) << r.output;
}

TEST(CliObjects, BadInputIsAClearError) {
  test::ScratchDir dir;
  fs::create_directories(dir / "data/empty_class");
  test::WriteShapesDataset(dir / "data", 3, 7);
  auto r = RunCli("objects train -q --data " + (dir / "data") + " -o " + (dir / "m.yml.gz"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("empty_class: class folder holds no images"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.yml.gz"));
  std::ofstream(dir / "junk.yml.gz") << "\x1f\x8b garbage";
  r = RunCli("objects eval -q --data " + (dir / "data") + " --model " + (dir / "junk.yml.gz"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("junk.yml.gz"), std::string::npos) << r.output;
  r = RunCli("objects train -q --data " + (dir / "data") + " -o " + (dir / "m.yml.gz") + " --kernel sigmoid");
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("sigmoid"), std::string::npos) << r.output;
  r = RunCli("objects train -q --data " + (dir / "data") + " -o " + (dir / "m.yml.gz") + " --orientations 3");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("orientations must be 1, 2, 4 or 8"), std::string::npos) << r.output;
  r = RunCli("objects train -q --data " + (dir / "data") + " -o " + (dir / "m.yml.gz") + " --encoding vlad --colour-statistics");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("colour statistics need the Fisher encoding"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "m.yml.gz"));
}

}  // namespace
}  // namespace rolamos
