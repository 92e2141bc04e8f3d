#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/georef_io.hpp"
#include "rolamos/objects.hpp"
#include "rolamos/tiff_writer.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

struct Planted {
  std::string cls;
  cv::Point centre;
};

// A 1400 x 1000 mosaic of seafloor with objects planted at known places and a corner without
// data, in a new store.
Store MosaicStore(const std::string& dir, std::vector<Planted>* planted, const Georef* georef) {
  Store store = Store::Create(dir);
  cv::Mat bgr = RenderSeafloor(7000, 3000, 1400, 1000);
  *planted = {{"disc", {300, 250}}, {"star", {900, 300}}, {"disc", {1100, 750}}, {"star", {450, 700}}};
  uint32_t seed = 40;
  for (const auto& p : *planted) {
    const cv::Mat sample = test::ShapeSample(p.cls, seed++);
    // The object and a feathered ring of its own seafloor, so no hard square edge is planted.
    cv::Mat mask(sample.size(), CV_32F, cv::Scalar(0));
    cv::circle(mask, {80, 80}, 60, cv::Scalar(1), cv::FILLED);
    cv::GaussianBlur(mask, mask, {0, 0}, 8);
    const cv::Rect r(p.centre.x - 80, p.centre.y - 80, 160, 160);
    for (int y = 0; y < 160; ++y)
      for (int x = 0; x < 160; ++x) {
        const float m = mask.at<float>(y, x);
        cv::Vec3b& d = bgr(r).at<cv::Vec3b>(y, x);
        const cv::Vec3b s = sample.at<cv::Vec3b>(y, x);
        for (int k = 0; k < 3; ++k) d[k] = cv::saturate_cast<uchar>(m * s[k] + (1 - m) * d[k]);
      }
  }
  cv::Mat bgra;
  cv::cvtColor(bgr, bgra, cv::COLOR_BGR2BGRA);
  bgra(cv::Rect(1150, 0, 250, 250)).setTo(cv::Scalar(0, 0, 0, 0));  // no data there
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(store.MosaicPath(), bgra, o, georef);
  return store;
}

const ObjectModel& ShapesModel() {
  static const ObjectModel model = [] {
    test::ScratchDir* dir = new test::ScratchDir();  // lives as long as the model is used
    test::WriteShapesDataset(*dir / "train", 30, 11, /*background=*/true);
    ObjectTrainOptions o;
    o.features.image_size = 96;
    o.vocabulary = 48;
    o.kmeans_samples = 20000;
    o.folds = 3;
    return ObjectModel::Train(*dir / "train", o);
  }();
  return model;
}

TEST(DetectObjects, FindsPlantedObjectsAndWritesGeoJsonInMapCoordinates) {
  test::ScratchDir dir;
  std::vector<Planted> planted;
  Georef g;
  g.crs = CrsToWkt("EPSG:32755");
  g.geotransform = {500000, 0.002, 0, 5200000, 0, -0.002};
  const Store store = MosaicStore(dir / "s.rolamos", &planted, &g);
  DetectOptions o;
  o.window = 160;
  o.stride = 0.25;
  const DetectSummary r = DetectObjects(store, ShapesModel(), o);
  EXPECT_TRUE(r.georeferenced);
  EXPECT_GT(r.skipped, 0);  // the corner without data
  EXPECT_EQ(r.output, store.dir() + "/objects/detections.geojson");
  std::ifstream in(r.output);
  const nlohmann::json doc = nlohmann::json::parse(in);
  EXPECT_EQ(doc["type"], "FeatureCollection");
  EXPECT_EQ(doc["crs"]["properties"]["name"], "urn:ogc:def:crs:EPSG::32755");
  EXPECT_EQ(doc["rolamos"]["coordinates"], "map");
  ASSERT_EQ(doc["features"].size(), static_cast<size_t>(r.detections));
  int found = 0;
  for (const auto& p : planted) {
    bool hit = false;
    for (const auto& f : doc["features"]) {
      const auto b = f["properties"]["pixel_bbox"];
      const cv::Point2d centre(b[0].get<double>() + b[2].get<double>() / 2, b[1].get<double>() + b[3].get<double>() / 2);
      if (f["properties"]["class"] == p.cls && cv::norm(centre - cv::Point2d(p.centre)) < 60) {
        hit = true;
        // The polygon is the pixel box through the geotransform.
        const auto ring = f["geometry"]["coordinates"][0];
        EXPECT_NEAR(ring[0][0].get<double>(), 500000 + 0.002 * b[0].get<double>(), 1e-6);
        EXPECT_NEAR(ring[0][1].get<double>(), 5200000 - 0.002 * b[1].get<double>(), 1e-6);
      }
    }
    found += hit;
  }
  EXPECT_EQ(found, static_cast<int>(planted.size())) << doc.dump(1);
  // Non-maximum suppression leaves about one detection per object, not one per window; no disc
  // or star is found where none was planted (dark streaks of the seafloor may pass for bars).
  EXPECT_LT(r.detections, (r.windows - r.skipped) / 10);
  for (const auto& f : doc["features"]) {
    if (f["properties"]["class"] == "bar") continue;
    const auto b = f["properties"]["pixel_bbox"];
    const cv::Point2d centre(b[0].get<double>() + b[2].get<double>() / 2, b[1].get<double>() + b[3].get<double>() / 2);
    double nearest = 1e9;
    for (const auto& p : planted) nearest = std::min(nearest, cv::norm(centre - cv::Point2d(p.centre)));
    EXPECT_LT(nearest, 60) << f.dump();
  }
}

TEST(DetectObjects, PixelCoordinatesWithoutGeoreferenceAndClearErrors) {
  test::ScratchDir dir;
  std::vector<Planted> planted;
  const Store store = MosaicStore(dir / "s.rolamos", &planted, nullptr);
  DetectOptions o;
  o.window = 160;
  o.level = 1;  // windows at half resolution: 160 px there cover 320 px of level 0
  o.output = dir / "out/d.geojson";
  const DetectSummary r = DetectObjects(store, ShapesModel(), o);
  EXPECT_FALSE(r.georeferenced);
  std::ifstream in(r.output);
  const nlohmann::json doc = nlohmann::json::parse(in);
  EXPECT_EQ(doc["rolamos"]["coordinates"], "pixel");
  EXPECT_FALSE(doc.contains("crs"));
  // Windows are 320 level-0 pixels; the detection is the object's square inside its window.
  for (const auto& f : doc["features"]) {
    const auto w = f["properties"]["window_bbox"], b = f["properties"]["pixel_bbox"];
    EXPECT_NEAR(w[2].get<double>(), 320, 1);
    EXPECT_GE(b[0].get<double>(), w[0].get<double>() - 1e-6);
    EXPECT_LE(b[0].get<double>() + b[2].get<double>(), w[0].get<double>() + w[2].get<double>() + 1e-6);
    EXPECT_LE(b[2].get<double>(), 320 + 1e-6);
  }

  o.level = 9;
  EXPECT_NE(test::ErrorOf([&] { DetectObjects(store, ShapesModel(), o); }).find("has levels"), std::string::npos);
  o.level = 0;
  o.patch = 3;
  EXPECT_NE(test::ErrorOf([&] { DetectObjects(store, ShapesModel(), o); }).find("has no patch 3"), std::string::npos);
  o.patch = 0;
  o.stride = 0;
  EXPECT_NE(test::ErrorOf([&] { DetectObjects(store, ShapesModel(), o); }).find("stride"), std::string::npos);
  const Store empty = Store::Create(dir / "e.rolamos");
  o.stride = 0.5;
  EXPECT_NE(test::ErrorOf([&] { DetectObjects(empty, ShapesModel(), o); }).find("rolamos compose"), std::string::npos);
}

}  // namespace
}  // namespace rolamos
