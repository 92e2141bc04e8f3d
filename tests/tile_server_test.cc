// The tile server over real HTTP on loopback: tiles match the stored pixels at every zoom, the
// Deep Zoom descriptor is right, caching works, and malformed or hostile requests get 4xx.
#include "rolamos/tile_server.hpp"

#include <httplib.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/tiff_writer.hpp"
#include "rolamos/tiled_image.hpp"
#include "server/overlays.h"
#include "test_support.h"

namespace rolamos {
namespace {

class TileServerTest : public testing::Test {
 protected:
  void SetUp() override {
    auto r = test::RunCli("demo -q --size 1500 --compression zstd -o " + (dir_ / "d.rolamos"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    TileServerOptions o;
    o.port = 0;
    server_ = std::make_unique<TileServer>(Store::Open(dir_ / "d.rolamos"), o);
    port_ = server_->Start();
    client_ = std::make_unique<httplib::Client>("127.0.0.1", port_);
    image_ = std::make_unique<TiledImage>(TiledImage::Open(dir_ / "d.rolamos/patches/000001.tif"));
  }
  void TearDown() override { server_->Stop(); }

  cv::Mat Get(const std::string& path, int expect = 200) {
    auto res = client_->Get(path.c_str());
    EXPECT_TRUE(res) << path;
    if (!res) return {};
    EXPECT_EQ(res->status, expect) << path << ": " << res->body;
    if (res->status != 200) return {};
    std::vector<uchar> bytes(res->body.begin(), res->body.end());
    return cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
  }

  test::ScratchDir dir_;
  std::unique_ptr<TileServer> server_;
  int port_ = 0;
  std::unique_ptr<httplib::Client> client_;
  std::unique_ptr<TiledImage> image_;
};

TEST_F(TileServerTest, TilesAreTheStoredPixelsAtEveryZoom) {
  auto list = client_->Get("/api/images");
  ASSERT_TRUE(list);
  auto j = nlohmann::json::parse(list->body);
  ASSERT_EQ(j.size(), 1u);
  EXPECT_EQ(j[0]["name"], "patch-1");
  const int max_zoom = j[0]["xyz_max_zoom"];
  EXPECT_EQ(max_zoom, 3);  // 1500 px: 188, 375, 750, 1500 -> zooms 0..3
  // Full resolution: exactly the stored pixels (PNG is lossless).
  // XYZ tiles are whole 256 x 256 BGRA tiles: the stored colour, alpha 255 where the image is.
  cv::Mat t = Get("/tiles/patch-1/3/1/2.png");
  ASSERT_EQ(t.type(), CV_8UC4);
  cv::Mat colour, alpha;
  cv::cvtColor(t, colour, cv::COLOR_BGRA2BGR);
  cv::extractChannel(t, alpha, 3);
  cv::Mat stored = image_->ReadRegion(0, cv::Rect(256, 512, 256, 256));
  if (stored.channels() == 4) cv::cvtColor(stored, stored, cv::COLOR_BGRA2BGR);
  EXPECT_EQ(cv::norm(colour, stored, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::countNonZero(alpha == 255), 256 * 256);
  // Edge tile: whole, transparent past the image (as GDAL, Leaflet and QGIS expect).
  cv::Mat edge = Get("/tiles/patch-1/3/5/5.png");
  ASSERT_EQ(edge.size(), cv::Size(256, 256));
  cv::extractChannel(edge, alpha, 3);
  EXPECT_EQ(cv::countNonZero(alpha), (1500 - 5 * 256) * (1500 - 5 * 256));
  // JPEG has no alpha: the part past the image takes the colour the request asks for.
  cv::Mat white = Get("/tiles/patch-1/3/5/5.jpg?background=ffffff");
  ASSERT_EQ(white.size(), cv::Size(256, 256));
  EXPECT_GT(cv::mean(white(cv::Rect(230, 230, 26, 26)))[0], 250);
  cv::Mat black = Get("/tiles/patch-1/3/5/5.jpg");
  EXPECT_LT(cv::mean(black(cv::Rect(230, 230, 26, 26)))[0], 5);
  // In the zoom's grid but off the image: a transparent tile, not an error.
  cv::Mat empty = Get("/tiles/patch-1/3/7/7.png");
  ASSERT_EQ(empty.size(), cv::Size(256, 256));
  cv::extractChannel(empty, alpha, 3);
  EXPECT_EQ(cv::countNonZero(alpha), 0);
  // Zoom 0: the whole image in one tile, the area average of it.
  // WebP tiles: the same pixels within lossy coding.
  cv::Mat w = Get("/tiles/patch-1/3/1/2.webp");
  ASSERT_FALSE(w.empty());
  if (w.channels() == 4) cv::cvtColor(w, w, cv::COLOR_BGRA2BGR);
  EXPECT_GE(test::Psnr(w, colour), 30.0);
  cv::Mat whole = Get("/tiles/patch-1/0/0/0.jpg");
  ASSERT_EQ(whole.size(), cv::Size(256, 256));
  cv::Mat expected = image_->ReadResampled(0, 0, 1.0 / 8, cv::Size(188, 188));
  EXPECT_GE(test::Psnr(whole(cv::Rect(0, 0, 188, 188)), expected), 30.0);
  // Deep Zoom: descriptor and the same tiles under their levels.
  auto dzi = client_->Get("/dzi/patch-1.dzi");
  ASSERT_TRUE(dzi);
  EXPECT_NE(dzi->body.find("Width=\"1500\" Height=\"1500\""), std::string::npos) << dzi->body;
  cv::Mat same = Get("/dzi/patch-1_files/11/1_2.png");  // ceil(log2 1500) = 11: full resolution
  EXPECT_EQ(cv::norm(same, colour, cv::NORM_INF), 0.0);
  cv::Mat one_pixel = Get("/dzi/patch-1_files/0/0_0.png");
  EXPECT_EQ(one_pixel.size(), cv::Size(1, 1));
}

TEST_F(TileServerTest, CachingHeadersAndRevalidation) {
  auto first = client_->Get("/tiles/patch-1/2/1/1.jpg");
  ASSERT_TRUE(first);
  const std::string etag = first->get_header_value("ETag");
  EXPECT_FALSE(etag.empty());
  EXPECT_NE(first->get_header_value("Cache-Control").find("max-age"), std::string::npos);
  auto again = client_->Get("/tiles/patch-1/2/1/1.jpg", {{"If-None-Match", etag}});
  ASSERT_TRUE(again);
  EXPECT_EQ(again->status, 304);
}

TEST_F(TileServerTest, MalformedAndHostileRequestsGet4xx) {
  for (const std::string path : {"/tiles/patch-1/a/0/0.jpg", "/tiles/patch-1/1/-1/0.jpg",
                                 "/tiles/patch-1/1/0/0.gif", "/tiles/patch-1/99999999999999/0/0.jpg",
                                 "/dzi/patch-1_files/x/0_0.jpg"}) {
    auto r = client_->Get(path.c_str());
    ASSERT_TRUE(r) << path;
    EXPECT_GE(r->status, 400) << path;
    EXPECT_LT(r->status, 500) << path;
  }
  for (const std::string path : {"/tiles/patch-1/4/0/0.jpg", "/tiles/patch-1/3/9/0.jpg",
                                 "/tiles/patch-9/0/0/0.jpg", "/tiles/..%2F..%2Fstore.json/0/0/0.jpg",
                                 "/../../etc/passwd", "/dzi/patch-1_files/12/0_0.jpg", "/nothing"}) {
    auto r = client_->Get(path.c_str());
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, 404) << path;
  }
  // Still serving after all that.
  EXPECT_FALSE(Get("/tiles/patch-1/0/0/0.jpg").empty());
}

// The page and its API: the viewer from the binary, overlays from the sidecar, and exports that
// are the stored pixels, with bounds on what a request may ask for.
TEST_F(TileServerTest, ViewerPageOverlaysAndExport) {
  auto page = client_->Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("openseadragon.min.js"), std::string::npos);
  EXPECT_EQ(client_->Get("/openseadragon.min.js")->status, 200);
  EXPECT_EQ(client_->Get("/viewer.js")->status, 200);
  auto o = client_->Get("/api/overlays/patch-1");
  ASSERT_TRUE(o);
  ASSERT_EQ(o->status, 200) << o->body;
  const auto j = nlohmann::json::parse(o->body);
  ASSERT_EQ(j["outlines"].size(), 1u);
  EXPECT_EQ(j["outlines"][0]["points"][2][0].get<double>(), 1500.0);
  EXPECT_EQ(client_->Get("/api/overlays/patch-7")->status, 404);

  const cv::Mat png = Get("/api/export/patch-1?region=100,200,300,150&format=png");
  ASSERT_EQ(png.size(), cv::Size(300, 150));
  cv::Mat stored = image_->ReadRegion(0, cv::Rect(100, 200, 300, 150));
  if (stored.channels() == 4 && png.channels() == 3) cv::cvtColor(stored, stored, cv::COLOR_BGRA2BGR);
  EXPECT_EQ(cv::norm(png, stored, cv::NORM_INF), 0.0);
  const cv::Mat half = Get("/api/export/patch-1?region=0,0,1500,1500&scale=0.5&format=jpg");
  EXPECT_EQ(half.size(), cv::Size(750, 750));
  for (const std::string bad : {"region=1,2,3", "region=-5,0,10,10", "region=0,0,0,10", "region=0,0,10,10&format=gif",
                                "region=0,0,10,10&scale=2", "region=0,0,100000000,100000000"}) {
    auto r = client_->Get(("/api/export/patch-1?" + bad).c_str());
    ASSERT_TRUE(r) << bad;
    EXPECT_EQ(r->status, 400) << bad << ": " << r->body;
  }
  auto outside = client_->Get("/api/export/patch-1?region=1400,1400,500,500");
  ASSERT_TRUE(outside);
  EXPECT_EQ(outside->status, 400) << outside->body;  // leaves the image: the export code says so
}

// Map coordinates under the cursor come from the overlays' georeference of the image.
TEST(Overlays, CarryTheImageGeoreference) {
  test::ScratchDir dir;
  Store store = Store::Create(dir / "g.rolamos");
  Georef g;
  g.crs = CrsToWkt("EPSG:32755");
  g.geotransform = {500000, 0.01, 0, 5200000, 0, -0.01};
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(store.MosaicPath(), test::MakeImage(600, 400), o, &g);
  const auto j = ImageOverlays(store, "mosaic", store.MosaicPath());
  ASSERT_TRUE(j["georef"].is_object()) << j.dump();
  EXPECT_EQ(j["georef"]["crs"], "EPSG::32755");
  EXPECT_DOUBLE_EQ(j["georef"]["geotransform"][1].get<double>(), 0.01);
  EXPECT_TRUE(j["outlines"].empty());
}

}  // namespace
}  // namespace rolamos
