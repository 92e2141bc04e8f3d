#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "rolamos/error.hpp"
#include "rolamos/survey.hpp"
#include "synth/camera_path.h"
#include "synth/seafloor_texture.h"
#include "util/files.h"

namespace fs = std::filesystem;

namespace rolamos {

bool SurveyOptions::IsValid(std::string* error) const {
  auto bad = [&](const std::string& e) {
    *error = e;
    return false;
  };
  if (frame_width < 64 || frame_height < 64 || frame_width > 8192 || frame_height > 8192)
    return bad("frame size " + std::to_string(frame_width) + "x" + std::to_string(frame_height) +
               " is outside 64..8192");
  if (!(focal_px > 10)) return bad("focal length must be more than 10 pixels");
  if (fov_deg != 0 && !(fov_deg >= 10 && fov_deg <= 150))
    return bad("field of view " + std::to_string(fov_deg) + " degrees is outside 10..150");
  if (!(attitude_jitter_deg >= 0 && attitude_jitter_deg <= 10))
    return bad("attitude jitter " + std::to_string(attitude_jitter_deg) + " degrees is outside 0..10");
  if (!(gsd > 0.05 && gsd < 20)) return bad("gsd " + std::to_string(gsd) + " is outside 0.05..20");
  if (path != "lawnmower" && path != "spiral" && path != "random" && path != "inspect")
    return bad("path \"" + path + "\" is not lawnmower, spiral, random or inspect");
  if (frames < 2 || frames > 1000000) return bad("frame count must be 2..1000000");
  if (!(forward_overlap >= 0 && forward_overlap < 0.98)) return bad("forward overlap must be in [0, 0.98)");
  if (!(side_overlap >= 0 && side_overlap < 0.95)) return bad("side overlap must be in [0, 0.95)");
  if (lanes < 0 || (lanes > 0 && frames < 2 * lanes))
    return bad("lanes " + std::to_string(lanes) + " need at least two frames each");
  if (!(max_turn_deg > 0 && max_turn_deg <= 180))
    return bad("max turn " + std::to_string(max_turn_deg) + " degrees is outside (0, 180]");
  if (jpeg_quality < 0 || jpeg_quality > 100) return bad("JPEG quality must be 0 (PNG) or 1..100");
  if (!repeat.empty() && repeat != "rotate" && repeat != "mirror")
    return bad("repeat \"" + repeat + "\" is not rotate or mirror");
  if (!video.empty()) {
    const std::string ext = std::filesystem::path(video).extension().string();
    if (ext != ".mp4" && ext != ".avi") return bad("video \"" + video + "\" must end in .mp4 or .avi");
    if (!(video_fps >= 1 && video_fps <= 240)) return bad("video frame rate must be 1..240 frames a second");
    const bool mp4 = ext == ".mp4";
    if (!(video_codec.empty() || ((video_codec == "mpeg4" || video_codec == "h264") && mp4) ||
          (video_codec == "mjpeg" && !mp4)))
      return bad("video codec \"" + video_codec + "\" is not mpeg4 or h264 for .mp4, or mjpeg for .avi");
  }
  if (!(k1 >= -0.5 && k1 <= 0.5)) return bad("lens distortion k1 " + std::to_string(k1) + " is outside -0.5..0.5");
  if (!(descent_from >= 1 && descent_from <= 5))
    return bad("descent from " + std::to_string(descent_from) + " times the altitude is outside 1..5");
  if (descent_frames < 0 || descent_frames > frames)
    return bad("descent of " + std::to_string(descent_frames) + " frames is outside 0.." + std::to_string(frames));
  if (!(motion_blur >= 0 && motion_blur <= 1))
    return bad("motion blur " + std::to_string(motion_blur) + " is outside 0..1 (the shutter's share of the frame interval)");
  if (!(light_cone >= 0 && light_cone <= 1) || !(exposure_jitter >= 0 && exposure_jitter <= 0.5))
    return bad("light cone must be in [0, 1] and exposure jitter in [0, 0.5]");
  if (noise < 0 || particles < 0 || vignetting < 0 || vignetting > 1 || backscatter < 0 ||
      attenuation < 0 || altitude_jitter < 0 || altitude_jitter > 0.5 || tilt_deg < 0 || tilt_deg > 30)
    return bad("a degradation or motion setting is out of range");
  return true;
}

double SurveyOptions::Focal() const {
  return fov_deg > 0 ? 0.5 * frame_width / std::tan(0.5 * fov_deg * CV_PI / 180) : focal_px;
}

cv::Size2d SurveyOptions::PathExtent() const {
  if (path != "lawnmower" || lanes <= 0) return {0, 0};
  const double step = frame_height * gsd * (1.0 - forward_overlap);
  const double lane_gap = frame_width * gsd * (1.0 - side_overlap);
  const int per_lane = (frames + lanes - 1) / lanes;
  const double r = lanes > 1 && lane_turns ? lane_gap / 2 : 0;
  return {(per_lane - 1) * step + 2 * r, (lanes - 1) * lane_gap};
}

namespace {

// What a TV survey burns into its frames: a timestamp that changes with the frame and two laser
// dots fixed in the image (they do not move with the seafloor).
void BurnOverlay(cv::Mat& frame, int index) {
  char text[64];
  std::snprintf(text, sizeof text, "2026-11-23 10:%02d:%02d.%d  #%05d", (index / 600) % 60, (index / 10) % 60,
                index % 10, index);
  const double scale = frame.cols / 900.0;
  const cv::Point at(frame.cols / 40, frame.rows / 14);
  cv::putText(frame, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(0, 0, 0), std::max(3, int(5 * scale)), cv::LINE_AA);
  cv::putText(frame, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(255, 255, 255), std::max(1, int(2 * scale)), cv::LINE_AA);
  const int r = std::max(3, frame.cols / 160);
  for (const double fx : {0.42, 0.58}) {
    const cv::Point dot(static_cast<int>(fx * frame.cols), static_cast<int>(0.55 * frame.rows));
    cv::circle(frame, dot, 2 * r, cv::Scalar(60, 60, 255), cv::FILLED, cv::LINE_AA);
    cv::circle(frame, dot, r, cv::Scalar(220, 220, 255), cv::FILLED, cv::LINE_AA);
  }
}

// The ground the camera flies over: an image, several images one above the other, or the
// procedural seafloor.
class TextureSource {
 public:
  TextureSource(const SurveyOptions& o) : options_(o) {
    if (!o.texture.empty()) {
      // "a.jpg,b.jpg": bands of ground from each image in turn, top to bottom.
      std::stringstream list(o.texture);
      for (std::string path; std::getline(list, path, ',');) {
        if (path.empty()) continue;
        cv::Mat image = cv::imread(path, cv::IMREAD_COLOR);
        if (image.empty()) Fail(path, "cannot be read as an image");
        images_.push_back(image);
      }
      if (images_.empty()) Fail(o.texture, "names no image");
      size_ = images_[0].size();
      for (size_t i = 1; i < images_.size(); ++i) {
        size_.width = std::min(size_.width, images_[i].cols);
        size_.height += images_[i].rows;
      }
      // A path of fixed size (lawnmower with lanes) larger than that flies over the images
      // mirrored sideways and repeated downwards as often as needed. Mirrored only about
      // vertical lines: mirrored both ways, the ground would be symmetric about points and match
      // itself turned 180 degrees; and a mirrored view does not match the original in SIFT.
      const cv::Size2d extent = o.PathExtent();
      if (extent.width > 0) {
        const double margin = (2 * std::max(o.frame_width, o.frame_height) * o.gsd +
                               2 * o.Focal() * o.gsd * std::tan(3 * o.attitude_jitter_deg * CV_PI / 180)) *
                              o.descent_from;  // from higher up a frame sees more ground
        size_.width = std::max(size_.width, static_cast<int>(std::ceil(extent.width + margin)));
        size_.height = std::max(size_.height, static_cast<int>(std::ceil(extent.height + margin)));
      }
    } else {
      // The procedural seafloor is endless: give it room for the path.
      const double foot = std::max(o.frame_width, o.frame_height) * o.gsd * o.descent_from;
      const cv::Size2d extent = o.PathExtent();
      if (extent.width > 0) {  // the path fixes its size: the margin holds the tilted footprint
        const double margin =
            2 * foot + 2 * o.Focal() * o.gsd * o.descent_from * std::tan(3 * o.attitude_jitter_deg * CV_PI / 180);
        size_ = cv::Size(static_cast<int>(std::ceil(extent.width + margin)),
                         static_cast<int>(std::ceil(extent.height + margin)));
        return;
      }
      const int side = static_cast<int>(std::ceil(
          std::max(8.0 * foot, foot * std::sqrt(double(o.frames)) * (1.0 - o.forward_overlap) * 3.0)));
      size_ = cv::Size(side, side);
    }
  }
  cv::Size size() const { return size_; }
  // Pixels of the texture in `r` (may reach outside: black there), the repeated quarter included.
  cv::Mat Window(const cv::Rect& r) const {
    cv::Mat out = Original(r);
    if (options_.repeat.empty()) return out;
    // The bottom-right quarter shows the top-left one, turned 180 degrees or mirrored.
    const cv::Rect copy(size_.width / 2, size_.height / 2, size_.width / 2, size_.height / 2);
    const cv::Rect part = r & copy;
    if (part.empty()) return out;
    const bool rotate = options_.repeat == "rotate";
    // Destination (x, y) in the copy shows source (Q - 1 - (x - x0), Q - 1 - (y - y0)) (rotate) or
    // (Q - 1 - (x - x0), y - y0) (mirror) of the top-left quarter.
    const int qx = copy.width, qy = copy.height;
    const int sx0 = qx - 1 - (part.x + part.width - 1 - copy.x);
    const int sy0 = rotate ? qy - 1 - (part.y + part.height - 1 - copy.y) : part.y - copy.y;
    cv::Mat src = Original(cv::Rect(sx0, sy0, part.width, part.height));
    cv::flip(src, src, rotate ? -1 : 1);
    src.copyTo(out(part - r.tl()));
    return out;
  }

 private:
  cv::Mat Original(const cv::Rect& r) const {
    if (images_.empty()) return RenderSeafloor(r.x, r.y, r.width, r.height);
    cv::Mat out = cv::Mat::zeros(r.size(), CV_8UC3);
    const cv::Rect inside = r & cv::Rect(cv::Point(), size_);
    for (int y = inside.y; y < inside.y + inside.height; ++y) {
      const auto [image, row] = RowAt(y);
      const cv::Vec3b* src = image->ptr<cv::Vec3b>(row);
      cv::Vec3b* dst = out.ptr<cv::Vec3b>(y - r.y);
      const int n = image->cols;
      for (int x = inside.x; x < inside.x + inside.width; ++x) {
        const int m = x % (2 * n);
        dst[x - r.x] = src[m < n ? m : 2 * n - 1 - m];
      }
    }
    return out;
  }

  // The image and its row at texture row y: the images stacked, the stack repeated.
  std::pair<const cv::Mat*, int> RowAt(int y) const {
    int stack = 0;
    for (const auto& im : images_) stack += im.rows;
    y %= stack;
    for (const auto& im : images_) {
      if (y < im.rows) return {&im, y};
      y -= im.rows;
    }
    return {&images_.back(), images_.back().rows - 1};
  }

  SurveyOptions options_;
  std::vector<cv::Mat> images_;
  cv::Size size_;
};

cv::Mat Degrade(const cv::Mat& clean, const SurveyOptions& o, const CameraPose& pose,
                double nominal_altitude, int index) {
  std::mt19937 rng(o.seed * 1000003u + static_cast<uint32_t>(index));
  cv::Mat f;
  clean.convertTo(f, CV_32FC3, 1.0 / 255.0);
  const double a = pose.position[2] / nominal_altitude;
  // Water absorbs red first, then green (Beer-Lambert with a made-up path length).
  const cv::Scalar gain(std::exp(-0.05 * o.attenuation * a), std::exp(-0.18 * o.attenuation * a),
                        std::exp(-0.55 * o.attenuation * a));
  const cv::Scalar haze = cv::Scalar(0.38, 0.33, 0.08) * o.backscatter;
  const float cx = (f.cols - 1) / 2.0f, cy = (f.rows - 1) / 2.0f;
  const float rmax2 = cx * cx + cy * cy;
  // The vehicle's lights: a broad bright cone a little below and left of the centre (lights sit
  // beside the camera), fixed in the frame; and the camera's exposure, different every frame.
  const float lx = cx - 0.15f * f.cols, ly = cy + 0.12f * f.rows, lr2 = 0.18f * rmax2;
  std::normal_distribution<double> exposure(1.0, o.exposure_jitter);
  const float e = o.exposure_jitter > 0 ? static_cast<float>(std::clamp(exposure(rng), 0.5, 1.5)) : 1.0f;
  for (int y = 0; y < f.rows; ++y) {
    cv::Vec3f* p = f.ptr<cv::Vec3f>(y);
    for (int x = 0; x < f.cols; ++x) {
      const float r2 = ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / rmax2;
      const float d2 = ((x - lx) * (x - lx) + (y - ly) * (y - ly)) / lr2;
      const float light = 1.0f - static_cast<float>(o.light_cone) * (1.0f - 1.6f * std::exp(-0.5f * d2));
      const float v = (1.0f - static_cast<float>(o.vignetting) * r2) * light * e;
      for (int c = 0; c < 3; ++c)
        p[x][c] = p[x][c] * static_cast<float>(gain[c]) * v +
                  static_cast<float>(haze[c]) * (0.8f + 0.4f * r2);
    }
  }
  // Marine snow: small soft bright blobs, different in every frame.
  if (o.particles > 0) {
    cv::Mat snow = cv::Mat::zeros(f.size(), CV_32F);
    std::uniform_real_distribution<float> ux(0, static_cast<float>(f.cols)), uy(0, static_cast<float>(f.rows)),
        ur(0.8f, 3.5f), ui(0.3f, 0.9f);
    for (int i = 0; i < o.particles; ++i)
      cv::circle(snow, cv::Point2f(ux(rng), uy(rng)), static_cast<int>(ur(rng)), cv::Scalar(ui(rng)),
                 cv::FILLED, cv::LINE_AA);
    cv::GaussianBlur(snow, snow, cv::Size(0, 0), 1.0);
    cv::Mat snow3;
    cv::merge(std::vector<cv::Mat>{snow, snow, snow}, snow3);
    f += snow3;
  }
  if (o.noise > 0) {
    cv::Mat n(f.size(), CV_32FC3);
    cv::randn(n, 0, o.noise / 255.0);
    f += n;
  }
  cv::Mat out;
  f.convertTo(out, CV_8UC3, 255.0);
  return out;
}

nlohmann::json Mat33(const cv::Matx33d& m) {
  return nlohmann::json::array({m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2), m(2, 0),
                                m(2, 1), m(2, 2)});
}

// Where each pixel of the (distorted) frame looks through the pinhole camera K: its undistorted
// pixel. Empty without distortion.
std::vector<cv::Point2f> LensLookup(const SurveyOptions& o, const cv::Matx33d& K) {
  std::vector<cv::Point2f> raw, out;
  if (o.k1 == 0) return out;
  raw.reserve(size_t(o.frame_width) * size_t(o.frame_height));
  for (int y = 0; y < o.frame_height; ++y)
    for (int x = 0; x < o.frame_width; ++x) raw.emplace_back(float(x), float(y));
  cv::undistortPoints(raw, out, cv::Mat(K), cv::Mat(cv::Vec4d(o.k1, 0, 0, 0)), cv::noArray(), cv::Mat(K),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 40, 1e-6));
  return out;
}

// The clean frame the camera sees from `world_to_frame`: the texture warped to it, through the
// lens when it has distortion (`lens`, from LensLookup).
cv::Mat RenderFrame(const TextureSource& texture, const cv::Matx33d& world_to_frame, cv::Size size,
                    const std::vector<cv::Point2f>& lens) {
  const cv::Matx33d frame_to_world = world_to_frame.inv();
  std::vector<cv::Point2f> seen = {{0, 0}, {size.width - 1.f, 0}, {size.width - 1.f, size.height - 1.f},
                                   {0, size.height - 1.f}};
  if (!lens.empty()) seen = lens;  // every pixel's ray: barrel lenses see beyond the pinhole's corners
  std::vector<cv::Point2f> world;
  cv::perspectiveTransform(seen, world, cv::Mat(frame_to_world));
  cv::Rect box = cv::boundingRect(world);
  box.x -= 3;
  box.y -= 3;
  box.width += 6;
  box.height += 6;
  cv::Mat window = texture.Window(box);
  cv::Mat clean;
  if (lens.empty()) {
    const cv::Matx33d shift(1, 0, box.x, 0, 1, box.y, 0, 0, 1);  // window pixel -> world
    cv::warpPerspective(window, clean, cv::Mat(world_to_frame * shift), size, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    return clean;
  }
  cv::Mat map(size, CV_32FC2);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x)
      map.at<cv::Vec2f>(y, x) = cv::Vec2f(world[size_t(y) * size.width + x].x - box.x,
                                          world[size_t(y) * size.width + x].y - box.y);
  cv::remap(window, clean, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  return clean;
}

// The camera's motion at frame i per frame interval (position and yaw; the attitude's jitter is
// per frame, not a motion): towards the next frame, or from the previous one where the next is
// a jump (a lawnmower's lanes joined without turns start turned 180 degrees). Zero when neither
// neighbour is a continuation. `typical` is the path's median step.
CameraPose MotionAt(const std::vector<CameraPose>& poses, size_t i, double typical) {
  auto step = [&](size_t a, size_t b, CameraPose* out) {
    const double yaw = std::remainder(poses[b].yaw - poses[a].yaw, 2 * CV_PI);
    if (cv::norm(poses[b].position - poses[a].position) > 3 * typical + 1 || std::abs(yaw) > CV_PI / 4) return false;
    out->position = poses[b].position - poses[a].position;
    out->yaw = yaw;
    return true;
  };
  CameraPose v;  // still, unless a neighbour continues the motion (step sets v only then)
  v.position = cv::Vec3d(0, 0, 0);
  if (i + 1 < poses.size() && step(i, i + 1, &v)) return v;
  if (i > 0) step(i - 1, i, &v);
  return v;
}

// The frame as the shutter saw it while the camera moved: renders along the motion, averaged,
// one a pixel of smear (at most 32), centred on the frame's own pose.
cv::Mat RenderExposure(const TextureSource& texture, const std::vector<CameraPose>& poses, size_t i,
                       double typical_step, const cv::Matx33d& K, cv::Size size,
                       const std::vector<cv::Point2f>& lens, double blur) {
  const cv::Matx33d centre = WorldToFrame(poses[i], K);
  if (blur <= 0) return RenderFrame(texture, centre, size, lens);
  const CameraPose v = MotionAt(poses, i, typical_step);
  auto at = [&](double t) {
    CameraPose p = poses[i];
    p.position += t * v.position;
    p.yaw += t * v.yaw;
    return WorldToFrame(p, K);
  };
  // The smear's length: how far a corner of the frame moves while the shutter is open.
  const std::vector<cv::Point2f> corners = {{0, 0}, {size.width - 1.f, 0}, {size.width - 1.f, size.height - 1.f},
                                            {0, size.height - 1.f}};
  std::vector<cv::Point2f> world, a, b;
  cv::perspectiveTransform(corners, world, cv::Mat(centre.inv()));
  cv::perspectiveTransform(world, a, cv::Mat(at(-blur / 2)));
  cv::perspectiveTransform(world, b, cv::Mat(at(blur / 2)));
  double length = 0;
  for (size_t k = 0; k < corners.size(); ++k) length = std::max(length, double(cv::norm(a[k] - b[k])));
  const int n = std::clamp(static_cast<int>(std::ceil(length)) + 1, 1, 32);
  if (n == 1) return RenderFrame(texture, centre, size, lens);
  cv::Mat sum = cv::Mat::zeros(size, CV_32FC3);
  for (int k = 0; k < n; ++k) {
    const double t = blur * (double(k) / (n - 1) - 0.5);
    cv::accumulate(RenderFrame(texture, at(t), size, lens), sum);
  }
  cv::Mat out;
  sum.convertTo(out, CV_8UC3, 1.0 / n);
  return out;
}

}  // namespace

Survey WriteSurvey(const SurveyOptions& o, const std::string& dir,
                   const ProgressFn& progress) {
  std::string error;
  if (!o.IsValid(&error)) Fail("synth", error);
  TextureSource texture(o);
  const double altitude = o.Focal() * o.gsd;
  const cv::Matx33d K(o.Focal(), 0, (o.frame_width - 1) / 2.0, 0, o.Focal(),
                      (o.frame_height - 1) / 2.0, 0, 0, 1);
  // The camera centre keeps the whole (tilted, higher) footprint on the texture.
  const double jitter_tilt = 3 * o.attitude_jitter_deg * CV_PI / 180;  // room for the jitter's extremes
  // A barrel lens sees beyond the pinhole's corners: room for its reach too.
  const std::vector<cv::Point2f> lens = LensLookup(o, K);
  double reach = 1;
  for (const auto& p : lens)
    reach = std::max(reach, std::hypot(p.x - K(0, 2), p.y - K(1, 2)) / std::hypot(K(0, 2), K(1, 2)));
  const double half_diag = reach * 0.5 * std::hypot(o.frame_width, o.frame_height) * o.gsd *
                               (1.0 + o.altitude_jitter) * o.descent_from * 1.1 +
                           altitude * o.descent_from * std::tan(jitter_tilt);
  cv::Rect2d area(half_diag, half_diag, texture.size().width - 2 * half_diag,
                  texture.size().height - 2 * half_diag);
  if (area.width < 1 || area.height < 1)
    Fail(o.texture.empty() ? "procedural texture" : o.texture,
         "is too small for frames of " + std::to_string(o.frame_width) + "x" +
             std::to_string(o.frame_height) + " at gsd " + std::to_string(o.gsd) +
             " (lower the ground sample distance or use a larger texture)");
  const cv::Size2d extent = o.PathExtent();
  if (extent.width > area.width + 1 || extent.height > area.height + 1)
    Fail(o.texture, std::to_string(o.lanes) + " lanes of " + std::to_string((o.frames + o.lanes - 1) / o.lanes) +
                        " frames need " + std::to_string(int(extent.width)) + "x" + std::to_string(int(extent.height)) +
                        " texture pixels for the camera centre, the texture leaves " +
                        std::to_string(int(area.width)) + "x" + std::to_string(int(area.height)) +
                        " (lower the ground sample distance, or fewer frames)");
  auto poses = PlanCameraPath(o, area);
  std::vector<double> steps;
  for (size_t k = 0; k + 1 < poses.size(); ++k) steps.push_back(cv::norm(poses[k + 1].position - poses[k].position));
  std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
  const double typical_step = steps.empty() ? 0 : steps[steps.size() / 2];

  std::error_code ec;
  fs::create_directories(fs::path(dir) / "frames", ec);
  if (ec) Fail(dir, "cannot create survey directory: " + ec.message());
  Survey survey;
  survey.texture = o.texture.empty() ? "procedural" : o.texture;
  survey.texture_size = texture.size();
  survey.frame_size = cv::Size(o.frame_width, o.frame_height);
  survey.camera_matrix = K;
  nlohmann::json frames = nlohmann::json::array();
  const std::string ext = o.jpeg_quality > 0 ? ".jpg" : ".png";
  cv::VideoWriter video;
  if (!o.video.empty()) {
    const std::string path = (fs::path(dir) / o.video).string();
    const std::string codec =
        !o.video_codec.empty() ? o.video_codec : fs::path(o.video).extension() == ".avi" ? "mjpeg" : "mpeg4";
    const int fourcc = codec == "mjpeg"  ? cv::VideoWriter::fourcc('M', 'J', 'P', 'G')
                       : codec == "h264" ? cv::VideoWriter::fourcc('a', 'v', 'c', '1')
                                         : cv::VideoWriter::fourcc('m', 'p', '4', 'v');
    if (!video.open(path, cv::CAP_FFMPEG, fourcc, o.video_fps, survey.frame_size, true))
      Fail(path, "cannot be written (no video encoder for it in OpenCV's FFmpeg)");
  }
  for (size_t i = 0; i < poses.size(); ++i) {
    const cv::Matx33d world_to_frame = WorldToFrame(poses[i], K);
    const cv::Matx33d frame_to_world = world_to_frame.inv();
    const cv::Mat clean = RenderExposure(texture, poses, i, typical_step, K, survey.frame_size, lens, o.motion_blur);
    cv::Mat frame = Degrade(clean, o, poses[i], altitude, static_cast<int>(i));
    if (o.overlay) BurnOverlay(frame, static_cast<int>(i));
    char name[64];
    std::snprintf(name, sizeof name, "frames/frame_%05zu%s", i, ext.c_str());
    std::vector<int> params;
    if (o.jpeg_quality > 0) params = {cv::IMWRITE_JPEG_QUALITY, o.jpeg_quality};
    if (!cv::imwrite((fs::path(dir) / name).string(), frame, params))
      Fail((fs::path(dir) / name).string(), "cannot be written");
    if (video.isOpened()) video.write(frame);
    SurveyFrame sf;
    sf.index = static_cast<int>(i);
    sf.file = name;
    for (int k = 0; k < 9; ++k) sf.frame_to_world[k] = frame_to_world.val[k];
    sf.camera_position = {poses[i].position[0], poses[i].position[1], poses[i].position[2]};
    sf.yaw_deg = poses[i].yaw * 180 / CV_PI;
    survey.frames.push_back(sf);
    frames.push_back({{"index", sf.index},
                      {"file", sf.file},
                      {"frame_to_world", Mat33(frame_to_world)},
                      {"camera_position", sf.camera_position},
                      {"yaw_deg", sf.yaw_deg}});
    if (progress) progress(double(i + 1) / poses.size());
  }
  nlohmann::json j{{"texture", survey.texture},
                   {"texture_size", {survey.texture_size.width, survey.texture_size.height}},
                   {"frame_size", {o.frame_width, o.frame_height}},
                   {"camera_matrix", Mat33(K)},
                   {"options",
                    {{"path", o.path}, {"gsd", o.gsd}, {"frames", o.frames}, {"seed", o.seed},
                     {"forward_overlap", o.forward_overlap}, {"side_overlap", o.side_overlap},
                     {"tilt_deg", o.tilt_deg}, {"altitude_jitter", o.altitude_jitter},
                     {"attitude_jitter_deg", o.attitude_jitter_deg}, {"lane_turns", o.lane_turns},
                     {"lanes", o.lanes}, {"max_turn_deg", o.max_turn_deg}, {"overlay", o.overlay},
                     {"repeat", o.repeat},
                     {"focal_px", o.Focal()}, {"k1", o.k1}, {"motion_blur", o.motion_blur},
                     {"descent_from", o.descent_from}, {"descent_frames", o.descent_frames}}},
                   {"frames", frames}};
  WriteFileAtomic((fs::path(dir) / "ground_truth.json").string(), j.dump(1) + "\n");
  return survey;
}

Survey ReadSurvey(const std::string& dir) {
  const std::string path = (fs::path(dir) / "ground_truth.json").string();
  nlohmann::json j = nlohmann::json::parse(ReadSmallFile(path), nullptr, false);
  if (j.is_discarded() || !j.is_object()) Fail(path, "is not valid JSON");
  try {
    Survey s;
    s.texture = j.at("texture").get<std::string>();
    s.texture_size = cv::Size(j.at("texture_size")[0], j.at("texture_size")[1]);
    s.frame_size = cv::Size(j.at("frame_size")[0], j.at("frame_size")[1]);
    for (int k = 0; k < 9; ++k) s.camera_matrix.val[k] = j.at("camera_matrix")[k];
    for (const auto& f : j.at("frames")) {
      SurveyFrame sf;
      sf.index = f.at("index");
      sf.file = f.at("file");
      for (int k = 0; k < 9; ++k) sf.frame_to_world[k] = f.at("frame_to_world")[k];
      for (int k = 0; k < 3; ++k) sf.camera_position[k] = f.at("camera_position")[k];
      sf.yaw_deg = f.at("yaw_deg");
      s.frames.push_back(sf);
    }
    return s;
  } catch (const nlohmann::json::exception& e) {
    Fail(path, std::string("malformed ground truth: ") + e.what());
  }
}

}  // namespace rolamos
