// The map in GIS clients, each a real one: GDAL's WMS driver (TMS minidriver) reads the served XYZ
// tiles, in pixels and in Web Mercator, at two zooms, and they equal `rolamos export` (pixels) or
// GDAL's own gdalwarp (Web Mercator); GDAL's WMTS driver opens the capabilities; /vsicurl/ reads
// mosaic.tif and an exported COG through range requests with the local checksums; bad requests get
// a clear 4xx and the server stays up; a STAC catalogue of two surveys is checked against the
// specification (STAC 1.0.0 Item and Catalog, projection extension 1.1.0) and read by OGR.
#include <httplib.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "rolamos/compose.hpp"
#include "rolamos/georeference.hpp"
#include "rolamos/tile_server.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

namespace fs = std::filesystem;

bool HaveGdalTools() {
  return test::HaveCommand("gdalinfo") && test::HaveCommand("gdal_translate") && test::HaveCommand("gdalwarp");
}

// One georeferenced survey (EPSG:32755, 1 cm pixels) shared by the tests, and a server on it.
class GisTest : public testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::ScratchDir();
    const Survey survey = WriteSurvey(test::SmallSurvey(24), *dir_ / "survey");
    test::MosaicAndCompose(*dir_ / "survey/frames", *dir_ / "s.rolamos");
    test::WriteSurveyNavigation(survey, *dir_ / "nav.csv", 420);
    NavigationCamera camera;
    camera.focal_px = 420;
    camera.width = 480;
    camera.height = 360;
    GeoreferenceMosaic(Store::Open(*dir_ / "s.rolamos"), ReadNavigationCsv(*dir_ / "nav.csv", camera));
    TileServerOptions o;
    o.port = 0;
    server_ = new TileServer(Store::Open(*dir_ / "s.rolamos"), o);
    port_ = server_->Start();
  }
  static void TearDownTestSuite() {
    delete server_;
    delete dir_;
  }
  static std::string Url(const std::string& path) { return "http://127.0.0.1:" + std::to_string(port_) + path; }
  static httplib::Result Get(const std::string& path, const httplib::Headers& headers = {}) {
    httplib::Client c("127.0.0.1", port_);
    return c.Get(path.c_str(), headers);
  }
  // Mean absolute colour difference where both images are fully covered (4-band files).
  static double MeanDifference(const std::string& a_path, const std::string& b_path, cv::Rect window, double* covered) {
    const cv::Mat a = cv::imread(a_path, cv::IMREAD_UNCHANGED), b = cv::imread(b_path, cv::IMREAD_UNCHANGED);
    EXPECT_EQ(a.channels(), 4) << a_path;
    EXPECT_EQ(b.channels(), 4) << b_path;
    if (a.empty() || b.empty() || a.channels() != 4 || b.channels() != 4) return 1e9;
    window &= cv::Rect(0, 0, std::min(a.cols, b.cols), std::min(a.rows, b.rows));
    double sum = 0;
    long long n = 0;
    for (int y = window.y; y < window.br().y; ++y)
      for (int x = window.x; x < window.br().x; ++x) {
        const cv::Vec4b p = a.at<cv::Vec4b>(y, x), q = b.at<cv::Vec4b>(y, x);
        if (p[3] != 255 || q[3] != 255) continue;
        for (int k = 0; k < 3; ++k) sum += std::abs(int(p[k]) - int(q[k]));
        n += 3;
      }
    *covered = double(n / 3) / double(std::max(1, window.area()));
    return n ? sum / double(n) : 1e9;
  }
  static test::ScratchDir* dir_;
  static TileServer* server_;
  static int port_;
};
test::ScratchDir* GisTest::dir_ = nullptr;
TileServer* GisTest::server_ = nullptr;
int GisTest::port_ = 0;

TEST_F(GisTest, GdalWmsReadsThePixelXyzTilesAtTwoZoomsAsExportDoes) {
  if (!HaveGdalTools()) GTEST_SKIP() << "GDAL's tools are not installed";
  auto images = nlohmann::json::parse(Get("/api/images")->body);
  const auto& mosaic = images[0]["name"] == "mosaic" ? images[0] : images[1];
  const int max_zoom = mosaic["xyz_max_zoom"];
  const int w = mosaic["width"], h = mosaic["height"];
  for (int z : {max_zoom, max_zoom - 1}) {
    SCOPED_TRACE("zoom " + std::to_string(z));
    const std::string wms = *dir_ / ("wms" + std::to_string(z) + ".png");
    const auto r = test::RunShell("gdal_translate -q -of PNG '/vsicurl/" + Url("/gdal/mosaic.xml?zoom=" + std::to_string(z)) +
                                  "' " + wms);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const double scale = std::ldexp(1.0, z - max_zoom);
    const std::string exported = *dir_ / ("export" + std::to_string(z) + ".png");
    ASSERT_EQ(test::RunCli("export -q " + (*dir_ / "s.rolamos") + " --scale " + std::to_string(scale) + " -o " + exported)
                  .exit_code, 0);
    double covered = 0;
    const double diff = MeanDifference(wms, exported, cv::Rect(0, 0, int(w * scale), int(h * scale)), &covered);
    EXPECT_LT(diff, 0.5) << "the served tiles differ from rolamos export at the same scale";
    EXPECT_GT(covered, 0.3);
    // Whole tiles: GDAL refused partial edge tiles ("Incorrect size 92 x 256 of downloaded block").
    EXPECT_EQ(r.output.find("Incorrect size"), std::string::npos) << r.output;
  }
}

TEST_F(GisTest, GdalWmsReadsTheWebMercatorTilesAsGdalwarpWarpsTheMosaic) {
  if (!HaveGdalTools()) GTEST_SKIP() << "GDAL's tools are not installed";
  const auto tilejson = nlohmann::json::parse(Get("/tilejson/mosaic.json")->body);
  const int max_zoom = tilejson["maxzoom"];
  for (int z : {max_zoom, max_zoom - 2}) {
    SCOPED_TRACE("zoom " + std::to_string(z));
    const std::string wms = *dir_ / ("merc" + std::to_string(z) + ".tif");
    auto r = test::RunShell("gdal_translate -q '/vsicurl/" + Url("/gdal/mosaic.webmercator.xml?zoom=" + std::to_string(z)) +
                            "' " + wms);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    // The same grid warped by gdalwarp from mosaic.tif: GDAL's own answer.
    const std::string info = test::RunShell("gdalinfo -json " + wms).output;
    const auto j = nlohmann::json::parse(info.substr(info.find('{')));
    const auto& gt = j["geoTransform"];
    const int sx = j["size"][0], sy = j["size"][1];
    char te[256];
    std::snprintf(te, sizeof te, "%.9f %.9f %.9f %.9f", gt[0].get<double>(), gt[3].get<double>() + sy * gt[5].get<double>(),
                  gt[0].get<double>() + sx * gt[1].get<double>(), gt[3].get<double>());
    const std::string truth = *dir_ / ("truth" + std::to_string(z) + ".tif");
    r = test::RunShell("gdalwarp -q -overwrite -t_srs EPSG:3857 -r bilinear -ovr AUTO -te " + std::string(te) + " -ts " +
                       std::to_string(sx) + " " + std::to_string(sy) + " " + (*dir_ / "s.rolamos/mosaic.tif") + " " + truth);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const std::string a = *dir_ / ("merc" + std::to_string(z) + ".png"), b = *dir_ / ("truth" + std::to_string(z) + ".png");
    ASSERT_EQ(test::RunShell("gdal_translate -q -of PNG " + wms + " " + a + " && gdal_translate -q -of PNG " + truth + " " + b)
                  .exit_code, 0);
    double covered = 0;
    EXPECT_LT(MeanDifference(a, b, cv::Rect(0, 0, sx, sy), &covered), 3.5) << "tile by tile against one warp";
    EXPECT_GT(covered, 0.05);
    EXPECT_NE(test::RunShell("gdalinfo " + wms).output.find("3857"), std::string::npos);
  }
}

TEST_F(GisTest, WmtsDriverOpensTheCapabilitiesAndTileJsonPlacesTheMap) {
  if (!HaveGdalTools()) GTEST_SKIP() << "GDAL's tools are not installed";
  const auto r = test::RunShell("gdalinfo 'WMTS:" + Url("/wmts/1.0.0/WMTSCapabilities.xml") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Driver: WMTS"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("3857"), std::string::npos);
  EXPECT_NE(r.output.find("ColorInterp=Alpha"), std::string::npos);
  // KVP GetCapabilities is the same document.
  EXPECT_EQ(Get("/wmts?service=WMTS&request=GetCapabilities")->body, Get("/wmts/1.0.0/WMTSCapabilities.xml")->body);
  // TileJSON: the map's bounds hold the navigation's fixes (near 147 E, 43.35 S).
  const auto t = nlohmann::json::parse(Get("/tilejson/mosaic.json")->body);
  EXPECT_EQ(t["tilejson"], "3.0.0");
  const auto& b = t["bounds"];
  EXPECT_GT(b[0].get<double>(), 146.99);
  EXPECT_LT(b[2].get<double>(), 147.01);
  EXPECT_LT(b[1].get<double>(), b[3].get<double>());
  EXPECT_NEAR(b[1].get<double>(), -43.35, 0.05);
  EXPECT_NE(t["tiles"][0].get<std::string>().find("/tiles/mosaic/webmercator/{z}/{x}/{y}.png"), std::string::npos);
  EXPECT_LE(t["minzoom"].get<int>(), t["maxzoom"].get<int>());
  // A KVP GetTile is the RESTful tile.
  const int z = t["maxzoom"];
  const double lon = t["center"][0], lat = t["center"][1];
  const long long n = 1LL << z;
  const long long x = static_cast<long long>((lon + 180) / 360 * n);
  const long long y = static_cast<long long>((1 - std::log(std::tan(lat * CV_PI / 180) + 1 / std::cos(lat * CV_PI / 180)) / CV_PI) / 2 * n);
  auto rest = Get("/tiles/mosaic/webmercator/" + std::to_string(z) + "/" + std::to_string(x) + "/" + std::to_string(y) + ".png");
  auto kvp = Get("/wmts?SERVICE=WMTS&REQUEST=GetTile&LAYER=mosaic&TILEMATRIXSET=GoogleMapsCompatible&TILEMATRIX=" +
                 std::to_string(z) + "&TILEROW=" + std::to_string(y) + "&TILECOL=" + std::to_string(x) + "&FORMAT=image/png");
  ASSERT_TRUE(rest && kvp);
  EXPECT_EQ(rest->status, 200);
  EXPECT_EQ(rest->body, kvp->body);
  const cv::Mat tile = cv::imdecode(std::vector<uchar>(rest->body.begin(), rest->body.end()), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(tile.size(), cv::Size(256, 256));
}

TEST_F(GisTest, RangeReadsGiveGdalTheFilesWithTheLocalChecksums) {
  if (!HaveGdalTools()) GTEST_SKIP() << "GDAL's tools are not installed";
  auto checksums = [](const std::string& what) {
    const std::string out = test::RunShell("gdalinfo -checksum '" + what + "'").output;
    std::string sums;
    for (size_t at = out.find("Checksum="); at != std::string::npos; at = out.find("Checksum=", at + 1))
      sums += out.substr(at, out.find('\n', at) - at) + ";";
    return sums;
  };
  const std::string local = checksums(*dir_ / "s.rolamos/mosaic.tif");
  ASSERT_FALSE(local.empty());
  EXPECT_EQ(checksums("/vsicurl/" + Url("/files/mosaic.tif")), local);
  // An exported COG inside the store is recorded in its manifest and served the same way.
  fs::create_directories(*dir_ / "s.rolamos/exports");
  const auto r = test::RunCli("export -q " + (*dir_ / "s.rolamos") + " --cog -o " + (*dir_ / "s.rolamos/exports/mosaic-cog.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("/files/exports/mosaic-cog.tif"), std::string::npos) << r.output;
  const std::string cog = checksums(*dir_ / "s.rolamos/exports/mosaic-cog.tif");
  ASSERT_FALSE(cog.empty());
  EXPECT_EQ(checksums("/vsicurl/" + Url("/files/exports/mosaic-cog.tif")), cog);
  // A single range: 206 with exactly those bytes.
  auto part = Get("/files/mosaic.tif", {{"Range", "bytes=100-299"}});
  ASSERT_TRUE(part);
  EXPECT_EQ(part->status, 206);
  EXPECT_EQ(part->body.size(), 200u);
  std::ifstream in(*dir_ / "s.rolamos/mosaic.tif", std::ios::binary);
  std::string bytes(200, '\0');
  in.seekg(100);
  in.read(bytes.data(), 200);
  EXPECT_EQ(part->body, bytes);
}

TEST_F(GisTest, BadRequestsGetAClearFourHundredAndTheServerStaysUp) {
  const auto size = fs::file_size(*dir_ / "s.rolamos/mosaic.tif");
  struct Case {
    std::string path;
    httplib::Headers headers;
    int status;
  };
  const std::vector<Case> cases = {
      {"/files/mosaic.tif", {{"Range", "bytes=" + std::to_string(size + 10) + "-"}}, 416},
      {"/files/mosaic.tif", {{"Range", "bytes=0-10,20-30"}}, 416},
      {"/files/mosaic.tif", {{"Range", "lines=0-10"}}, 416},
      {"/files/../store.json", {}, 404},
      {"/files/store.json", {}, 404},
      {"/files/%2e%2e/%2e%2e/etc/passwd", {}, 404},
      {"/wmts?SERVICE=WMTS&REQUEST=GetTile&LAYER=mosaic&TILEMATRIX=x&TILEROW=0&TILECOL=0", {}, 400},
      {"/wmts?SERVICE=WMS&REQUEST=GetMap", {}, 400},
      {"/wmts?SERVICE=WMTS&REQUEST=Explode", {}, 400},
      {"/wmts?SERVICE=WMTS&REQUEST=GetTile&LAYER=nope&TILEMATRIX=1&TILEROW=0&TILECOL=0", {}, 404},
      {"/wmts?SERVICE=WMTS&REQUEST=GetTile&LAYER=mosaic&TILEMATRIX=1&TILEROW=0&TILECOL=0&FORMAT=image/gif", {}, 400},
      {"/tilejson/nope.json", {}, 404},
      {"/tilejson/mosaic.json?format=bmp", {}, 400},
      {"/tiles/mosaic/webmercator/31/0/0.png", {}, 404},
      {"/tiles/mosaic/webmercator/5/99/0.png", {}, 404},
      {"/tiles/mosaic/webmercator/x/0/0.png", {}, 400},
      {"/tiles/mosaic/999999999999/0/0.png", {}, 404},
      {"/tiles/mosaic/2/99999999/0.png", {}, 404},
      {"/tiles/mosaic/1/0/0.jpg?background=red", {}, 400},
      {"/gdal/mosaic.xml?zoom=99", {}, 404},
      {"/gdal/mosaic.xml?zoom=-1", {}, 400},
  };
  for (const auto& c : cases) {
    auto r = Get(c.path, c.headers);
    ASSERT_TRUE(r) << c.path;
    EXPECT_EQ(r->status, c.status) << c.path << ": " << r->body;
    // Ours say why (a unit other than bytes is refused by the HTTP library itself, before us).
    if (c.status == 416 && c.headers.begin()->second.rfind("bytes=", 0) == 0)
      EXPECT_FALSE(r->get_header_value("X-Rolamos-Problem").empty()) << c.path;
  }
  auto alive = Get("/api/images");
  ASSERT_TRUE(alive);
  EXPECT_EQ(alive->status, 200);
}

// A map in a local frame (no navigation) has no Web Mercator tiles, and says why.
TEST(GisLocal, AMapWithoutACrsHasNoWebTilesAndSaysWhy) {
  test::ScratchDir dir;
  WriteSurvey(test::SmallSurvey(8), dir / "survey");
  test::MosaicAndCompose(dir / "survey/frames", dir / "s.rolamos");
  TileServerOptions o;
  o.port = 0;
  TileServer server(Store::Open(dir / "s.rolamos"), o);
  httplib::Client c("127.0.0.1", server.Start());
  auto t = c.Get("/tilejson/mosaic.json");
  ASSERT_TRUE(t);
  EXPECT_EQ(t->status, 404);
  EXPECT_NE(t->body.find("not georeferenced"), std::string::npos) << t->body;
  auto w = c.Get("/wmts/1.0.0/WMTSCapabilities.xml");
  ASSERT_TRUE(w);
  EXPECT_EQ(w->status, 400);
  EXPECT_NE(w->body.find("ExceptionReport"), std::string::npos);
  EXPECT_EQ(c.Get("/tiles/mosaic/0/0/0.png")->status, 200);  // pixel tiles still
}

// --- STAC: a catalogue of two surveys, checked against the specification -----------------------

bool IsRfc3339(const std::string& s) {
  // YYYY-MM-DDTHH:MM:SS(.fff)?(Z|+HH:MM)
  if (s.size() < 20 || s[4] != '-' || s[7] != '-' || s[10] != 'T' || s[13] != ':' || s[16] != ':') return false;
  return s.back() == 'Z' || s[s.size() - 3] == ':';
}

// STAC Item 1.0.0 (item-spec/json-schema/item.json) and the projection extension 1.1.0: the fields
// a validator checks, each with its type.
void ExpectValidItem(const nlohmann::json& item, const fs::path& dir) {
  EXPECT_EQ(item["type"], "Feature");
  EXPECT_EQ(item["stac_version"], "1.0.0");
  ASSERT_TRUE(item["id"].is_string() && !item["id"].get<std::string>().empty());
  ASSERT_TRUE(item["stac_extensions"].is_array());
  EXPECT_EQ(item["stac_extensions"][0], "https://stac-extensions.github.io/projection/v1.1.0/schema.json");
  // geometry: a GeoJSON (Multi)Polygon in WGS 84, rings closed; bbox [w, s, e, n] enclosing it.
  const auto& g = item["geometry"];
  ASSERT_TRUE(g["type"] == "Polygon" || g["type"] == "MultiPolygon");
  const auto polygons = g["type"] == "Polygon" ? nlohmann::json::array({g["coordinates"]}) : g["coordinates"];
  const auto& bbox = item["bbox"];
  ASSERT_TRUE(bbox.is_array() && bbox.size() == 4);
  for (const auto& polygon : polygons)
    for (const auto& ring : polygon) {
      ASSERT_GE(ring.size(), 4u);
      EXPECT_EQ(ring.front(), ring.back()) << "rings are closed";
      for (const auto& p : ring) {
        EXPECT_GE(p[0].get<double>(), bbox[0].get<double>() - 1e-9);
        EXPECT_LE(p[0].get<double>(), bbox[2].get<double>() + 1e-9);
        EXPECT_GE(p[1].get<double>(), bbox[1].get<double>() - 1e-9);
        EXPECT_LE(p[1].get<double>(), bbox[3].get<double>() + 1e-9);
        EXPECT_LE(std::abs(p[0].get<double>()), 180.0);
        EXPECT_LE(std::abs(p[1].get<double>()), 90.0);
      }
    }
  // properties: datetime null requires start_datetime and end_datetime (RFC 3339).
  const auto& pr = item["properties"];
  ASSERT_TRUE(pr.is_object());
  EXPECT_TRUE(pr["datetime"].is_null());
  EXPECT_TRUE(IsRfc3339(pr["start_datetime"].get<std::string>())) << pr["start_datetime"];
  EXPECT_TRUE(IsRfc3339(pr["end_datetime"].get<std::string>())) << pr["end_datetime"];
  EXPECT_LE(pr["start_datetime"].get<std::string>(), pr["end_datetime"].get<std::string>());
  EXPECT_TRUE(pr["gsd"].is_number() && pr["gsd"].get<double>() > 0);
  EXPECT_TRUE(pr["proj:epsg"].is_number_integer());
  EXPECT_TRUE(pr["proj:shape"].is_array() && pr["proj:shape"].size() == 2);
  EXPECT_TRUE(pr["proj:transform"].is_array() && pr["proj:transform"].size() == 6);
  // links: objects with rel and href; assets: href, type, roles; the files exist.
  ASSERT_TRUE(item["links"].is_array());
  for (const auto& l : item["links"]) EXPECT_TRUE(l["rel"].is_string() && l["href"].is_string());
  ASSERT_TRUE(item["assets"].is_object());
  for (const auto& [key, a] : item["assets"].items()) {
    ASSERT_TRUE(a["href"].is_string()) << key;
    EXPECT_TRUE(a["type"].is_string()) << key;
    EXPECT_TRUE(a["roles"].is_array()) << key;
    EXPECT_TRUE(fs::exists(dir / a["href"].get<std::string>())) << key;
  }
}

TEST_F(GisTest, StacCatalogueOfTwoSurveysFollowsTheSpecification) {
  const std::string catalogue = *dir_ / "catalogue";
  auto r = test::RunCli("export -q " + (*dir_ / "s.rolamos") + " --stac " + catalogue + " --stac-id dive-1 --title 'Dive 1'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::RunCli("export -q " + (*dir_ / "s.rolamos") + " --stac " + catalogue +
                   " --stac-id dive-2 --datetime 2026-05-01T08:00:00Z/2026-05-01T09:30:00Z");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // Again: the item is replaced, not listed twice.
  ASSERT_EQ(test::RunCli("export -q " + (*dir_ / "s.rolamos") + " --stac " + catalogue + " --stac-id dive-2 "
                         "--datetime 2026-05-01T08:00:00Z/2026-05-01T09:30:00Z").exit_code, 0);
  std::ifstream in(catalogue + "/catalog.json");
  const auto cat = nlohmann::json::parse(in);
  EXPECT_EQ(cat["type"], "Catalog");
  EXPECT_EQ(cat["stac_version"], "1.0.0");
  EXPECT_TRUE(cat["id"].is_string() && cat["description"].is_string());
  int items = 0;
  for (const auto& l : cat["links"]) {
    if (l["rel"] != "item") continue;
    ++items;
    const fs::path item_path = fs::path(catalogue) / l["href"].get<std::string>();
    std::ifstream f(item_path);
    const auto item = nlohmann::json::parse(f);
    SCOPED_TRACE(item_path.string());
    ExpectValidItem(item, item_path.parent_path());
    EXPECT_EQ(item["properties"]["proj:epsg"], 32755);
    EXPECT_NEAR(item["properties"]["gsd"].get<double>(), 0.01, 0.002);  // 1 cm pixels
    EXPECT_GT(item["geometry"]["coordinates"][0].size(), 5u) << "the covered ground's outline, not a box";
    // The footprint is the covered ground, inside (and smaller than) the bounding box; OGR reads
    // the item as a GeoJSON feature and finds the geometry valid.
    if (test::HaveCommand("ogrinfo")) {
      const auto o = test::RunShell("ogrinfo -q -dialect SQLite -sql \"SELECT ST_IsValid(geometry) AS ok, "
                                    "ST_Area(geometry) / ((MbrMaxX(geometry) - MbrMinX(geometry)) * "
                                    "(MbrMaxY(geometry) - MbrMinY(geometry))) AS fill FROM \\\"" +
                                    item_path.stem().string() + "\\\"\" " + item_path.string());
      EXPECT_NE(o.output.find("ok (Integer) = 1"), std::string::npos) << o.output;
      const size_t at = o.output.find("fill (Real) = ");
      ASSERT_NE(at, std::string::npos) << o.output;
      const double fill = std::stod(o.output.substr(at + 14));
      EXPECT_GT(fill, 0.2);
      EXPECT_LT(fill, 0.995) << "a footprint, not the bounding box";
    }
    // The COG asset is one GDAL reads, with the georeference.
    const auto info = test::RunShell("gdalinfo " + (item_path.parent_path() / item["assets"]["mosaic"]["href"].get<std::string>()).string());
    EXPECT_NE(info.output.find("LAYOUT=COG"), std::string::npos) << info.output;
    EXPECT_NE(info.output.find("32755"), std::string::npos);
  }
  EXPECT_EQ(items, 2);
  // A local-frame map cannot be catalogued on Earth: a clear error.
  test::ScratchDir other;
  WriteSurvey(test::SmallSurvey(6), other / "survey");
  test::MosaicAndCompose(other / "survey/frames", other / "s.rolamos");
  r = test::RunCli("export -q " + (other / "s.rolamos") + " --stac " + (other / "cat"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("not georeferenced"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace rolamos
