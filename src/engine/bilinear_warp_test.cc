#include "engine/bilinear_warp.h"

#include <array>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"

namespace rolamos {
namespace {

// A smooth BGRW image (the warp's error grows with the image's gradient) of `type`.
cv::Mat SmoothImage(cv::Size size, int type, double top) {
  cv::Mat noise(size, CV_32FC4);
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, top);
  cv::GaussianBlur(noise, noise, cv::Size(), 6.0);
  cv::normalize(noise.reshape(1), noise.reshape(1), 0, top, cv::NORM_MINMAX);
  cv::Mat out;
  noise.convertTo(out, type);
  return out;
}

// Bilinear with edge pixels repeated, in double: what the warp must give. `sub`: positions
// rounded to 1/sub px first, as the warp rounds them.
cv::Vec4d Reference(const cv::Mat& src, const cv::Matx33d& dst_to_src, int x, int y, double sub = 0) {
  const cv::Vec3d q = dst_to_src * cv::Vec3d(x, y, 1);
  double sx = q[0] / q[2], sy = q[1] / q[2];
  if (sub > 0) sx = std::round(sx * sub) / sub, sy = std::round(sy * sub) / sub;
  const double fx = std::floor(sx), fy = std::floor(sy);
  const auto at = [&](int xx, int yy, int c) {
    xx = std::clamp(xx, 0, src.cols - 1);
    yy = std::clamp(yy, 0, src.rows - 1);
    return src.depth() == CV_8U ? double(src.at<cv::Vec4b>(yy, xx)[c]) : double(src.at<cv::Vec4w>(yy, xx)[c]);
  };
  cv::Vec4d v;
  for (int c = 0; c < 4; ++c) {
    const int x0 = int(fx), y0 = int(fy);
    const double ax = sx - fx, ay = sy - fy;
    v[c] = (1 - ay) * ((1 - ax) * at(x0, y0, c) + ax * at(x0 + 1, y0, c)) +
           ay * ((1 - ax) * at(x0, y0 + 1, c) + ax * at(x0 + 1, y0 + 1, c));
  }
  return v;
}

// The largest change between neighbouring pixels, any channel: what a position error of e pixels
// can change a bilinear value by, times e, per axis.
double Steepest(const cv::Mat& image) {
  cv::Mat f, dx, dy;
  image.reshape(1).convertTo(f, CV_64F);
  cv::absdiff(f.colRange(4, f.cols), f.colRange(0, f.cols - 4), dx);
  cv::absdiff(f.rowRange(1, f.rows), f.rowRange(0, f.rows - 1), dy);
  double mx = 0, my = 0;
  cv::minMaxLoc(dx, nullptr, &mx);
  cv::minMaxLoc(dy, nullptr, &my);
  return mx + my;
}

// Turned, scaled, tilted, and placed so that part of the output lies beyond the frame (edge
// pixels repeated there).
const cv::Matx33d kWarps[] = {
    {1, 0, 0, 0, 1, 0, 0, 0, 1},
    {0.97, -0.26, 40.3, 0.26, 0.97, -12.7, 0, 0, 1},
    {1.21, 0.05, -30.5, -0.08, 1.17, 10.25, 2e-4, -1.5e-4, 1},
    {0.6, 0.2, 300, -0.3, 0.7, 200, -3e-4, 1e-4, 1},
};

// Every code but 0 weighs 1: the sums are then the warped colour itself, unrounded.
std::array<float, 256> UnitWeights() {
  std::array<float, 256> table;
  table.fill(1.0f);
  table[0] = 0.0f;
  return table;
}

// The frame warped by `m` onto a zero canvas of `size`, with UnitWeights and code 255 everywhere
// (every pixel weighs 1, edge pixels repeated beyond the frame): its colour.
cv::Mat WarpedColour(cv::Mat src, const cv::Matx33d& m, cv::Size size) {
  std::vector<cv::Mat> ch;
  cv::split(src, ch);
  ch[3].setTo(255);
  cv::merge(ch, src);
  cv::Mat sum = cv::Mat::zeros(size, CV_32FC3), weight = cv::Mat::zeros(size, CV_32F);
  WarpAccumulate(src, m, UnitWeights(), 1.0f, sum, weight, CodeEdges{});
  EXPECT_EQ(cv::countNonZero(weight != 1.0f), 0);
  return sum;
}

TEST(BilinearWarp, IsBilinearWithEdgePixelsRepeatedInBothDepths) {
  for (const int type : {CV_8UC4, CV_16UC4}) {
    const double top = type == CV_8UC4 ? 255 : 16320;  // 16 bits: 255 grey levels x 64
    const cv::Mat src = SmoothImage({203, 151}, type, top);
    const double steepest = Steepest(src);
    for (const cv::Matx33d& m : kWarps) {
      const cv::Size size(260, 230);
      const cv::Mat colour = WarpedColour(src, m, size);
      const cv::Matx33d back = m.inv();
      double worst = 0;
      for (int y = 0; y < size.height; ++y)
        for (int x = 0; x < size.width; ++x) {
          const cv::Vec4d want = Reference(src, back, x, y);
          for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(colour.at<cv::Vec3f>(y, x)[c] - want[c]));
        }
      // Float arithmetic, and positions rounded to 1/256 px.
      EXPECT_LE(worst, top * 1e-5 + steepest / 512) << cv::typeToString(type) << " warp " << m;
    }
  }
}

// The same as OpenCV's warp up to its positions rounded to 1/32 pixel and its levels rounded.
TEST(BilinearWarp, AgreesWithOpenCvsWarp) {
  for (const int type : {CV_8UC4, CV_16UC4}) {
    const double top = type == CV_8UC4 ? 255 : 16320;
    const cv::Mat src = SmoothImage({320, 240}, type, top);
    for (const cv::Matx33d& m : kWarps) {
      const cv::Size size(400, 300);
      cv::Mat theirs, theirs_colour;
      cv::warpPerspective(src, theirs, cv::Mat(m), size, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      std::vector<cv::Mat> ch;
      cv::split(theirs, ch);
      cv::merge(std::vector<cv::Mat>(ch.begin(), ch.begin() + 3), theirs_colour);
      theirs_colour.convertTo(theirs_colour, CV_32FC3);
      cv::Mat diff;
      cv::absdiff(WarpedColour(src, m, size).reshape(1), theirs_colour.reshape(1), diff);
      double worst = 0;
      cv::minMaxLoc(diff, nullptr, &worst);
      EXPECT_LE(cv::mean(diff)[0], 0.5 + top * 2e-4) << cv::typeToString(type) << " warp " << m;
      EXPECT_LE(worst, 1 + top * 2e-3) << cv::typeToString(type) << " warp " << m;
    }
  }
}

// A placement that sends part of the output behind the camera (the denominator crosses zero):
// positions that are not numbers or are huge must still give pixels, not a crash.
TEST(BilinearWarp, SurvivesADegeneratePlacement) {
  const cv::Mat src = SmoothImage({64, 48}, CV_8UC4, 255);
  // w = 1 + 0.05 x crosses zero at x = -20 of the source: the output's left part comes from
  // behind the camera, its right part from the frame as usual.
  const cv::Matx33d m(1, 0, 0, 0, 1, 0, 0.05, 0, 1);
  const cv::Mat colour = WarpedColour(src, m, {128, 96});
  const cv::Matx33d back = m.inv();
  for (int y = 0; y < 20; ++y)
    for (int x = 0; x < 20; ++x) {
      const cv::Vec4d want = Reference(src, back, x, y);
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(colour.at<cv::Vec3f>(y, x)[c], want[c], 0.1) << x << "," << y;
    }
  // Every pixel from a point at infinity.
  cv::Mat sum = cv::Mat::zeros(16, 16, CV_32FC3), weight = cv::Mat::zeros(16, 16, CV_32F);
  EXPECT_NO_THROW(WarpAccumulate(src, cv::Matx33d(1, 0, 0, 0, 1, 0, 0, 0, 1e-30), UnitWeights(), 1.0f, sum, weight,
                                 CodeEdges{}));
}

// Blended straight into a canvas: each pixel adds weight[code] x colour x unit, and onto what
// the canvas holds; the code rounded as the warped image would hold it, the colour not.
TEST(BilinearWarp, AccumulatesWhatTheWarpedFrameWouldAdd) {
  std::array<float, 256> table;
  for (int c = 0; c < 256; ++c) table[size_t(c)] = c == 0 ? 0.0f : 0.01f + c / 255.0f;
  for (const int type : {CV_8UC4, CV_16UC4}) {
    const double top = type == CV_8UC4 ? 255 : 16320;
    cv::Mat src = SmoothImage({203, 151}, type, top);
    // The code channel: 0 on the outer ring, 1..255 inside, as a feather code is.
    for (int y = 0; y < src.rows; ++y)
      for (int x = 0; x < src.cols; ++x) {
        const bool edge = x == 0 || y == 0 || x == src.cols - 1 || y == src.rows - 1;
        const int code = edge ? 0 : 1 + (x + y) * 254 / (src.cols + src.rows);  // smooth
        if (type == CV_8UC4) src.at<cv::Vec4b>(y, x)[3] = uchar(code);
        else src.at<cv::Vec4w>(y, x)[3] = ushort(code);
      }
    const float unit = type == CV_8UC4 ? 1.0f : 1.0f / 64;
    for (const cv::Matx33d& m : kWarps) {
      const cv::Size size(260, 230);
      cv::Mat sum(size, CV_32FC3, cv::Scalar::all(1)), weight(size, CV_32F, cv::Scalar(2));
      WarpAccumulate(src, m, table, unit, sum, weight, CodeEdges{});
      // With the ring's code 0, the pixels beyond the frame are left out: the same sums.
      const CodeEdges ring = ZeroCodeEdges(src);
      ASSERT_TRUE(ring.left && ring.right && ring.top && ring.bottom);
      cv::Mat skipped(size, CV_32FC3, cv::Scalar::all(1)), skipped_weight(size, CV_32F, cv::Scalar(2));
      WarpAccumulate(src, m, table, unit, skipped, skipped_weight, ring);
      EXPECT_EQ(cv::norm(sum.reshape(1), skipped.reshape(1), cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      EXPECT_EQ(cv::norm(weight, skipped_weight, cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      // A band of the frame (rows 40 to 99: its first and last rows hold codes, its sides are
      // the frame's), placed where the frame puts it: only beyond its sides is anything left out.
      const cv::Mat band = src.rowRange(40, 100);
      const CodeEdges sides = ZeroCodeEdges(band);
      ASSERT_TRUE(sides.left && sides.right && !sides.top && !sides.bottom);
      const cv::Matx33d band_to_canvas = m * cv::Matx33d(1, 0, 0, 0, 1, 40, 0, 0, 1);
      cv::Mat whole(size, CV_32FC3, cv::Scalar::all(1)), whole_weight(size, CV_32F, cv::Scalar(2));
      cv::Mat part(size, CV_32FC3, cv::Scalar::all(1)), part_weight(size, CV_32F, cv::Scalar(2));
      WarpAccumulate(band, band_to_canvas, table, unit, whole, whole_weight, CodeEdges{});
      WarpAccumulate(band, band_to_canvas, table, unit, part, part_weight, sides);
      EXPECT_EQ(cv::norm(whole.reshape(1), part.reshape(1), cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      EXPECT_EQ(cv::norm(whole_weight, part_weight, cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      const cv::Matx33d back = m.inv();
      int blended = 0;
      for (int y = 0; y < size.height; ++y)
        for (int x = 0; x < size.width; ++x) {
          const cv::Vec4d want = Reference(src, back, x, y, 256);
          const int code = std::min(255, int(std::lround(want[3])));
          // A code on the edge of rounding may go either way.
          if (std::abs(want[3] - std::floor(want[3]) - 0.5) < 0.01) continue;
          const float a = table[size_t(std::max(code, 0))];
          ASSERT_NEAR(weight.at<float>(y, x), 2 + a, 1e-5) << x << "," << y;
          for (int c = 0; c < 3; ++c)
            ASSERT_NEAR(sum.at<cv::Vec3f>(y, x)[c], 1 + a * want[c] * unit, 1e-4 * (1 + a * want[c] * unit))
                << cv::typeToString(type) << " at " << x << "," << y;
          blended += code > 0;
        }
      // The last placement puts the frame beyond this canvas: the sums stay as they were.
      if (&m == &kWarps[3]) EXPECT_EQ(blended, 0);
      else EXPECT_GT(blended, 1000) << cv::typeToString(type) << " warp " << m;
    }
  }
}

// A canvas blended whole (sixteen pixels a step) equals it blended in strips seven pixels wide
// (the last pixels of each row, one by one), to the bit: the patch's pixels do not depend on
// where a row's runs begin.
TEST(BilinearWarp, SumsDoNotDependOnHowARowIsSplit) {
  std::array<float, 256> table;
  for (int c = 0; c < 256; ++c) table[size_t(c)] = c == 0 ? 0.0f : 0.02f + c / 300.0f;
  for (const int type : {CV_8UC4, CV_16UC4}) {
    const double top = type == CV_8UC4 ? 255 : 16320;
    const cv::Mat src = SmoothImage({203, 151}, type, top);  // codes vary with the noise
    const float unit = type == CV_8UC4 ? 1.0f : 1.0f / 64;
    for (const cv::Matx33d& m : kWarps) {
      const cv::Size size(261, 230);
      cv::Mat whole(size, CV_32FC3, cv::Scalar::all(1)), whole_weight(size, CV_32F, cv::Scalar(2));
      WarpAccumulate(src, m, table, unit, whole, whole_weight, CodeEdges{});
      cv::Mat strips(size, CV_32FC3, cv::Scalar::all(1)), strips_weight(size, CV_32F, cv::Scalar(2));
      for (int x = 0; x < size.width; x += 7) {
        const cv::Rect strip(x, 0, std::min(7, size.width - x), size.height);
        cv::Mat sum = strips(strip), weight = strips_weight(strip);
        WarpAccumulate(src, cv::Matx33d(1, 0, -x, 0, 1, 0, 0, 0, 1) * m, table, unit, sum, weight, CodeEdges{});
      }
      EXPECT_EQ(cv::norm(whole.reshape(1), strips.reshape(1), cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      EXPECT_EQ(cv::norm(whole_weight, strips_weight, cv::NORM_INF), 0.0) << cv::typeToString(type) << " " << m;
      if (&m != &kWarps[3]) EXPECT_GT(cv::countNonZero(whole_weight != 2.0f), 1000) << cv::typeToString(type) << " " << m;
    }
  }
}

TEST(BilinearWarp, TellsWhichEdgesHoldNoCode) {
  const auto edges = [](const CodeEdges& e) {
    return std::string(e.left ? "L" : "") + (e.right ? "R" : "") + (e.top ? "T" : "") + (e.bottom ? "B" : "");
  };
  for (const int type : {CV_8UC4, CV_16UC4}) {
    cv::Mat src(40, 30, type, cv::Scalar(9, 9, 9, 7));
    EXPECT_EQ(edges(ZeroCodeEdges(src)), "");
    src.row(0).setTo(cv::Scalar(9, 9, 9, 0));
    src.row(39).setTo(cv::Scalar(9, 9, 9, 0));
    src.col(0).setTo(cv::Scalar(9, 9, 9, 0));
    EXPECT_EQ(edges(ZeroCodeEdges(src)), "LTB") << "the last column still holds 7";
    src.col(29).setTo(cv::Scalar(9, 9, 9, 0));
    EXPECT_EQ(edges(ZeroCodeEdges(src)), "LRTB");
    if (type == CV_8UC4)
      src.at<cv::Vec4b>(39, 17)[3] = 1;
    else
      src.at<cv::Vec4w>(39, 17)[3] = 1;
    EXPECT_EQ(edges(ZeroCodeEdges(src)), "LRT");
  }
}

TEST(BilinearWarp, SaysWhichImageItCannotWarp) {
  const cv::Mat grey(10, 10, CV_8UC1, cv::Scalar(0));
  try {
    cv::Mat sum = cv::Mat::zeros(10, 10, CV_32FC3), weight = cv::Mat::zeros(10, 10, CV_32F);
    WarpAccumulate(grey, cv::Matx33d::eye(), UnitWeights(), 1.0f, sum, weight, CodeEdges{});
    FAIL() << "a grey image was warped";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("8UC1"), std::string::npos) << e.what();
  }
}

// The temporal filter's warp: cv::warpPerspective with a transparent border, bilinear.
TEST(WarpInside, IsOpenCvsTransparentWarp) {
  const cv::Mat bgrw = SmoothImage(cv::Size(403, 301), CV_8UC4, 255);
  cv::Mat src;
  cv::cvtColor(bgrw, src, cv::COLOR_BGRA2BGR);
  const cv::Mat background(src.size(), CV_8UC3, cv::Scalar(1, 2, 3));
  // Turned, scaled, in perspective and moved by 40 px: part of the frame falls outside `src`.
  const cv::Matx33d dst_to_src(0.998, 0.03, 40.3, -0.02, 1.004, -3.7, 2e-5, -1e-5, 1);
  cv::Mat ours = background.clone(), theirs = background.clone();
  WarpInside(src, dst_to_src, ours);
  cv::warpPerspective(src, theirs, cv::Mat(dst_to_src), src.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                      cv::BORDER_TRANSPARENT);
  int inner = 0, edge_differs = 0;
  double worst = 0;
  for (int y = 0; y < src.rows; ++y)
    for (int x = 0; x < src.cols; ++x) {
      const cv::Vec3d q = dst_to_src * cv::Vec3d(x, y, 1);
      const double sx = q[0] / q[2], sy = q[1] / q[2];
      const cv::Vec3b a = ours.at<cv::Vec3b>(y, x), b = theirs.at<cv::Vec3b>(y, x);
      if (sx < -0.1 || sy < -0.1 || sx > src.cols - 0.9 || sy > src.rows - 0.9) {
        EXPECT_EQ(a, background.at<cv::Vec3b>(y, x)) << x << ", " << y;  // its taps are not all inside
      } else if (sx > 0.1 && sy > 0.1 && sx < src.cols - 1.1 && sy < src.rows - 1.1) {
        ++inner;
        for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(double(a[c]) - double(b[c])));
      } else {
        edge_differs += a != b;  // OpenCV rounds the position to 1/32 px first: either may take it
      }
    }
  EXPECT_GT(inner, 100000);
  EXPECT_LE(worst, 1);  // positions rounded to 1/32 px apart, on a smooth image
  EXPECT_LT(edge_differs, 2 * (src.cols + src.rows));
}

// Every pixel the identity reaches (all but the last row and column, whose taps pass the edge),
// exactly; the image's last pixel (read apart from the others) included.
TEST(WarpInside, IdentityCopiesWhatItReaches) {
  for (const cv::Size size : {cv::Size(17, 5), cv::Size(64, 3), cv::Size(2, 2)}) {
    cv::Mat src(size, CV_8UC3);
    cv::RNG(5).fill(src, cv::RNG::UNIFORM, 0, 256);
    cv::Mat dst(size, CV_8UC3, cv::Scalar(9, 9, 9));
    WarpInside(src, cv::Matx33d::eye(), dst);
    const cv::Rect reached(0, 0, size.width - 1, size.height - 1);
    EXPECT_EQ(cv::norm(dst(reached), src(reached), cv::NORM_INF), 0) << size;
    EXPECT_EQ(cv::norm(dst.col(size.width - 1), cv::Mat(size.height, 1, CV_8UC3, cv::Scalar(9, 9, 9)), cv::NORM_INF), 0);
    // Shifted by a third of a pixel: the image's last pixel is a tap of the last pixel reached.
    // Against bilinear at the exact position (OpenCV's 1/32 px would be 3 grey levels off on noise).
    cv::Mat shifted(size, CV_8UC3, cv::Scalar(9, 9, 9));
    WarpInside(src, cv::Matx33d(1, 0, 1.0 / 3, 0, 1, 1.0 / 3, 0, 0, 1), shifted);
    for (int y = 0; y + 1 < size.height; ++y)
      for (int x = 0; x + 1 < size.width; ++x)
        for (int c = 0; c < 3; ++c) {
          auto at = [&](int yy, int xx) { return double(src.at<cv::Vec3b>(yy, xx)[c]); };
          const double top = at(y, x) + (at(y, x + 1) - at(y, x)) / 3, bottom = at(y + 1, x) + (at(y + 1, x + 1) - at(y + 1, x)) / 3;
          EXPECT_LE(std::abs(shifted.at<cv::Vec3b>(y, x)[c] - (top + (bottom - top) / 3)), 0.5 + 1e-3) << size << x << "," << y;
        }
  }
}

// What the vector path does not take (grey frames here) is OpenCV's own, value for value.
TEST(WarpInside, GreyFramesAreOpenCvs) {
  cv::Mat src(60, 80, CV_8UC1), ours(60, 80, CV_8UC1, cv::Scalar(7)), theirs = ours.clone();
  cv::RNG(2).fill(src, cv::RNG::UNIFORM, 0, 256);
  const cv::Matx33d m(1, 0.1, 3.3, 0, 1, -2.2, 0, 0, 1);
  WarpInside(src, m, ours);
  cv::warpPerspective(src, theirs, cv::Mat(m), src.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                      cv::BORDER_TRANSPARENT);
  EXPECT_EQ(cv::norm(ours, theirs, cv::NORM_INF), 0);
}

}  // namespace
}  // namespace rolamos
