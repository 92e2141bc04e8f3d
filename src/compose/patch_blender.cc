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

// How near each pixel of mosaic region `rect` is to the patch's nearest frame centre (its bounds'
// centre when its frames were not placed one by one), in (0, 1): on a grid of 8 mosaic pixels
// anchored to the mosaic, so that every block computes the same values.
cv::Mat Closeness(const PlacedPatch* p, const cv::Rect& rect) {
  constexpr int kCell = 8;
  std::vector<cv::Point2d> centres;
  for (const auto& l : p->local) centres.push_back(l.centre);
  if (centres.empty()) centres.emplace_back(p->bounds.x + p->bounds.width / 2, p->bounds.y + p->bounds.height / 2);
  const int x0 = static_cast<int>(std::floor(double(rect.x) / kCell)), y0 = static_cast<int>(std::floor(double(rect.y) / kCell));
  const int x1 = static_cast<int>(std::floor(double(rect.x + rect.width - 1) / kCell));
  const int y1 = static_cast<int>(std::floor(double(rect.y + rect.height - 1) / kCell));
  cv::Mat coarse(y1 - y0 + 1, x1 - x0 + 1, CV_32F);
  for (int j = 0; j < coarse.rows; ++j)
    for (int i = 0; i < coarse.cols; ++i) {
      const cv::Point2d m((x0 + i + 0.5) * kCell, (y0 + j + 0.5) * kCell);
      double d2 = 1e300;
      for (const auto& c : centres) d2 = std::min(d2, (m - c).dot(m - c));
      coarse.at<float>(j, i) = static_cast<float>(1.0 / (1.0 + std::sqrt(d2) / 1000.0));
    }
  cv::Mat fine;
  cv::resize(coarse, fine, cv::Size(coarse.cols * kCell, coarse.rows * kCell), 0, 0, cv::INTER_NEAREST);
  return fine(cv::Rect(rect.x - x0 * kCell, rect.y - y0 * kCell, rect.width, rect.height)).clone();
}

}  // namespace

PatchBlender::PatchBlender(std::vector<PlacedPatch> patches, double scale, int feather_px, int bands)
    : patches_(std::move(patches)), scale_(scale), feather_px_(feather_px), bands_(bands) {}

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
  if (bands_ > 0) {
    const int margin = 1 << (bands_ + 3);
    const cv::Rect2d grown(rect.x - margin, rect.y - margin, rect.width + 2.0 * margin, rect.height + 2.0 * margin);
    int reach = 0;
    for (const auto& p : patches_) reach += (p.bounds & grown).area() > 0;
    if (reach >= 2) return RenderMultiband(rect);
  }
  return RenderFeather(rect);
}

// Patch k read and mapped for one region: its pixels at the level the scale needs (with room
// for the feather), and how they map onto the region.
struct PatchBlender::Source {
  cv::Mat px;           // BGRA at `level`
  cv::Mat alpha;
  cv::Matx33d warp;     // read-region pixel -> region pixel (single placement)
  cv::Mat map_x, map_y; // region roi pixel -> read-region pixel (per-frame placements)
  cv::Rect roi;         // the part of the region the patch covers
  int feather = 1;
  bool interior = false;
};

bool PatchBlender::Read(size_t k, const cv::Rect& rect, Source* src) const {
  const PlacedPatch& p = patches_[k];
  const cv::Rect2d cover = p.bounds & cv::Rect2d(rect);
  if (cover.area() <= 0) return false;
  const TiledImage& image = *p.image;
  // The region's footprint in the patch, with room for the feather.
  const cv::Matx33d to_region = cv::Matx33d(1, 0, -rect.x, 0, 1, -rect.y, 0, 0, 1) * p.to_mosaic;
  const cv::Rect2d need = WarpedBounds(to_region.inv(), rect.size());
  const int level = image.LevelForScale(std::min(1.0, scale_ * 1.0001));
  const auto& L = image.info().levels[static_cast<size_t>(level)];
  const double fx = double(L.width) / image.width(), fy = double(L.height) / image.height();
  src->feather = std::max(1, static_cast<int>(feather_px_ * fx));
  const double margin = src->feather + 2;
  const int step = FeatherStep(src->feather);
  const int rx0 = std::max(0, static_cast<int>(std::floor(need.x * fx - margin)) / step * step);
  const int ry0 = std::max(0, static_cast<int>(std::floor(need.y * fy - margin)) / step * step);
  const int rx1 = std::min<int>(static_cast<int>(L.width), static_cast<int>(std::ceil((need.x + need.width) * fx + margin)));
  const int ry1 = std::min<int>(static_cast<int>(L.height), static_cast<int>(std::ceil((need.y + need.height) * fy + margin)));
  if (rx1 <= rx0 || ry1 <= ry0) return false;
  // Only the part of the region the patch covers is warped.
  src->roi = cv::Rect(static_cast<int>(std::floor(cover.x)) - rect.x - 1, static_cast<int>(std::floor(cover.y)) - rect.y - 1,
                      static_cast<int>(std::ceil(cover.width)) + 3, static_cast<int>(std::ceil(cover.height)) + 3) &
             cv::Rect(0, 0, rect.width, rect.height);
  if (src->roi.empty()) return false;
  src->px = image.ReadRegion(level, cv::Rect(rx0, ry0, rx1 - rx0, ry1 - ry0));
  if (src->px.channels() != 4)
    cv::cvtColor(src->px, src->px, src->px.channels() == 3 ? cv::COLOR_BGR2BGRA : cv::COLOR_GRAY2BGRA);
  cv::extractChannel(src->px, src->alpha, 3);
  // read-region pixel -> patch level-0 pixel -> region pixel
  const cv::Matx33d R(1 / fx, 0, (rx0 + 0.5) / fx - 0.5, 0, 1 / fy, (ry0 + 0.5) / fy - 0.5, 0, 0, 1);
  src->warp = to_region * R;
  src->interior = rx0 > 0 && ry0 > 0 && rx1 < L.width && ry1 < L.height;
  if (!p.local.empty()) LocalMaps(p, rect, src->roi, R, &src->map_x, &src->map_y);
  return true;
}

// Weighted colour (times the patch's exposure gain) and the weight, warped together over the roi.
void PatchBlender::Warp(size_t k, const Source& src, cv::Mat* warped) const {
  thread_local cv::Mat weighted_buffer;
  const PlacedPatch& p = patches_[k];
  const cv::Mat weight = FeatherFromAlpha(src.alpha, src.feather);
  cv::Mat weighted = Scratch(weighted_buffer, src.px.rows, src.px.cols, CV_32FC4);
  const float g = static_cast<float>(p.gain);
  for (int r = 0; r < src.px.rows; ++r) {
    const cv::Vec4b* s4 = src.px.ptr<cv::Vec4b>(r);
    const float* w = weight.ptr<float>(r);
    cv::Vec4f* c = weighted.ptr<cv::Vec4f>(r);
    for (int x = 0; x < src.px.cols; ++x) {
      const float gw = g * w[x];
      c[x] = cv::Vec4f(s4[x][0] * gw, s4[x][1] * gw, s4[x][2] * gw, w[x]);
    }
  }
  const cv::Matx33d T(1, 0, -src.roi.x, 0, 1, -src.roi.y, 0, 0, 1);
  if (p.local.empty())
    cv::warpPerspective(weighted, *warped, cv::Mat(T * src.warp), src.roi.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  else
    cv::remap(weighted, *warped, src.map_x, src.map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
}

cv::Mat PatchBlender::RenderFeather(const cv::Rect& rect) const {
  // Sums of weight x colour (channels 0-2) and of weight (3), per thread, reused.
  thread_local cv::Mat acc_buffer, warped_buffer;
  const cv::Rect2d area(rect);
  cv::Mat acc;
  for (size_t k = 0; k < patches_.size(); ++k) {
    const PlacedPatch& p = patches_[k];
    Source src;
    if (!Read(k, rect, &src)) continue;
    if (acc.empty() && src.interior && OnlyOne(k, area) && cv::countNonZero(src.alpha != 255) == 0) {
      // A region well inside a single patch, where every weight is 1 (the common case on a large
      // survey): the 8-bit warp is the blend, and 4x faster than the sums.
      cv::Mat out;
      const cv::Scalar gain(p.gain, p.gain, p.gain, 1.0);
      if (p.local.empty()) {
        cv::warpPerspective(src.px, out, cv::Mat(src.warp), rect.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
        if (p.gain != 1.0) cv::multiply(out, gain, out);
        return out;
      }
      if (src.roi == cv::Rect(0, 0, rect.width, rect.height)) {
        cv::remap(src.px, out, src.map_x, src.map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
        if (p.gain != 1.0) cv::multiply(out, gain, out);
        return out;
      }
    }
    cv::Mat warped = Scratch(warped_buffer, src.roi.height, src.roi.width, CV_32FC4);
    Warp(k, src, &warped);
    if (acc.empty()) {
      acc = Scratch(acc_buffer, rect.height, rect.width, CV_32FC4);
      acc.setTo(cv::Scalar::all(0));
    }
    acc(src.roi) += warped;
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

cv::Mat PatchBlender::RenderMultiband(const cv::Rect& rect) const {
  const int margin = 1 << (bands_ + 3);
  const cv::Rect grown(rect.x - margin, rect.y - margin, rect.width + 2 * margin, rect.height + 2 * margin);
  const cv::Size size = grown.size();
  // Each patch's colour and feather weight over the grown region; the feathered average of all,
  // which stands in for a patch's colour beyond its own data (so that no patch's coarse bands
  // carry its black surroundings across a seam).
  std::vector<cv::Mat> colour, weight;
  std::vector<const PlacedPatch*> used;
  cv::Mat acc(size, CV_32FC4, cv::Scalar::all(0));
  for (size_t k = 0; k < patches_.size(); ++k) {
    Source src;
    if (!Read(k, grown, &src)) continue;
    used.push_back(&patches_[k]);
    cv::Mat warped;
    Warp(k, src, &warped);
    cv::Mat full(size, CV_32FC4, cv::Scalar::all(0));
    warped.copyTo(full(src.roi));
    acc += full;
    cv::Mat w;
    cv::extractChannel(full, w, 3);
    weight.push_back(w);
    colour.push_back(full);
  }
  if (colour.empty()) return {};
  std::vector<cv::Mat> a;
  cv::split(acc, a);
  const cv::Mat any = a[3] > 1e-4f;
  cv::Mat mean;
  {
    cv::Mat total = cv::max(a[3], 1e-4f);
    std::vector<cv::Mat> m = {a[0] / total, a[1] / total, a[2] / total};
    cv::merge(m, mean);
  }
  // Seams where the weights cross: each pixel from the patch that is deepest inside its data;
  // where several are full (deep inside each), from the one whose frame centre is nearest, so the
  // seam runs midway between them (and every block draws it in the same place).
  cv::Mat best(size, CV_32F, cv::Scalar(1e-4f)), label(size, CV_32S, cv::Scalar(-1));
  for (size_t k = 0; k < weight.size(); ++k) {
    cv::Mat score = weight[k].clone();
    const cv::Mat full = weight[k] >= 0.999f;
    if (cv::countNonZero(full) > 0) {
      cv::Mat near = Closeness(used[k], grown);
      near.setTo(0, ~full);
      score.setTo(1.0f, full);
      score += near;
    }
    const cv::Mat better = score > best;
    score.copyTo(best, better);
    label.setTo(static_cast<int>(k), better);
  }
  // Pixels no patch covers go to the patch whose frames are nearest: the masks then cover every
  // pixel once, and a part only one patch reaches comes out exactly as that patch.
  const cv::Mat unassigned = label < 0;
  if (cv::countNonZero(unassigned) > 0) {
    cv::Mat nearest(size, CV_32F, cv::Scalar(-1.0f));
    for (size_t k = 0; k < used.size(); ++k) {
      const cv::Mat near = Closeness(used[k], grown);
      const cv::Mat better = (near > nearest) & unassigned;
      near.copyTo(nearest, better);
      label.setTo(static_cast<int>(k), better);
    }
  }
  // Burt & Adelson: each patch's Laplacian pyramid weighted by the Gaussian pyramid of its mask,
  // summed level by level and collapsed. The masks sum to one, so where one patch is alone it
  // comes out exactly as it was.
  std::vector<cv::Mat> sum(static_cast<size_t>(bands_ + 1));
  for (size_t k = 0; k < colour.size(); ++k) {
    cv::Mat mask;
    cv::Mat(label == static_cast<int>(k)).convertTo(mask, CV_32F, 1.0 / 255);
    if (cv::countNonZero(mask) == 0) continue;
    std::vector<cv::Mat> c;
    cv::split(colour[k], c);
    const cv::Mat w = cv::max(c[3], 1e-4f);
    cv::Mat image;
    cv::merge(std::vector<cv::Mat>{c[0] / w, c[1] / w, c[2] / w}, image);
    mean.copyTo(image, c[3] <= 1e-4f);
    for (int l = 0; l <= bands_; ++l) {
      cv::Mat band = image;
      if (l < bands_) {
        cv::Mat down, up;
        cv::pyrDown(image, down);
        cv::pyrUp(down, up, image.size());
        band = image - up;
        image = down;
      }
      cv::Mat m3;
      cv::merge(std::vector<cv::Mat>{mask, mask, mask}, m3);
      const cv::Mat weighted = band.mul(m3);
      auto& s_l = sum[static_cast<size_t>(l)];
      if (s_l.empty()) s_l = weighted;
      else s_l += weighted;
      if (l < bands_) cv::pyrDown(mask, mask);
    }
  }
  cv::Mat collapsed = sum[static_cast<size_t>(bands_)];
  for (int l = bands_ - 1; l >= 0; --l) {
    cv::Mat up;
    cv::pyrUp(collapsed, up, sum[static_cast<size_t>(l)].size());
    collapsed = up + sum[static_cast<size_t>(l)];
  }
  const cv::Mat blended = collapsed;
  const cv::Rect inner(margin, margin, rect.width, rect.height);
  cv::Mat bgr;
  blended(inner).convertTo(bgr, CV_8UC3);
  cv::Mat out;
  cv::cvtColor(bgr, out, cv::COLOR_BGR2BGRA);
  std::vector<cv::Mat> ch;
  cv::split(out, ch);
  ch[3] = cv::Mat(rect.size(), CV_8U, cv::Scalar(0));
  ch[3].setTo(255, any(inner));
  for (int c = 0; c < 3; ++c) ch[c].setTo(0, ~any(inner));
  cv::merge(ch, out);
  return out;
}

}  // namespace rolamos
