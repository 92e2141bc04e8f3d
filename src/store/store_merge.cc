#include "rolamos/store_merge.hpp"

#include <chrono>
#include <filesystem>
#include <map>
#include <optional>

#include "rolamos/error.hpp"
#include "store/frame_data.h"

namespace fs = std::filesystem;

namespace rolamos {

namespace {

// Hard link, or copy when the file system cannot link (another device, no links).
bool LinkOrCopy(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::create_hard_link(from, to, ec);
  if (!ec) return true;
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) Fail(to.string(), "cannot be written from " + from.string() + ": " + ec.message());
  return false;
}

}  // namespace

MergeSummary MergeStores(const std::vector<std::string>& inputs, const std::string& output, const ProgressFn& progress) {
  const auto start = std::chrono::steady_clock::now();
  if (inputs.size() < 2) Fail("merge", "needs at least two stores");
  MergeSummary summary;
  // Check them all before writing anything.
  std::vector<Store> stores;
  std::optional<std::array<int, 2>> frame_size;
  long long total = 0;
  for (const auto& in : inputs) {
    std::error_code ec;
    if (fs::exists(output, ec) && fs::equivalent(fs::path(in), fs::path(output), ec)) Fail(output, "is also an input");
    Store s = Store::Open(in);
    for (const auto& e : s.patches()) {
      const PatchSidecar side = s.ReadSidecar(e.id);
      if (side.frame_size) {
        if (frame_size && *frame_size != *side.frame_size)
          Fail(in, "has frames of " + std::to_string((*side.frame_size)[0]) + "x" + std::to_string((*side.frame_size)[1]) +
                       ", the stores before it " + std::to_string((*frame_size)[0]) + "x" + std::to_string((*frame_size)[1]) +
                       ": one map needs one camera");
        frame_size = side.frame_size;
      }
      ++total;
    }
    stores.push_back(s);
  }
  StoreOptions so;
  so.camera = stores.front().camera();
  so.crs = stores.front().crs();
  Store out = Store::Create(output, so);
  summary.linked = true;
  long long done = 0;
  for (size_t k = 0; k < stores.size(); ++k) {
    Store& in = stores[k];
    std::map<int, int> new_id;
    int next = out.NextPatchId();
    for (const auto& e : in.patches()) new_id[e.id] = next++;
    for (const auto& e : in.patches()) {
      PatchSidecar s = in.ReadSidecar(e.id);
      const int id = new_id[e.id];
      const fs::path dir = out.dir();
      summary.linked &= LinkOrCopy(fs::path(in.dir()) / e.image, out.PatchImagePath(id));
      const std::string stem = fs::path(out.PatchSidecarPath(id)).stem().string();
      if (s.frame_links) {
        std::vector<StoredLink> links = ReadFrameLinks((fs::path(in.dir()) / *s.frame_links).string());
        std::vector<StoredLink> kept;
        for (auto& l : links) {
          auto a = new_id.find(l.a.patch), b = new_id.find(l.b.patch);
          if (a == new_id.end() || b == new_id.end()) continue;  // a patch the input no longer has
          l.a.patch = a->second;
          l.b.patch = b->second;
          kept.push_back(std::move(l));
        }
        WriteFrameLinks((dir / "patches" / (stem + ".links.json")).string(), kept);
        s.frame_links = "patches/" + stem + ".links.json";
      }
      if (s.frame_features) {
        summary.linked &= LinkOrCopy(fs::path(in.dir()) / *s.frame_features, dir / "patches" / (stem + ".features"));
        s.frame_features = "patches/" + stem + ".features";
      }
      s.id = id;
      if (s.link) {
        auto it = new_id.find(s.link->previous_patch);
        if (it == new_id.end()) s.link.reset();
        else s.link->previous_patch = it->second;
      }
      // Placed anew by the merged store's own alignment.
      s.patch_to_global.reset();
      s.patch_to_global_online.reset();
      s.aligned.reset();
      s.component.reset();
      for (auto& f : s.frames) f.frame_to_global.reset();
      s.extra["merged_from"] = {{"store", fs::absolute(in.dir()).lexically_normal().string()}, {"patch", e.id}};
      out.CommitPatch(s);
      summary.frames += s.n_images;
      ++summary.patches;
      if (progress) progress(double(++done) / std::max(1LL, total));
    }
    ++summary.stores;
  }
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace rolamos
