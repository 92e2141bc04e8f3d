#include "store/frame_data.h"

#include <cmath>
#include <cstring>

#include <nlohmann/json.hpp>

#include "rolamos/error.hpp"
#include "util/files.h"

namespace rolamos {

namespace {

constexpr const char* kLinksFormat = "rolamos-frame-links";
constexpr char kFeaturesMagic[8] = {'R', 'L', 'M', 'F', 'E', 'A', 'T', '1'};
constexpr int kDescriptorBytes = 128;

double Round2(double v) { return std::round(v * 100.0) / 100.0; }

template <typename T>
void Put(std::string& out, T v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}

template <typename T>
T Take(const std::string& in, size_t* at, const std::string& path) {
  if (*at + sizeof(T) > in.size()) Fail(path, "is truncated at byte " + std::to_string(*at));
  T v;
  std::memcpy(&v, in.data() + *at, sizeof v);
  *at += sizeof v;
  return v;
}

}  // namespace

void WriteFrameLinks(const std::string& path, const std::vector<StoredLink>& links) {
  nlohmann::json out = {{"format", kLinksFormat}, {"version", 1}, {"links", nlohmann::json::array()}};
  for (const auto& l : links) {
    nlohmann::json pairs = nlohmann::json::array();
    for (size_t i = 0; i < l.in_a.size(); ++i) {
      pairs.push_back(Round2(l.in_a[i].x));
      pairs.push_back(Round2(l.in_a[i].y));
      pairs.push_back(Round2(l.in_b[i].x));
      pairs.push_back(Round2(l.in_b[i].y));
    }
    out["links"].push_back({{"a", {l.a.patch, l.a.index}}, {"b", {l.b.patch, l.b.index}}, {"pairs", pairs}});
  }
  WriteFileAtomic(path, out.dump() + "\n");
}

std::vector<StoredLink> ReadFrameLinks(const std::string& path) {
  const nlohmann::json j = nlohmann::json::parse(ReadSmallFile(path, 1u << 30), nullptr, false);
  if (j.is_discarded() || !j.is_object()) Fail(path, "is not valid JSON");
  if (j.value("format", "") != kLinksFormat) Fail(path, "is not a frame links file (format \"" + std::string(kLinksFormat) + "\")");
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() != 1)
    Fail(path, "has a links format version this rolamos does not read (it reads 1)");
  std::vector<StoredLink> links;
  try {
    for (const auto& l : j.at("links")) {
      StoredLink s;
      s.a = {l.at("a").at(0).get<int>(), l.at("a").at(1).get<int>()};
      s.b = {l.at("b").at(0).get<int>(), l.at("b").at(1).get<int>()};
      const auto& p = l.at("pairs");
      if (p.size() % 4 != 0) Fail(path, "a link's pairs are not groups of four numbers");
      for (size_t i = 0; i + 3 < p.size(); i += 4) {
        s.in_a.emplace_back(p[i].get<float>(), p[i + 1].get<float>());
        s.in_b.emplace_back(p[i + 2].get<float>(), p[i + 3].get<float>());
      }
      links.push_back(std::move(s));
    }
  } catch (const nlohmann::json::exception& e) {
    Fail(path, std::string("malformed link: ") + e.what());
  }
  return links;
}

void WriteFrameFeatures(const std::string& path, const std::vector<StoredFeatures>& frames) {
  std::string out(kFeaturesMagic, sizeof kFeaturesMagic);
  Put<uint32_t>(out, static_cast<uint32_t>(frames.size()));
  for (const auto& f : frames) {
    CV_Assert(f.descriptors.type() == CV_8U && f.descriptors.rows == static_cast<int>(f.points.size()) &&
              (f.points.empty() || f.descriptors.cols == kDescriptorBytes));
    Put<int32_t>(out, f.index);
    Put<uint32_t>(out, static_cast<uint32_t>(f.points.size()));
    for (const auto& p : f.points) {
      Put<float>(out, p.x);
      Put<float>(out, p.y);
    }
    for (int r = 0; r < f.descriptors.rows; ++r)
      out.append(reinterpret_cast<const char*>(f.descriptors.ptr<uchar>(r)), kDescriptorBytes);
  }
  WriteFileAtomic(path, out);
}

std::vector<StoredFeatures> ReadFrameFeatures(const std::string& path) {
  const std::string in = ReadSmallFile(path, 1u << 30);
  if (in.size() < sizeof kFeaturesMagic || std::memcmp(in.data(), kFeaturesMagic, sizeof kFeaturesMagic) != 0)
    Fail(path, "is not a frame features file (or of a version this rolamos does not read)");
  size_t at = sizeof kFeaturesMagic;
  const uint32_t count = Take<uint32_t>(in, &at, path);
  std::vector<StoredFeatures> frames;
  for (uint32_t k = 0; k < count; ++k) {
    StoredFeatures f;
    f.index = Take<int32_t>(in, &at, path);
    const uint32_t n = Take<uint32_t>(in, &at, path);
    if (n > 1000000 || at + size_t(n) * (8 + kDescriptorBytes) > in.size())
      Fail(path, "frame " + std::to_string(f.index) + " claims " + std::to_string(n) + " features past the end");
    for (uint32_t i = 0; i < n; ++i) {
      const float x = Take<float>(in, &at, path), y = Take<float>(in, &at, path);
      f.points.emplace_back(x, y);
    }
    f.descriptors = cv::Mat(static_cast<int>(n), kDescriptorBytes, CV_8U);
    if (n) std::memcpy(f.descriptors.data, in.data() + at, size_t(n) * kDescriptorBytes);
    at += size_t(n) * kDescriptorBytes;
    frames.push_back(std::move(f));
  }
  return frames;
}

}  // namespace rolamos
