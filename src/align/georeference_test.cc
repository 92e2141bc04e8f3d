// Vehicle navigation (position, altitude, heading) placing a composed mosaic on the map: made from
// a synthetic survey's ground truth, so the fitted georeference must agree with it closely, in
// eastings/northings and in latitude/longitude.
#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "rolamos/compose.hpp"
#include "rolamos/error.hpp"
#include "rolamos/georeference.hpp"
#include "rolamos/mosaicker.hpp"
#include "rolamos/survey.hpp"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

using test::WriteSurveyNavigation;

TEST(Navigation, VehicleNavigationPlacesTheMosaic) {
  test::ScratchDir dir;
  const Survey survey = WriteSurvey(test::SmallSurvey(16), dir / "survey");
  Store store = test::MosaicAndCompose(dir / "survey/frames", dir / "s.rolamos");
  NavigationCamera camera;
  camera.focal_px = 420;
  camera.width = 480;
  camera.height = 360;
  WriteSurveyNavigation(survey, dir / "nav.csv", 420, false);
  const GeoreferenceResult g = GeoreferenceMosaic(store, ReadNavigationCsv(dir / "nav.csv", camera));
  EXPECT_EQ(g.frames_used, 16);
  EXPECT_LT(g.median_residual_m, 0.03);  // 3 texture pixels
  EXPECT_NEAR(std::hypot(g.georef.geotransform[1], g.georef.geotransform[4]), 0.01, 0.001);
  EXPECT_NE(g.georef.crs.find("32755"), std::string::npos);

  WriteSurveyNavigation(survey, dir / "latlon.csv", 420, true);
  const GeoreferenceResult h = GeoreferenceMosaic(store, ReadNavigationCsv(dir / "latlon.csv", camera));
  EXPECT_LT(h.median_residual_m, 0.05);
  EXPECT_NE(h.georef.crs.find("32755"), std::string::npos);  // the UTM zone of 147 E, south
}

TEST(Navigation, BadNavigationFilesAreClearErrors) {
  test::ScratchDir dir;
  NavigationCamera camera;
  camera.width = 480;
  camera.height = 360;
  std::ofstream(dir / "a.csv") << "frame,easting,northing,epsg,altitude,heading\nf1.jpg,500000,5200000,32755,3,0\n";
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(dir / "a.csv", camera); }).find("focal"), std::string::npos);
  camera.focal_px = 420;
  std::ofstream(dir / "b.csv") << "frame,easting,northing,altitude,heading\nf1.jpg,500000,5200000,3,0\n";
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(dir / "b.csv", camera); }).find("CRS must be given"), std::string::npos);
  std::ofstream(dir / "c.csv") << "frame,lat,lon,altitude,heading\nf1.jpg,-43.5,abc,3,0\n";
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(dir / "c.csv", camera); }).find("c.csv:2: column lon is not a number"),
            std::string::npos);
  std::ofstream(dir / "d.csv") << "frame,lat,lon,altitude,heading\nf1.jpg,-43.5,147,-2,0\n";
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(dir / "d.csv", camera); }).find("altitude must be positive"),
            std::string::npos);
  std::ofstream(dir / "e.csv") << "frame,depth\nf1.jpg,30\n";
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(dir / "e.csv", camera); }).find("needs the columns"), std::string::npos);
}

// A navigation CSV that grows while a live run reads it: a bad line is skipped and named, the
// last line is left until its newline is written, and the good lines are read; the strict reader
// (compose) still fails on the bad line, naming it.
TEST(Navigation, AGrowingCsvSkipsBadLinesAndWaitsForTheLastOne) {
  test::ScratchDir dir;
  NavigationCamera camera;
  camera.focal_px = 420;
  camera.width = 480;
  camera.height = 360;
  const std::string csv = dir / "nav.csv";
  {
    std::ofstream out(csv);
    out << "frame,easting,northing,epsg,altitude,heading\n"
        << "a.jpg,500000,5200000,32755,4.2,0\n"
        << "b.jpg,500001,north,32755,4.2,0\n"
        << "c.jpg,500002,5200000,32755,4.2,0\n"
        << "d.jpg,500003,52000";  // being written
  }
  std::vector<std::string> skipped;
  const auto nav = ReadNavigationCsv(csv, camera, "", &skipped);
  EXPECT_EQ(nav.size(), 2u);
  EXPECT_TRUE(nav.count("a.jpg") && nav.count("c.jpg"));
  ASSERT_EQ(skipped.size(), 1u);
  EXPECT_NE(skipped[0].find("nav.csv:3"), std::string::npos) << skipped[0];
  EXPECT_NE(skipped[0].find("northing"), std::string::npos) << skipped[0];
  EXPECT_NE(test::ErrorOf([&] { ReadNavigationCsv(csv, camera); }).find("nav.csv:3"), std::string::npos);
  {
    std::ofstream out(csv, std::ios::app);
    out << "00,32755,4.2,0\n";
  }
  skipped.clear();
  EXPECT_EQ(ReadNavigationCsv(csv, camera, "", &skipped).size(), 3u) << "the last line, once finished";
  // A header alone is no error while growing.
  {
    std::ofstream out(csv);
    out << "frame,easting,northing,epsg,altitude,heading\n";
  }
  EXPECT_TRUE(ReadNavigationCsv(csv, camera, "", &skipped).empty());
}

}  // namespace
}  // namespace rolamos
