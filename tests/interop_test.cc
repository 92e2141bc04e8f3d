// Our pyramids as other tools see them: GDAL lists overviews, OpenImageIO sees MIP levels,
// libvips reads every level, and every reader gets the pixels we wrote.
#include <gdal_priv.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/tiff_writer.hpp"
#include "rolamos/tiled_image.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

using test::ScratchDir;

class Interop : public testing::TestWithParam<int> {  // channels
 protected:
  void SetUp() override {
    image_ = test::MakeImage(1800, 1300, GetParam());
    TiffWriteOptions o;
    o.compression = Compression::kZstd;
    WritePyramidTiff(path_, image_, o);
    mine_ = std::make_unique<TiledImage>(TiledImage::Open(path_, std::make_shared<TileCache>()));
  }
  cv::Mat Level(int k) const {
    const auto& l = mine_->info().levels[k];
    return mine_->ReadRegion(k, cv::Rect(0, 0, int(l.width), int(l.height)));
  }
  ScratchDir dir_;
  std::string path_ = dir_ / "p.tif";
  cv::Mat image_;
  std::unique_ptr<TiledImage> mine_;
};

TEST_P(Interop, GdalListsOverviewsAndReadsTheSamePixels) {
  GDALAllRegister();
  GDALDatasetUniquePtr ds(GDALDataset::Open(path_.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
  ASSERT_TRUE(ds);
  GDALRasterBand* band = ds->GetRasterBand(1);
  ASSERT_EQ(band->GetOverviewCount(), mine_->num_levels() - 1);
  if (GetParam() == 4) EXPECT_EQ(ds->GetRasterBand(4)->GetColorInterpretation(), GCI_AlphaBand);
  for (int k = 1; k < mine_->num_levels(); ++k) {
    GDALRasterBand* ov = band->GetOverview(k - 1);
    cv::Mat mine = Level(k);
    ASSERT_EQ(ov->GetXSize(), mine.cols);
    ASSERT_EQ(ov->GetYSize(), mine.rows);
    cv::Mat gdal_band(mine.rows, mine.cols, CV_8U);
    ASSERT_EQ(ov->RasterIO(GF_Read, 0, 0, mine.cols, mine.rows, gdal_band.data, mine.cols,
                           mine.rows, GDT_Byte, 0, 0),
              CE_None);
    cv::Mat mine_first;  // GDAL band 1 is red (or gray)
    cv::extractChannel(mine, mine_first, GetParam() >= 3 ? 2 : 0);
    EXPECT_EQ(cv::norm(gdal_band, mine_first, cv::NORM_INF), 0.0) << "level " << k;
  }
}

TEST_P(Interop, OpenImageIoSeesMipLevels) {
  if (!test::HaveCommand("oiiotool")) GTEST_SKIP() << "oiiotool not installed";
  auto r = test::RunShell("oiiotool --info -v " + path_);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("MIP-map levels: 1800x1300 900x650 450x325 225x163"), std::string::npos)
      << r.output;
}

TEST_P(Interop, VipsReadsEveryLevel) {
  if (!test::HaveCommand("vips")) GTEST_SKIP() << "vips not installed";
  for (int k = 0; k < mine_->num_levels(); ++k) {
    const std::string out = dir_ / ("vips" + std::to_string(k) + ".png");
    auto r = test::RunShell("vips copy '" + path_ + "[page=" + std::to_string(k) + "]' " + out);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    cv::Mat v = cv::imread(out, cv::IMREAD_UNCHANGED);
    EXPECT_EQ(cv::norm(v, Level(k), cv::NORM_INF), 0.0) << "level " << k;
  }
}

INSTANTIATE_TEST_SUITE_P(Channels, Interop, testing::Values(1, 3, 4));

}  // namespace
}  // namespace rolamos
