#include <algorithm>
#include <filesystem>

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

}  // namespace rolamos
