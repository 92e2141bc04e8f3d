// Boxed frames (YOLO label files) and their survey stations.
#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include <OpenImageIO/imageio.h>

#include "input/frame_source.h"
#include "rolamos/box_detector.hpp"
#include "rolamos/error.hpp"

namespace rolamos {

namespace fs = std::filesystem;

namespace {

// Seconds since the epoch of a "D2023-06-03T16-26-07" in the name; -1 when there is none.
long long CaptureTime(const std::string& name) {
  static const std::regex pattern(R"((\d{4})-(\d{2})-(\d{2})T(\d{2})[-:](\d{2})[-:](\d{2}))");
  std::smatch m;
  if (!std::regex_search(name, m, pattern)) return -1;
  std::tm t{};
  t.tm_year = std::stoi(m[1]) - 1900;
  t.tm_mon = std::stoi(m[2]) - 1;
  t.tm_mday = std::stoi(m[3]);
  t.tm_hour = std::stoi(m[4]);
  t.tm_min = std::stoi(m[5]);
  t.tm_sec = std::stoi(m[6]);
  return static_cast<long long>(timegm(&t));
}

cv::Size HeaderSize(const std::string& path) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) Fail(path, "cannot be opened as an image (" + OIIO::geterror() + ")");
  const OIIO::ImageSpec& spec = in->spec();
  return {spec.width, spec.height};
}

std::vector<cv::Rect2d> ReadYoloLabels(const std::string& path, cv::Size image) {
  std::vector<cv::Rect2d> boxes;
  std::ifstream in(path);
  if (!in) Fail(path, "cannot be read");
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::istringstream s(line);
    double cls, cx, cy, w, h;
    if (!(s >> cls >> cx >> cy >> w >> h))
      Fail(path + ":" + std::to_string(number), "is not \"class cx cy w h\" (YOLO, normalised): \"" + line + "\"");
    if (!(cx >= 0 && cx <= 1 && cy >= 0 && cy <= 1 && w > 0 && w <= 1 && h > 0 && h <= 1))
      Fail(path + ":" + std::to_string(number), "has a box outside the image (values must be in 0..1): \"" + line + "\"");
    boxes.emplace_back((cx - w / 2) * image.width, (cy - h / 2) * image.height, w * image.width, h * image.height);
  }
  return boxes;
}

}  // namespace

std::vector<BoxedImage> ReadBoxedFolder(const std::string& dir) {
  const fs::path images = fs::path(dir) / "images", labels = fs::path(dir) / "labels_gt";
  std::error_code ec;
  if (!fs::is_directory(images, ec)) Fail(dir, "holds no images/ folder (expected DIR/images and DIR/labels_gt)");
  if (!fs::is_directory(labels, ec)) Fail(dir, "holds no labels_gt/ folder of YOLO label files");
  std::vector<std::string> files;
  for (const auto& entry : fs::directory_iterator(images))
    if (entry.is_regular_file() && IsImageName(entry.path().string())) files.push_back(entry.path().string());
  std::sort(files.begin(), files.end());
  if (files.empty()) Fail(images.string(), "holds no images (.jpg, .png, .tif, ...)");
  std::vector<BoxedImage> out;
  for (const auto& f : files) {
    BoxedImage b;
    b.path = f;
    b.time = CaptureTime(fs::path(f).filename().string());
    const fs::path label = labels / (fs::path(f).stem().string() + ".txt");
    if (fs::exists(label)) {
      // The label's numbers are fractions of the image's size, read from its header only.
      b.boxes = ReadYoloLabels(label.string(), HeaderSize(f));
    }
    out.push_back(std::move(b));
  }
  GroupStations(&out);
  return out;
}

void GroupStations(std::vector<BoxedImage>* images, double gap_seconds) {
  std::vector<size_t> order(images->size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return (*images)[a].time < (*images)[b].time; });
  std::string current;
  long long last = -1;
  for (size_t i : order) {
    BoxedImage& b = (*images)[i];
    if (b.time < 0) {
      b.station = fs::path(b.path).stem().string();
      continue;
    }
    if (current.empty() || double(b.time - last) > gap_seconds) {
      const std::time_t t = static_cast<std::time_t>(b.time);
      char text[32];
      std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%S", std::gmtime(&t));
      current = text;
    }
    b.station = current;
    last = b.time;
  }
}

std::vector<int> StationFolds(const std::vector<BoxedImage>& images, int folds) {
  std::map<std::string, int> count;
  for (const auto& b : images) ++count[b.station];
  std::vector<std::pair<int, std::string>> stations;
  for (const auto& [s, n] : count) stations.emplace_back(n, s);
  std::sort(stations.begin(), stations.end(), [](const auto& a, const auto& b) { return a.first != b.first ? a.first > b.first : a.second < b.second; });
  const int k = std::max(1, std::min<int>(folds, static_cast<int>(stations.size())));
  std::vector<int> load(static_cast<size_t>(k), 0);
  std::map<std::string, int> fold_of;
  for (const auto& [n, s] : stations) {
    const int f = static_cast<int>(std::min_element(load.begin(), load.end()) - load.begin());
    fold_of[s] = f;
    load[static_cast<size_t>(f)] += n;
  }
  std::vector<int> out;
  for (const auto& b : images) out.push_back(fold_of[b.station]);
  return out;
}

}  // namespace rolamos
