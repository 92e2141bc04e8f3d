#include "compose/patch_blender.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "util/homography.h"

namespace rolamos {

namespace {

// How much coarser than the region the feather's distances are computed: the ramp is smooth,
// and the distance transform was a third of compose's time at full resolution.
int FeatherStep(int width) { return std::clamp(width / 8, 1, 4); }

// Weights that fall to zero at a patch's no-data border over `width` pixels (in the region read,
// whose origin is a multiple of FeatherStep so every block sees the same coarse grid).
cv::Mat FeatherFromAlpha(const cv::Mat& alpha, int width) {
  const cv::Mat inside = alpha > 127;
  const int f = FeatherStep(width);
  cv::Mat dist;
  if (f == 1) {
    cv::distanceTransform(inside, dist, cv::DIST_L2, 3);
  } else {
    // A coarse cell is inside only when all of it is; its distance, scaled back, is a slight
    // underestimate, so the ramp never reaches past the data.
    cv::Mat small, coarse;
    cv::resize(inside, small, cv::Size((alpha.cols + f - 1) / f, (alpha.rows + f - 1) / f), 0, 0, cv::INTER_AREA);
    cv::distanceTransform(small >= 255, coarse, cv::DIST_L2, 3);
    coarse *= static_cast<float>(f);
    cv::resize(coarse, dist, cv::Size(small.cols * f, small.rows * f), 0, 0, cv::INTER_LINEAR);
    dist = dist(cv::Rect(0, 0, alpha.cols, alpha.rows)).clone();
    dist.setTo(0, ~inside);
  }
  return cv::min(dist / static_cast<float>(width), 1.0f);
}

// Mosaic region pixel -> read-region pixel through the frames' own placements, blended: maps for
// cv::remap over `roi` (region pixels), computed on a coarse grid (the blend is smooth) and
// interpolated.
void LocalMaps(const PlacedPatch& p, const cv::Rect& rect, const cv::Rect& roi, const cv::Matx33d& R,
               cv::Mat* map_x, cv::Mat* map_y) {
  constexpr int kStep = 8;
  const int gw = roi.width / kStep + 2, gh = roi.height / kStep + 2;
  cv::Mat gx(gh, gw, CV_32F), gy(gh, gw, CV_32F);
  // The frames that matter here, and their mosaic -> read-region maps.
  const cv::Point2d mid(rect.x + roi.x + roi.width / 2.0, rect.y + roi.y + roi.height / 2.0);
  const double reach = 3 * p.local_sigma + std::hypot(roi.width, roi.height);
  std::vector<std::pair<cv::Matx33d, cv::Point2d>> near;
  for (const auto& l : p.local)
    if (cv::norm(l.centre - mid) < reach) near.emplace_back((l.to_mosaic * R).inv(), l.centre);
  if (near.empty())
    for (const auto& l : p.local) near.emplace_back((l.to_mosaic * R).inv(), l.centre);
  const double k = -0.5 / (p.local_sigma * p.local_sigma);
  for (int j = 0; j < gh; ++j) {
    for (int i = 0; i < gw; ++i) {
      const cv::Point2d m(rect.x + roi.x + i * kStep, rect.y + roi.y + j * kStep);
      double sx = 0, sy = 0, sw = 0, dmin = 1e300;
      for (const auto& [inv, c] : near) dmin = std::min(dmin, (m - c).dot(m - c));
      for (const auto& [inv, c] : near) {
        const double w = std::exp(k * ((m - c).dot(m - c) - dmin));  // relative to the nearest: no underflow
        const cv::Point2d q = ApplyHomography(inv, m);
        sx += w * q.x;
        sy += w * q.y;
        sw += w;
      }
      gx.at<float>(j, i) = static_cast<float>(sx / sw);
      gy.at<float>(j, i) = static_cast<float>(sy / sw);
    }
  }
  // Grid node (i, j) sits at roi pixel (i, j) * kStep: bilinear between nodes.
  map_x->create(roi.height, roi.width, CV_32F);
  map_y->create(roi.height, roi.width, CV_32F);
  for (int v = 0; v < roi.height; ++v) {
    const int j = v / kStep;
    const float b = float(v - j * kStep) / kStep;
    float* mx = map_x->ptr<float>(v);
    float* my = map_y->ptr<float>(v);
    for (int u = 0; u < roi.width; ++u) {
      const int i = u / kStep;
      const float a = float(u - i * kStep) / kStep;
      auto lerp = [&](const cv::Mat& g) {
        return (1 - b) * ((1 - a) * g.at<float>(j, i) + a * g.at<float>(j, i + 1)) +
               b * ((1 - a) * g.at<float>(j + 1, i) + a * g.at<float>(j + 1, i + 1));
      };
      mx[u] = lerp(gx);
      my[u] = lerp(gy);
    }
  }
}

}  // namespace

PatchBlender::PatchBlender(std::vector<PlacedPatch> patches, double scale, int feather_px)
    : patches_(std::move(patches)), scale_(scale), feather_px_(feather_px) {}

bool PatchBlender::OnlyOne(size_t k, const cv::Rect2d& area) const {
  for (size_t j = 0; j < patches_.size(); ++j)
    if (j != k && (patches_[j].bounds & area).area() > 0) return false;
  return true;
}

namespace {

// A view of `rows` x `cols` into a per-thread buffer that only grows: fresh 16 MB blocks for every
// render cost a fifth of compose's time in page faults.
cv::Mat Scratch(cv::Mat& buffer, int rows, int cols, int type) {
  if (buffer.type() != type || buffer.rows < rows || buffer.cols < cols)
    buffer.create(std::max(rows, buffer.rows), std::max(cols, buffer.cols), type);
  return buffer(cv::Rect(0, 0, cols, rows));
}

}  // namespace

cv::Mat PatchBlender::Render(const cv::Rect& rect) const {
  // Sums of weight x colour (channels 0-2) and of weight (3), per thread, reused.
  thread_local cv::Mat acc_buffer, weighted_buffer, warped_buffer;
  const cv::Rect2d area(rect);
  cv::Mat acc;
  for (size_t k = 0; k < patches_.size(); ++k) {
    const PlacedPatch& p = patches_[k];
    const cv::Rect2d cover = p.bounds & area;
    if (cover.area() <= 0) continue;
    const TiledImage& image = *p.image;
    // The region's footprint in the patch, with room for the feather.
    const cv::Matx33d to_region = cv::Matx33d(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1) * p.to_mosaic;
    const cv::Rect2d need = WarpedBounds(to_region.inv(), rect.size());
    const int level = image.LevelForScale(std::min(1.0, scale_ * 1.0001));
    const auto& L = image.info().levels[static_cast<size_t>(level)];
    const double fx = double(L.width) / image.width(), fy = double(L.height) / image.height();
    const int feather = std::max(1, static_cast<int>(feather_px_ * fx));
    const double margin = feather + 2;
    const int step = FeatherStep(feather);
    const int rx0 = std::max(0, static_cast<int>(std::floor(need.x * fx - margin)) / step * step);
    const int ry0 = std::max(0, static_cast<int>(std::floor(need.y * fy - margin)) / step * step);
    const int rx1 = std::min<int>(static_cast<int>(L.width), static_cast<int>(std::ceil((need.x + need.width) * fx + margin)));
    const int ry1 = std::min<int>(static_cast<int>(L.height), static_cast<int>(std::ceil((need.y + need.height) * fy + margin)));
    if (rx1 <= rx0 || ry1 <= ry0) continue;
    // Only the part of the region the patch covers is warped.
    const cv::Rect roi = cv::Rect(static_cast<int>(std::floor(cover.x)) - rect.x - 1,
                                  static_cast<int>(std::floor(cover.y)) - rect.y - 1,
                                  static_cast<int>(std::ceil(cover.width)) + 3,
                                  static_cast<int>(std::ceil(cover.height)) + 3) &
                         cv::Rect(0, 0, rect.width, rect.height);
    if (roi.empty()) continue;
    cv::Mat px = image.ReadRegion(level, cv::Rect(rx0, ry0, rx1 - rx0, ry1 - ry0));
    if (px.channels() != 4) cv::cvtColor(px, px, px.channels() == 3 ? cv::COLOR_BGR2BGRA : cv::COLOR_GRAY2BGRA);
    cv::Mat alpha;
    cv::extractChannel(px, alpha, 3);
    // read-region pixel -> patch level-0 pixel -> region pixel -> roi pixel
    const cv::Matx33d R(1 / fx, 0, (rx0 + 0.5) / fx - 0.5, 0, 1 / fy, (ry0 + 0.5) / fy - 0.5, 0, 0, 1);
    const bool interior = rx0 > 0 && ry0 > 0 && rx1 < L.width && ry1 < L.height;
    cv::Mat map_x, map_y;
    if (!p.local.empty()) LocalMaps(p, rect, roi, R, &map_x, &map_y);
    if (acc.empty() && interior && OnlyOne(k, area) && cv::countNonZero(alpha != 255) == 0) {
      // A region well inside a single patch, where every weight is 1 (the common case on a large
      // survey): the 8-bit warp is the blend, and 4x faster than the sums.
      cv::Mat out;
      const cv::Scalar gain(p.gain, p.gain, p.gain, 1.0);
      if (p.local.empty()) {
        cv::warpPerspective(px, out, cv::Mat(to_region * R), rect.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
        if (p.gain != 1.0) cv::multiply(out, gain, out);
        return out;
      }
      if (roi == cv::Rect(0, 0, rect.width, rect.height)) {
        cv::remap(px, out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
        if (p.gain != 1.0) cv::multiply(out, gain, out);
        return out;
      }
    }
    const cv::Mat weight = FeatherFromAlpha(alpha, feather);
    // Weighted colour (times the patch's exposure gain) and the weight, warped together.
    cv::Mat weighted = Scratch(weighted_buffer, px.rows, px.cols, CV_32FC4);
    const float g = static_cast<float>(p.gain);
    for (int r = 0; r < px.rows; ++r) {
      const cv::Vec4b* s4 = px.ptr<cv::Vec4b>(r);
      const float* w = weight.ptr<float>(r);
      cv::Vec4f* c = weighted.ptr<cv::Vec4f>(r);
      for (int x = 0; x < px.cols; ++x) {
        const float gw = g * w[x];
        c[x] = cv::Vec4f(s4[x][0] * gw, s4[x][1] * gw, s4[x][2] * gw, w[x]);
      }
    }
    const cv::Matx33d T(1, 0, -roi.x, 0, 1, -roi.y, 0, 0, 1);
    cv::Mat warped = Scratch(warped_buffer, roi.height, roi.width, CV_32FC4);
    if (p.local.empty())
      cv::warpPerspective(weighted, warped, cv::Mat(T * to_region * R), roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    else
      cv::remap(weighted, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    if (acc.empty()) {
      acc = Scratch(acc_buffer, rect.height, rect.width, CV_32FC4);
      acc.setTo(cv::Scalar::all(0));
    }
    acc(roi) += warped;
  }
  if (acc.empty()) return {};
  cv::Mat out(rect.size(), CV_8UC4, cv::Scalar::all(0));
  for (int r = 0; r < out.rows; ++r) {
    const cv::Vec4f* a = acc.ptr<cv::Vec4f>(r);
    cv::Vec4b* o = out.ptr<cv::Vec4b>(r);
    for (int c = 0; c < out.cols; ++c) {
      if (a[c][3] <= 1e-4f) continue;
      const float k = 1.0f / a[c][3];
      o[c] = cv::Vec4b(cv::saturate_cast<uchar>(a[c][0] * k), cv::saturate_cast<uchar>(a[c][1] * k),
                       cv::saturate_cast<uchar>(a[c][2] * k), 255);
    }
  }
  return out;
}

}  // namespace rolamos
