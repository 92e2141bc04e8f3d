#include "engine/patch_canvas.h"

#include <cmath>
#include <tuple>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

// One frame at identity: the rendered patch is that frame (the colour is the weighted mean of one
// sample), with alpha 255 wherever it carries weight and 0 outside.
TEST(PatchCanvas, RendersASingleFrameExactly) {
  const cv::Mat frame = RenderSeafloor(100, 200, 300, 200);
  PatchCanvas canvas(10'000'000);
  canvas.Add(frame, FeatherCode(FeatherWeights(frame.size(), 0.2)), cv::Matx33d::eye());
  const cv::Mat out = canvas.Render(cv::Rect(-10, -10, 320, 220));
  for (int y = 0; y < out.rows; ++y) {
    for (int x = 0; x < out.cols; ++x) {
      const int fx = x - 10, fy = y - 10;
      const bool inner = fx >= 1 && fy >= 1 && fx < frame.cols - 1 && fy < frame.rows - 1;
      const cv::Vec4b p = out.at<cv::Vec4b>(y, x);
      if (inner) {
        const cv::Vec3b f = frame.at<cv::Vec3b>(fy, fx);
        ASSERT_EQ(p[3], 255) << fx << "," << fy;
        for (int k = 0; k < 3; ++k) ASSERT_NEAR(p[k], f[k], 1) << fx << "," << fy;
      } else if (fx < 0 || fy < 0 || fx >= frame.cols || fy >= frame.rows) {
        ASSERT_EQ(p[3], 0) << fx << "," << fy;
      }
    }
  }
}

// The live preview: the whole working canvas in colour at a reduced scale, placed by its origin
// as RenderGray's image is. A frame at a shift renders where the shift puts it, with its colours,
// and transparent beyond it.
TEST(PatchCanvas, ColourPreviewShowsTheFramesWhereTheyLie) {
  const cv::Mat frame = RenderSeafloor(40, 60, 400, 300);
  PatchCanvas canvas(10'000'000, 0.5);
  const cv::Matx33d shift(1, 0, 120, 0, 1, -80, 0, 0, 1);
  canvas.Add(frame, FeatherCode(FeatherWeights(frame.size(), 0.2)), shift);
  cv::Mat bgra;
  cv::Point2d origin;
  ASSERT_TRUE(canvas.RenderColour(0.25, &bgra, &origin));
  ASSERT_EQ(bgra.type(), CV_8UC4);
  // About the frame's size at a quarter (the canvas rounds to its blocks' reduction).
  EXPECT_NEAR(bgra.cols, 100, 4);
  EXPECT_NEAR(bgra.rows, 75, 4);
  cv::Mat reduced;
  cv::resize(frame, reduced, cv::Size(), 0.25, 0.25, cv::INTER_AREA);
  double diff = 0;
  int n = 0;
  for (int y = 8; y < reduced.rows - 8; ++y)
    for (int x = 8; x < reduced.cols - 8; ++x) {
      // Frame pixel (x, y) of the reduced frame -> patch -> preview pixel.
      const cv::Point2d p((x + 0.5) * 4 - 0.5 + 120, (y + 0.5) * 4 - 0.5 - 80);
      const int qx = static_cast<int>(std::lround((p.x - origin.x + 0.5) * 0.25 - 0.5));
      const int qy = static_cast<int>(std::lround((p.y - origin.y + 0.5) * 0.25 - 0.5));
      ASSERT_TRUE(qx >= 0 && qy >= 0 && qx < bgra.cols && qy < bgra.rows) << qx << "," << qy;
      const cv::Vec4b v = bgra.at<cv::Vec4b>(qy, qx);
      ASSERT_EQ(v[3], 255);
      const cv::Vec3b f = reduced.at<cv::Vec3b>(y, x);
      for (int k = 0; k < 3; ++k) diff += std::abs(double(v[k]) - f[k]);
      n += 3;
    }
  EXPECT_LT(diff / n, 6.0) << "mean absolute difference from the frame reduced alike";
  PatchCanvas empty(10'000'000, 0.5);
  EXPECT_FALSE(empty.RenderColour(0.25, &bgra, &origin));
}

// ECC's quarter-resolution view of the mosaic comes from sums reduced as frames are added; it
// must be what reducing the full-resolution mosaic gives.
TEST(PatchCanvas, QuarterResolutionViewMatchesTheReducedMosaic) {
  const cv::Mat ground = RenderSeafloor(0, 0, 900, 700);
  PatchCanvas canvas(10'000'000);
  const FeatherCode weights(FeatherWeights({640, 480}, 0.2));
  canvas.Add(ground(cv::Rect(0, 0, 640, 480)).clone(), weights, cv::Matx33d::eye());
  const cv::Matx33d second(1, 0, 131, 0, 1, 97, 0, 0, 1);
  canvas.Add(ground(cv::Rect(131, 97, 640, 480)).clone(), weights, second);
  // Seen from a frame placed over the overlap, at 1/4 and at full resolution reduced to 1/4.
  const cv::Matx33d view(1, 0, 64, 0, 1, 48, 0, 0, 1);
  cv::Mat quarter, quarter_mask, full, full_mask;
  canvas.ViewFromFrame(view, {640, 480}, 0.25, &quarter, &quarter_mask);
  canvas.ViewFromFrame(view, {640, 480}, 1.0, &full, &full_mask);
  cv::Mat reduced;
  cv::resize(full, reduced, quarter.size(), 0, 0, cv::INTER_AREA);
  cv::Mat inner = quarter_mask.clone();
  cv::erode(inner, inner, cv::Mat(), cv::Point(-1, -1), 2);
  ASSERT_GT(cv::countNonZero(inner), static_cast<int>(inner.total() / 2));
  cv::Mat diff;
  cv::absdiff(quarter, reduced, diff);
  // Rounding of the gray conversion moves a few high-contrast pixels by more than a level.
  EXPECT_LT(cv::mean(diff, inner)[0], 0.3);
  EXPECT_LT(cv::countNonZero((diff > 2) & inner), static_cast<int>(inner.total() / 1000));
}

// The patch writer blends a band at a time from the part of each frame that lands in it: three
// overlapping frames, turned and scaled, give the same image band by band as whole.
TEST(PatchCanvas, BandsFromFramePartsRenderWhatWholeFramesRender) {
  const cv::Size size(320, 240);
  const FeatherCode code(FeatherWeights(size, 0.2));
  std::vector<cv::Mat> frames;
  std::vector<cv::Matx33d> placements;
  for (int i = 0; i < 3; ++i) {
    frames.push_back(RenderSeafloor(60 * i, 40 * i, size.width, size.height));
    const double a = 0.3 * i, s = 1 + 0.05 * i;
    placements.emplace_back(s * std::cos(a), -s * std::sin(a), 90.0 * i, s * std::sin(a), s * std::cos(a), 70.0 * i,
                            1e-5 * i, 0, 1);
  }
  const cv::Rect area(-120, -60, 560, 520);
  PatchCanvas whole(10'000'000, 1.0, false);
  for (int i = 0; i < 3; ++i) whole.Add(frames[size_t(i)], code, placements[size_t(i)]);
  const cv::Mat expected = whole.Render(area);
  cv::Mat banded(area.size(), CV_8UC4);
  for (int y = 0; y < area.height; y += 64) {
    const cv::Rect band(area.x, area.y + y, area.width, std::min(64, area.height - y));
    PatchCanvas canvas(10'000'000, 1.0, false);
    for (int i = 0; i < 3; ++i) {
      // Only the frame's pixels that land in the band (as the patch writer takes them).
      const cv::Rect part = PatchCanvas::SourceRect(placements[size_t(i)], band, size);
      if (part.empty()) continue;
      if (i == 0) EXPECT_LE(part.height, band.height + 8) << "band " << y;  // not turned: its own rows
      canvas.Add(frames[size_t(i)](part), code.Part(part),
                 placements[size_t(i)] * cv::Matx33d(1, 0, part.x, 0, 1, part.y, 0, 0, 1), band);
    }
    canvas.Render(band).copyTo(banded.rowRange(y, y + band.height));
  }
  EXPECT_EQ(cv::norm(banded, expected, cv::NORM_INF), 0);
}

// A turned frame's part of each band is most of the frame, so the patch writer interleaves it
// (colour and feather code) once and warps each band's part of that: the same bands as
// interleaving each band's part anew, 8-bit and 16-bit.
TEST(PatchCanvas, AFrameInterleavedOnceRendersWhatItsBandPartsRender) {
  const cv::Size size(320, 240);
  const FeatherCode code(FeatherWeights(size, 0.2));
  const cv::Mat frame = RenderSeafloor(30, 20, size.width, size.height);
  cv::Mat deep;
  frame.convertTo(deep, CV_16U, PatchCanvas::kDeepScale * 1.1);
  const double a = 0.7;  // 40 degrees: each band's part is most of the frame
  const cv::Matx33d placement(std::cos(a), -std::sin(a), 150, std::sin(a), std::cos(a), 10, 0, 0, 1);
  const cv::Rect area(-20, -20, 400, 420);
  for (const cv::Mat& f : {frame, deep}) {
    const cv::Mat once = PatchCanvas::Interleave(f, code.code);
    ASSERT_EQ(once.channels(), 4);
    double share = 0;
    for (int y = 0; y < area.height; y += 64) {
      const cv::Rect band(area.x, area.y + y, area.width, std::min(64, area.height - y));
      const cv::Rect part = PatchCanvas::SourceRect(placement, band, size);
      if (part.empty()) continue;
      share += part.area();
      const cv::Matx33d part_to_patch = placement * cv::Matx33d(1, 0, part.x, 0, 1, part.y, 0, 0, 1);
      PatchCanvas anew(10'000'000, 1.0, false), reused(10'000'000, 1.0, false);
      anew.Add(f(part), code.Part(part), part_to_patch, band);
      reused.AddInterleaved(once(part), code.weight, part_to_patch, band);
      EXPECT_EQ(cv::norm(anew.Render(band), reused.Render(band), cv::NORM_INF), 0) << "band " << y;
    }
    EXPECT_GT(share, 2.0 * size.area());  // what interleaving once saves
  }
}

// Colour correction and interleaving in one pass: what OpenCV's multiply (or convertTo without a
// colour map) gives, to a unit of the 16-bit scale, saturated alike; the code exact.
TEST(PatchCanvas, DeepInterleavingCorrectsAsOpenCVDoes) {
  const cv::Size size(97, 61);
  cv::Mat frame(size, CV_8UC3), colour(size, CV_32FC3), code(size, CV_8U);
  cv::RNG rng(7);
  rng.fill(frame, cv::RNG::UNIFORM, 0, 256);
  rng.fill(colour, cv::RNG::UNIFORM, 0.2, 12.0);  // up to past the 16-bit range at 255
  rng.fill(code, cv::RNG::UNIFORM, 0, 256);
  const double scale = 1.07 * PatchCanvas::kDeepScale;
  for (const cv::Mat& map : {colour, cv::Mat()}) {
    cv::Mat expected;
    if (map.empty()) frame.convertTo(expected, CV_16U, scale);
    else cv::multiply(frame, map, expected, scale, CV_16U);
    const cv::Mat got = PatchCanvas::InterleaveDeep(frame, map, scale, code);
    ASSERT_EQ(got.type(), CV_16UC4);
    std::vector<cv::Mat> ch;
    cv::split(got, ch);
    cv::Mat bgr, wide;
    cv::merge(std::vector<cv::Mat>(ch.begin(), ch.begin() + 3), bgr);
    EXPECT_LE(cv::norm(bgr, expected, cv::NORM_INF), 1.0);
    if (!map.empty()) EXPECT_GT(cv::countNonZero(ch[0] == 65535), 0);  // saturated, not wrapped
    code.convertTo(wide, CV_16U);
    EXPECT_EQ(cv::norm(ch[3], wide, cv::NORM_INF), 0);
  }
}

// The working canvas's sums, by the book: two frames at whole-pixel shifts (their warps copy
// them), each pixel weight[code] x colour and weight[code] added frame after frame where the
// code is not 0; one frame starts on an odd column, both leave rows' tails.
TEST(PatchCanvas, WorkingCanvasSumsAreTheFramesWeighted) {
  const cv::Mat a = RenderSeafloor(10, 20, 203, 61), b = RenderSeafloor(60, 10, 187, 57);
  const FeatherCode code_a(FeatherWeights(a.size(), 0.2)), code_b(FeatherWeights(b.size(), 0.2));
  PatchCanvas canvas(10'000'000);
  const cv::Point at_a(0, 0), at_b(33, 7);
  canvas.Add(a, code_a, cv::Matx33d(1, 0, at_a.x, 0, 1, at_a.y, 0, 0, 1));
  canvas.Add(b, code_b, cv::Matx33d(1, 0, at_b.x, 0, 1, at_b.y, 0, 0, 1));
  const cv::Rect rect(0, 0, 240, 70);
  cv::Mat sum = cv::Mat::zeros(rect.size(), CV_32FC3), weight = cv::Mat::zeros(rect.size(), CV_32F);
  for (const auto& [frame, code, at] : {std::make_tuple(&a, &code_a, at_a), std::make_tuple(&b, &code_b, at_b)})
    for (int y = 0; y < frame->rows; ++y)
      for (int x = 0; x < frame->cols; ++x) {
        const uchar c = code->code.at<uchar>(y, x);
        if (!c) continue;
        const float w = code->weight[c];
        const cv::Vec3b p = frame->at<cv::Vec3b>(y, x);
        sum.at<cv::Vec3f>(y + at.y, x + at.x) += cv::Vec3f(w * p[0], w * p[1], w * p[2]);
        weight.at<float>(y + at.y, x + at.x) += w;
      }
  EXPECT_EQ(cv::norm(canvas.Render(rect), RenderSums(sum, weight), cv::NORM_INF), 0);
}

// The sums rendered as the rule says, value by value: colours past 255 and below 0, weights at
// and around the cut, products on a rounding boundary (half-way values go to the even byte).
TEST(PatchCanvas, RendersSumsByTheRule) {
  const cv::Size size(53, 7);  // three 16-pixel steps and a tail
  cv::Mat sum(size, CV_32FC3), weight(size, CV_32F);
  cv::RNG rng(5);
  rng.fill(sum, cv::RNG::UNIFORM, -40.0, 600.0);
  rng.fill(weight, cv::RNG::UNIFORM, 0.0, 2.0);
  weight.at<float>(0, 3) = kAlphaCut;
  weight.at<float>(0, 4) = std::nextafter(kAlphaCut, 1.0f);
  weight.at<float>(1, 5) = 0;
  for (int x = 0; x < 8; ++x) {
    weight.at<float>(2, x) = 1.0f;
    sum.at<cv::Vec3f>(2, x) = cv::Vec3f(x + 0.5f, 254.5f, 255.5f);
  }
  const cv::Mat out = RenderSums(sum, weight);
  ASSERT_EQ(out.type(), CV_8UC4);
  int wrong = 0;
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const float w = weight.at<float>(y, x);
      cv::Vec4b want(0, 0, 0, 0);
      if (w > kAlphaCut) {
        const float k = 1.0f / w;
        const cv::Vec3f s = sum.at<cv::Vec3f>(y, x);
        want = cv::Vec4b(cv::saturate_cast<uchar>(s[0] * k), cv::saturate_cast<uchar>(s[1] * k),
                         cv::saturate_cast<uchar>(s[2] * k), 255);
      }
      wrong += out.at<cv::Vec4b>(y, x) != want;
    }
  EXPECT_EQ(wrong, 0);
  EXPECT_EQ(out.at<cv::Vec4b>(2, 1), cv::Vec4b(2, 254, 255, 255));  // 1.5 -> 2, 254.5 -> 254
  EXPECT_EQ(out.at<cv::Vec4b>(0, 3), cv::Vec4b(0, 0, 0, 0));
}

}  // namespace
}  // namespace rolamos
