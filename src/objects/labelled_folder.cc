#include <algorithm>
#include <filesystem>
#include <set>

#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"

namespace rolamos {

namespace fs = std::filesystem;

namespace {

bool IsImageName(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".tif" || ext == ".tiff" ||
         ext == ".bmp" || ext == ".webp";
}

}  // namespace

LabelledImages ReadLabelledFolder(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    Fail(dir, "is not a folder (expected a folder per class, e.g. " + dir + "/Crab/*.jpg)");
  LabelledImages out;
  for (const auto& entry : fs::directory_iterator(dir))
    if (entry.is_directory() && entry.path().filename().string()[0] != '.')
      out.classes.push_back(entry.path().filename().string());
  std::sort(out.classes.begin(), out.classes.end());
  if (out.classes.empty()) Fail(dir, "holds no class folders (expected a folder per class)");
  for (size_t c = 0; c < out.classes.size(); ++c) {
    std::vector<std::string> files;
    for (const auto& entry : fs::directory_iterator(fs::path(dir) / out.classes[c]))
      if (entry.is_regular_file() && IsImageName(entry.path())) files.push_back(entry.path().string());
    if (files.empty())
      Fail((fs::path(dir) / out.classes[c]).string(), "class folder holds no images (.jpg, .png, .tif, ...)");
    std::sort(files.begin(), files.end());
    for (auto& f : files) {
      out.files.push_back(std::move(f));
      out.labels.push_back(static_cast<int>(c));
    }
  }
  return out;
}

LabelledImages ReadLabelledFolders(const std::vector<std::string>& dirs) {
  if (dirs.empty()) Fail("labelled images", "no folder given");
  std::vector<LabelledImages> parts;
  std::set<std::string> names;
  for (const auto& d : dirs) {
    parts.push_back(ReadLabelledFolder(d));
    names.insert(parts.back().classes.begin(), parts.back().classes.end());
  }
  LabelledImages out;
  out.classes.assign(names.begin(), names.end());
  for (const auto& p : parts)
    for (size_t i = 0; i < p.files.size(); ++i) {
      out.files.push_back(p.files[i]);
      const std::string& c = p.classes[static_cast<size_t>(p.labels[i])];
      out.labels.push_back(static_cast<int>(std::find(out.classes.begin(), out.classes.end(), c) - out.classes.begin()));
    }
  return out;
}

LabelledImages Subset(const LabelledImages& data, const std::vector<int>& rows) {
  LabelledImages out;
  out.classes = data.classes;
  for (int r : rows) {
    out.files.push_back(data.files[static_cast<size_t>(r)]);
    out.labels.push_back(data.labels[static_cast<size_t>(r)]);
  }
  return out;
}

}  // namespace rolamos
