// Colour of a store's patches and mosaic against the true seafloor of a synthetic survey (issue
// 15). Prints one JSON line per image: the low-pass colour error and a seam-visibility figure.
//
//   colour_bench SURVEY_DIR STORE
//
// The truth is the survey's texture (the procedural seafloor, or its image) seen through the
// image's placement (a best-fit homography from its frames' placements and their ground truth).
// Both are read at 1/4 resolution. One colour fit per image (per channel, gain and offset, as
// a uniform cast or brightness is forgiven), then:
//  - colour error: RMS over the image of the difference low-passed by a Gaussian of 64 px (full
//    resolution): what the eye sees as bands and blotches, in grey levels;
//  - seam visibility: RMS of the same difference band-passed between 8 and 32 px (a difference of
//    Gaussians): steps where frames or patches meet, in grey levels.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/store.hpp"
#include "rolamos/tiled_image.hpp"
#include "synth/seafloor_texture.h"
#include "util/homography.h"

namespace fs = std::filesystem;
using namespace rolamos;

namespace {

constexpr int kLevel = 2;  // 1/4 resolution

struct Truth {
  std::map<std::string, cv::Matx33d> frame_to_world;
  cv::Size frame;
  std::string texture;
  cv::Mat image;  // when the texture is an image
};

cv::Mat TextureWindow(const Truth& t, const cv::Rect& r) {
  if (t.texture == "procedural") return RenderSeafloor(r.x, r.y, r.width, r.height);
  cv::Mat out = cv::Mat::zeros(r.size(), CV_8UC3);
  const cv::Rect inside = r & cv::Rect(0, 0, t.image.cols, t.image.rows);
  if (!inside.empty()) t.image(inside).copyTo(out(inside - r.tl()));
  return out;
}

// The image's pixels (level 0) -> world, fitted over its frames' 5 x 5 grids.
cv::Matx33d ToWorld(const std::vector<std::pair<cv::Matx33d, cv::Matx33d>>& frames, cv::Size size) {
  std::vector<cv::Point2d> a, b;
  for (const auto& [to_image, to_world] : frames)
    for (int i = 0; i < 5; ++i)
      for (int j = 0; j < 5; ++j) {
        const cv::Point2d p(i * (size.width - 1) / 4.0, j * (size.height - 1) / 4.0);
        a.push_back(ApplyHomography(to_image, p));
        b.push_back(ApplyHomography(to_world, p));
      }
  return cv::Matx33d(cv::findHomography(a, b, 0));
}

nlohmann::json Measure(const std::string& name, const std::string& path, const cv::Matx33d& to_world, const Truth& t) {
  TiledImage image = TiledImage::Open(path, std::make_shared<TileCache>());
  const int level = std::min(kLevel, image.num_levels() - 1);
  const auto& L = image.info().levels[size_t(level)];
  cv::Mat ours = image.ReadRegion(level, cv::Rect(0, 0, int(L.width), int(L.height)));
  const double f = double(L.width) / image.width();
  // level pixel -> level-0 pixel -> world; the texture window it needs, seen from the level.
  const cv::Matx33d up(1 / f, 0, 0.5 / f - 0.5, 0, 1 / f, 0.5 / f - 0.5, 0, 0, 1);
  const cv::Matx33d M = to_world * up;
  const cv::Rect2d need = WarpedBounds(M, ours.size());
  const cv::Rect window(int(std::floor(need.x)) - 2, int(std::floor(need.y)) - 2, int(std::ceil(need.width)) + 5,
                        int(std::ceil(need.height)) + 5);
  const cv::Mat texture = TextureWindow(t, window);
  // dst(x) = texture(A x): A carries a level pixel to its texture window pixel.
  const cv::Matx33d A = cv::Matx33d(1, 0, -window.x, 0, 1, -window.y, 0, 0, 1) * M;
  cv::Mat truth;
  cv::warpPerspective(texture, truth, cv::Mat(A), ours.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT);
  cv::Mat mask;
  cv::extractChannel(ours, mask, 3);
  mask = mask > 127;
  cv::erode(mask, mask, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(33, 33)));
  const int n = cv::countNonZero(mask);
  if (n < 1000) return {{"image", name}, {"error", "too little of it"}};
  cv::Mat o3, t3;
  cv::cvtColor(ours, o3, cv::COLOR_BGRA2BGR);
  o3.convertTo(o3, CV_32F);
  truth.convertTo(t3, CV_32F);
  std::vector<cv::Mat> oc, tc;
  cv::split(o3, oc);
  cv::split(t3, tc);
  double colour2 = 0, seam2 = 0, raw2 = 0;
  for (int c = 0; c < 3; ++c) {
    // One colour fit: gain and offset by least squares over the image.
    cv::Mat x = oc[size_t(c)].reshape(1, 1), y = tc[size_t(c)].reshape(1, 1), m = mask.reshape(1, 1);
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (int i = 0; i < x.cols; ++i) {
      if (!m.at<uchar>(i)) continue;
      const double a = x.at<float>(i), b = y.at<float>(i);
      sx += a, sy += b, sxx += a * a, sxy += a * b;
    }
    const double gain = (n * sxy - sx * sy) / std::max(1e-9, n * sxx - sx * sx), offset = (sy - gain * sx) / n;
    cv::Mat e = oc[size_t(c)] * gain + offset - tc[size_t(c)];
    cv::Mat low, band1, band2;
    cv::GaussianBlur(e, low, cv::Size(), 64.0 * f);  // 64 px at level 0
    cv::GaussianBlur(e, band1, cv::Size(), 8.0 * f);
    cv::GaussianBlur(e, band2, cv::Size(), 32.0 * f);
    const cv::Mat band = band1 - band2;
    colour2 += std::pow(cv::norm(low, cv::NORM_L2, mask), 2) / n;
    seam2 += std::pow(cv::norm(band, cv::NORM_L2, mask), 2) / n;
    raw2 += std::pow(cv::norm(e, cv::NORM_L2, mask), 2) / n;
  }
  return {{"image", name}, {"colour_error", std::sqrt(colour2 / 3)}, {"seam_visibility", std::sqrt(seam2 / 3)},
          {"rms_after_fit", std::sqrt(raw2 / 3)}, {"pixels", n}};
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: colour_bench SURVEY_DIR STORE\n");
    return 2;
  }
  const std::string survey = argv[1];
  Store store = Store::Open(argv[2]);
  nlohmann::json gt;
  std::ifstream(survey + "/ground_truth.json") >> gt;
  Truth t;
  t.texture = gt["texture"];
  if (t.texture != "procedural") t.image = cv::imread(t.texture.substr(0, t.texture.find(',')));
  t.frame = cv::Size(gt["frame_size"][0], gt["frame_size"][1]);
  for (const auto& f : gt["frames"]) {
    cv::Matx33d W;
    for (int k = 0; k < 9; ++k) W.val[k] = f["frame_to_world"][k];
    t.frame_to_world[fs::path(f["file"].get<std::string>()).filename().string()] = W;
  }
  std::vector<std::pair<cv::Matx33d, cv::Matx33d>> mosaic_frames;
  for (const auto& p : store.patches()) {
    const PatchSidecar s = store.ReadSidecar(p.id);
    std::vector<std::pair<cv::Matx33d, cv::Matx33d>> frames;
    for (const auto& f : s.frames) {
      const cv::Matx33d W = t.frame_to_world.at(fs::path(f.source).filename().string());
      frames.emplace_back(ToMatx(f.frame_to_patch), W);
      if (s.patch_to_global)
        mosaic_frames.emplace_back(f.frame_to_global ? ToMatx(*f.frame_to_global)
                                                     : ToMatx(*s.patch_to_global) * ToMatx(f.frame_to_patch), W);
    }
    if (frames.size() < 3) continue;
    std::printf("%s\n", Measure("patch " + std::to_string(p.id), store.PatchImagePath(p.id), ToWorld(frames, t.frame), t).dump().c_str());
  }
  if (store.HasMosaic() && mosaic_frames.size() >= 3) {
    const GlobalRecord g = store.global();
    cv::Matx33d S = cv::Matx33d::eye();
    S(0, 0) = S(1, 1) = g.scale;
    S(0, 2) = S(1, 2) = 0.5 * g.scale - 0.5;
    for (auto& [to_global, W] : mosaic_frames) to_global = S * to_global;
    std::printf("%s\n", Measure("mosaic", store.MosaicPath(), ToWorld(mosaic_frames, t.frame), t).dump().c_str());
  }
  return 0;
}
