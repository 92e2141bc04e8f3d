#include "rolamos/store.hpp"

#include <filesystem>
#include <fstream>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "rolamos/error.hpp"
#include "rolamos/tiff_writer.hpp"
#include "test_support.h"

namespace rolamos {
namespace {

using test::ErrorOf;

using test::ScratchDir;
namespace fs = std::filesystem;

PatchSidecar SampleSidecar(int id) {
  PatchSidecar s;
  s.id = id;
  s.size = {640, 480};
  s.n_images = 2;
  s.offset = {12.5, -3};
  s.first_homography = {1, 0, 5, 0, 1, 6, 0, 0, 1};
  s.last_homography = {1.01, 0.02, 40, -0.02, 1.01, 7, 1e-6, 0, 1};
  FrameRecord f;
  f.index = 0;
  f.source = "frame_00000.jpg";
  f.egomotion = Egomotion{{1, 0, 0, 0, 1, 0, 0, 0, 1}, {0.1, 0, 0}, {0, 0, 1}};
  f.matches = 412;
  f.inliers = 380;
  f.ecc = 0.93;
  s.frames.push_back(f);
  f.index = 1;
  f.source = "frame_00001.jpg";
  f.egomotion.reset();
  s.frames.push_back(f);
  s.rejected.push_back({17, "frame_00017.jpg", "kalman_gate"});
  return s;
}

void AddPatch(Store& store, int id) {
  TiffWriteOptions o;
  o.compression = Compression::kZstd;
  WritePyramidTiff(store.PatchImagePath(id), test::MakeImage(640, 480), o);
  store.CommitPatch(SampleSidecar(id));
}

TEST(Sidecar, RoundTripsEveryFieldAndKeepsUnknownOnes) {
  PatchSidecar s = SampleSidecar(3);
  s.extra["added_by_v2"] = {{"x", 1}};
  s.frames[0].extra["blur"] = 0.2;
  nlohmann::json j = SidecarToJson(s);
  // The DESIGN.md field names, exactly.
  for (const char* key : {"id", "size", "n_images", "offset", "first_homography",
                          "last_homography", "patch_to_global", "frames", "rejected"})
    EXPECT_TRUE(j.contains(key)) << key;
  for (const char* key : {"index", "source", "frame_to_patch", "egomotion", "matches", "inliers",
                          "ecc", "status"})
    EXPECT_TRUE(j["frames"][0].contains(key)) << key;
  EXPECT_TRUE(j["patch_to_global"].is_null());
  PatchSidecar back = ParseSidecar(j.dump(), "test");
  EXPECT_EQ(SidecarToJson(back), j);
  EXPECT_EQ(back.extra["added_by_v2"]["x"], 1);
  EXPECT_FALSE(back.frames[1].egomotion.has_value());
}

// The optional fields the engine, compose and align write, as version-1 stores hold them (homographies
// as doubles, as every writer emits them): typed on reading, and written back to the same bytes.
TEST(Sidecar, DocumentedOptionalFieldsAreTypedAndKeepTheirBytes) {
  nlohmann::json j = SidecarToJson(SampleSidecar(2));
  j["link"] = {{"previous_patch", 1}, {"to_previous", {1.0, 0.0, 5.5, 0.0, 1.0, -2.0, 0.0, 0.0, 1.0}},
               {"method", "place_recognition"}, {"inliers", 57}};
  j["pixel_budget"] = 5000000;
  j["frame_size"] = {800, 600};
  j["patch_to_global_online"] = {1.0, 0.0, 3.0, 0.0, 1.0, 4.0, 0.0, 0.0, 1.0};
  j["aligned"] = true;
  j["frames"][0]["bilateral_error"] = 0.42;
  j["frames"][0]["ecc_shift_px"] = 0.3;
  j["frames"][0]["frame_to_global"] = {1.0, 0.0, 7.0, 0.0, 1.0, 8.0, 0.0, 0.0, 1.0};
  const std::string text = j.dump();
  const PatchSidecar s = ParseSidecar(text, "p.json");
  ASSERT_TRUE(s.link.has_value());
  EXPECT_EQ(s.link->previous_patch, 1);
  EXPECT_DOUBLE_EQ(s.link->to_previous[2], 5.5);
  EXPECT_EQ(s.link->method, "place_recognition");
  EXPECT_EQ(s.link->inliers.value_or(0), 57);
  EXPECT_EQ(s.pixel_budget.value_or(0), 5000000);
  EXPECT_EQ(s.frame_size.value_or(std::array<int, 2>{0, 0})[1], 600);
  EXPECT_DOUBLE_EQ(s.patch_to_global_online.value()[5], 4);
  EXPECT_TRUE(s.aligned.value_or(false));
  EXPECT_DOUBLE_EQ(s.frames[0].bilateral_error.value_or(0), 0.42);
  EXPECT_DOUBLE_EQ(s.frames[0].ecc_shift_px.value_or(0), 0.3);
  EXPECT_DOUBLE_EQ(s.frames[0].frame_to_global.value()[2], 7);
  EXPECT_TRUE(s.extra.empty());
  EXPECT_EQ(SidecarToJson(s).dump(), text);
  // Absent fields stay absent; malformed ones are named.
  EXPECT_FALSE(ParseSidecar(SidecarToJson(SampleSidecar(2)).dump(), "q.json").link.has_value());
  j["link"]["previous_patch"] = "one";
  EXPECT_NE(ErrorOf([&] { ParseSidecar(j.dump(), "p.json"); }).find("previous_patch"), std::string::npos);
  j["link"]["previous_patch"] = 1;
  j["frame_size"] = {800};
  EXPECT_NE(ErrorOf([&] { ParseSidecar(j.dump(), "p.json"); }).find("frame_size"), std::string::npos);
}

TEST(Sidecar, MalformedFieldsAreNamed) {
  nlohmann::json good = SidecarToJson(SampleSidecar(1));
  auto error_with = [&](const std::function<void(nlohmann::json&)>& mutate) {
    nlohmann::json j = good;
    mutate(j);
    return ErrorOf([&] { ParseSidecar(j.dump(), "p.json"); });
  };
  EXPECT_NE(ErrorOf([] { ParseSidecar("{not json", "p.json"); }).find("p.json: is not valid JSON"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseSidecar("[1,2]", "p.json"); }).find("JSON object"), std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j.erase("size"); }).find("missing field \"size\""),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["id"] = "one"; }).find("field \"id\": must be an integer"),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["size"] = {0, 10}; }).find("\"size\""), std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["first_homography"] = {1, 2, 3}; }).find("9 numbers"),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["last_homography"] = {0, 0, 0, 0, 0, 0, 0, 0, 0}; })
                .find("singular"),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["frames"][1]["frame_to_patch"][4] = "x"; })
                .find("frames[1]: field \"frame_to_patch\"[4]"),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["rejected"][0].erase("reason"); }).find("rejected[0]"),
            std::string::npos);
  EXPECT_NE(error_with([](auto& j) { j["n_images"] = -4; }).find("outside"), std::string::npos);
}

TEST(Store, CreateCommitReopen) {
  ScratchDir dir;
  const std::string path = dir / "s.rolamos";
  {
    Store store = Store::Create(path);
    EXPECT_EQ(store.NextPatchId(), 1);
    AddPatch(store, 1);
    AddPatch(store, 2);
    GlobalRecord g = store.global();
    g.size = {2000, 1000};
    g.scale = 0.5;
    g.georef = Georef{"EPSG:32755", {500000, 0.01, 0, 5200000, 0, -0.01}};
    store.SetGlobal(g);
  }
  EXPECT_TRUE(Store::LooksLikeStore(path));
  Store store = Store::Open(path);
  ASSERT_EQ(store.patches().size(), 2u);
  EXPECT_EQ(store.NextPatchId(), 3);
  EXPECT_EQ(store.patches()[1].image, "patches/000002.tif");
  EXPECT_EQ(SidecarToJson(store.ReadSidecar(2)), SidecarToJson(SampleSidecar(2)));
  const GlobalRecord g = store.global();
  EXPECT_EQ(g.n_patches, 2);
  EXPECT_EQ(g.n_images, 4);
  EXPECT_EQ(g.size[0], 2000);
  EXPECT_DOUBLE_EQ(g.scale, 0.5);
  ASSERT_TRUE(g.georef.has_value());
  EXPECT_DOUBLE_EQ(g.georef->geotransform[3], 5200000);
  // The manifest holds the Table I global fields by their DESIGN.md names.
  nlohmann::json m = nlohmann::json::parse(std::ifstream(store.ManifestPath()));
  EXPECT_EQ(m["format"], "rolamos-store");
  EXPECT_EQ(m["version"], 1);
  for (const char* key : {"size", "offset", "n_images", "n_patches", "scale", "crs", "geotransform"})
    EXPECT_TRUE(m["global"].contains(key)) << key;
}

TEST(Store, CopiesShareOneManifest) {
  // The engine commits patches from its writer thread through its own copy of the handle; a
  // later SetGlobal through the caller's copy must not forget them.
  ScratchDir dir;
  Store caller = Store::Create(dir / "s.rolamos");
  Store writer = caller;
  AddPatch(writer, 1);
  EXPECT_EQ(caller.patches().size(), 1u);
  GlobalRecord g = caller.global();
  g.scale = 0.25;
  caller.SetGlobal(g);
  Store reopened = Store::Open(dir / "s.rolamos");
  EXPECT_EQ(reopened.patches().size(), 1u);
  EXPECT_DOUBLE_EQ(reopened.global().scale, 0.25);
}

TEST(Store, AChangeIsMadeToWhatTheStoreHoldsNow) {
  // Two handles, as two processes hold them: `export` recording a COG must not write the
  // manifest from what it read before the other committed a patch (the patch would be lost).
  ScratchDir dir;
  Store early = Store::Create(dir / "s.rolamos");
  Store other = Store::Open(dir / "s.rolamos");
  AddPatch(other, 1);
  std::ofstream(dir / "s.rolamos/exports.tif") << "a file";
  early.RecordExport({"exports.tif", "cog"});
  const Store reopened = Store::Open(dir / "s.rolamos");
  EXPECT_EQ(reopened.patches().size(), 1u);
  EXPECT_EQ(reopened.exports().size(), 1u);
}

TEST(Store, AChangeIsRefusedWhileAnotherProcessWritesTheStore) {
  ScratchDir dir;
  Store store = Store::Create(dir / "s.rolamos");
  AddPatch(store, 1);
  // Another process's engine, as the kernel sees it: a flock on the writer lock from another
  // open file, with its note.
  const std::string lock_path = dir / "s.rolamos/.writer.lock";
  std::ofstream(lock_path) << "a rolamos mosaic engine (pid 4242)\n";
  const int fd = ::open(lock_path.c_str(), O_RDWR | O_CLOEXEC);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::flock(fd, LOCK_EX | LOCK_NB), 0);
  GlobalRecord g = store.global();
  g.scale = 0.5;
  EXPECT_NE(ErrorOf([&] { store.SetGlobal(g); }).find("is being written by a rolamos mosaic engine (pid 4242)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { store.UpdateSidecar(SampleSidecar(1)); }).find("is being written by"), std::string::npos);
  ::close(fd);
  EXPECT_NE(Store::Open(dir / "s.rolamos").global().scale, 0.5);  // nothing written
  store.SetGlobal(g);  // and once it has ended, the change goes in
  EXPECT_EQ(Store::Open(dir / "s.rolamos").global().scale, 0.5);
}

TEST(Store, KilledWriterLeavesAStoreThatOpens) {
  ScratchDir dir;
  const std::string path = dir / "s.rolamos";
  Store store = Store::Create(path);
  AddPatch(store, 1);
  // What a process killed mid-patch leaves: a temporary image, an image without sidecar, and
  // a temporary manifest. None of it is listed, all of it is ignored.
  std::ofstream(path + "/patches/.000002.tif.tmp-123-0") << "half a tiff";
  fs::copy_file(store.PatchImagePath(1), store.PatchImagePath(2));
  std::ofstream(path + "/.store.json.tmp-123-1") << "{\"half\":";
  Store reopened = Store::Open(path);
  EXPECT_EQ(reopened.patches().size(), 1u);
  EXPECT_EQ(reopened.NextPatchId(), 2);
  // The next patch takes the orphan's place.
  AddPatch(reopened, 2);
  EXPECT_EQ(Store::Open(path).patches().size(), 2u);
}

TEST(Store, BadStoresAreClearErrors) {
  ScratchDir dir;
  EXPECT_NE(ErrorOf([&] { Store::Open(dir / "missing"); }).find("no such store"), std::string::npos);
  fs::create_directories(dir / "plain");
  EXPECT_NE(ErrorOf([&] { Store::Open(dir / "plain"); }).find("not a rolamos store"),
            std::string::npos);
  std::ofstream(dir / "file.txt") << "x";
  EXPECT_NE(ErrorOf([&] { Store::Open(dir / "file.txt"); }).find("is a file"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { Store::Create(dir / "file.txt"); }).find("not a directory"),
            std::string::npos);
  fs::create_directories(dir / "full");
  std::ofstream(dir / "full/x") << "x";
  EXPECT_NE(ErrorOf([&] { Store::Create(dir / "full"); }).find("not empty"), std::string::npos);

  const std::string s = dir / "s.rolamos";
  Store::Create(s);
  EXPECT_NE(ErrorOf([&] { Store::Create(s); }).find("already a store"), std::string::npos);
  auto with_manifest = [&](const std::string& text) {
    std::ofstream(s + "/store.json") << text;
    return ErrorOf([&] { Store::Open(s); });
  };
  EXPECT_NE(with_manifest("{").find("store.json: is not valid JSON"), std::string::npos);
  EXPECT_NE(with_manifest("{\"format\":\"other\"}").find("\"format\""), std::string::npos);
  EXPECT_NE(with_manifest("{\"format\":\"rolamos-store\",\"version\":99}").find("version 99"),
            std::string::npos);
  EXPECT_NE(with_manifest("{\"format\":\"rolamos-store\",\"version\":1,\"patches\":[{\"id\":1,"
                          "\"image\":\"../../etc/passwd\",\"sidecar\":\"a.json\"}],\"global\":{}}")
                .find("leaves the store"),
            std::string::npos);
  EXPECT_NE(with_manifest("{\"format\":\"rolamos-store\",\"version\":1,\"patches\":[],"
                          "\"global\":{\"size\":[1,1]}}")
                .find("global: missing field \"offset\""),
            std::string::npos);
}

TEST(Store, MissingOrWrongSidecarIsNamed) {
  ScratchDir dir;
  Store store = Store::Create(dir / "s.rolamos");
  AddPatch(store, 1);
  AddPatch(store, 2);
  fs::remove(store.PatchSidecarPath(1));
  EXPECT_NE(ErrorOf([&] { store.ReadSidecar(1); }).find("000001.json: sidecar of patch 1 is missing"),
            std::string::npos);
  std::ofstream(store.PatchSidecarPath(2)) << SidecarToJson(SampleSidecar(5)).dump();
  EXPECT_NE(ErrorOf([&] { store.ReadSidecar(2); }).find("says it is patch 5"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { store.ReadSidecar(9); }).find("no patch 9"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { store.CommitPatch(SampleSidecar(7)); }).find("must be written before"),
            std::string::npos);
}

}  // namespace
}  // namespace rolamos
