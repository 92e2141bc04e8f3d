#include "engine/features.h"

#include <algorithm>
#include <cfloat>
#include <tuple>
#include <set>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "synth/seafloor_texture.h"

namespace rolamos {
namespace {

// Each extraction starts from a threshold raised to the last one's weakest kept response; the
// features must be those a fresh extractor finds, on textured ground (kept from the raised start)
// and on flat ground after it (found again from the options' threshold).
TEST(Features, RaisedStartFindsWhatAFreshExtractorFinds) {
  cv::Mat textured, flat;
  cv::cvtColor(RenderSeafloor(0, 0, 640, 480), textured, cv::COLOR_BGR2GRAY);
  cv::GaussianBlur(textured, flat, cv::Size(), 10);
  flat.convertTo(flat, CV_8U, 0.2, 100);
  cv::Mat shifted;
  cv::warpAffine(textured, shifted, cv::Mat(cv::Matx23d(1, 0, 30, 0, 1, 20)), textured.size(), cv::INTER_LINEAR,
                 cv::BORDER_REFLECT);
  FeatureOptions o;
  o.max_features = 500;
  o.detect_scale = 1.0;
  for (bool doubled : {true, false}) {
    o.double_first_octave = doubled;
    const FeatureExtractor running(o);
    for (const cv::Mat* image : {&textured, &shifted, &flat, &textured}) {
      const Features got = running.Extract(*image);
      const Features want = FeatureExtractor(o).Extract(*image);
      ASSERT_EQ(got.points.size(), want.points.size()) << "doubled " << doubled;
      ASSERT_FALSE(got.points.empty());
      EXPECT_EQ(got.strong, want.strong);
      for (size_t i = 0; i < got.points.size(); ++i) ASSERT_EQ(got.points[i], want.points[i]) << i;
      EXPECT_EQ(cv::norm(got.descriptors, want.descriptors, cv::NORM_INF), 0.0);
    }
  }
  // The flat image has fewer than max_features candidates: it was found again from the
  // options' threshold (else it would have kept only the strong few).
  EXPECT_LT(FeatureExtractor(o).Extract(flat).points.size(), 500u);
}

// SIFT matching uses one distance matrix for both directions; it must keep exactly the matches
// OpenCV's brute-force kNN + ratio test + mutual-best check keeps.
TEST(Features, DistanceMatrixMatchingEqualsBruteForceWithCrossCheck) {
  const cv::Mat ground = RenderSeafloor(0, 0, 800, 600);
  cv::Mat a, b;
  cv::cvtColor(ground(cv::Rect(0, 0, 640, 480)), a, cv::COLOR_BGR2GRAY);
  cv::Mat M = cv::getRotationMatrix2D({320, 240}, 7, 1.04);
  M.at<double>(0, 2) += 40;
  M.at<double>(1, 2) += 25;
  cv::Mat warped;
  cv::warpAffine(ground, warped, M, {640, 480});
  cv::cvtColor(warped, b, cv::COLOR_BGR2GRAY);
  FeatureOptions o;
  o.max_features = 600;
  FeatureExtractor extractor(o);
  const Features fa = extractor.Extract(a), fb = extractor.Extract(b);
  ASSERT_GT(fa.points.size(), 300u);
  for (bool cross : {true, false}) {
    o.cross_check = cross;
    const Matches ours = MatchFeatures(fa, fb, o);
    cv::BFMatcher bf(cv::NORM_L2);
    std::vector<std::vector<cv::DMatch>> knn;
    bf.knnMatch(fa.descriptors, fb.descriptors, knn, 2);
    std::vector<cv::DMatch> back;
    bf.match(fb.descriptors, fa.descriptors, back);
    std::set<std::pair<int, int>> reference;
    for (const auto& k : knn)
      if (k.size() == 2 && k[0].distance < o.ratio * k[1].distance &&
          (!cross || back[static_cast<size_t>(k[0].trainIdx)].trainIdx == k[0].queryIdx))
        reference.insert({k[0].queryIdx, k[0].trainIdx});
    ASSERT_GT(reference.size(), 100u);
    // Compare as point pairs (the matcher reports points, not indices).
    std::set<std::pair<std::pair<float, float>, std::pair<float, float>>> got, want;
    for (size_t i = 0; i < ours.from.size(); ++i)
      got.insert({{ours.from[i].x, ours.from[i].y}, {ours.to[i].x, ours.to[i].y}});
    for (const auto& [i, j] : reference)
      want.insert({{fa.points[static_cast<size_t>(i)].x, fa.points[static_cast<size_t>(i)].y},
                   {fb.points[static_cast<size_t>(j)].x, fb.points[static_cast<size_t>(j)].y}});
    // Ties between equal distances may resolve differently: allow a handful.
    size_t common = 0;
    for (const auto& m : got) common += want.count(m);
    EXPECT_GE(common + 3, want.size()) << "cross-check " << cross;
    EXPECT_GE(common + 3, got.size()) << "cross-check " << cross;
  }
}

// A detector per call: extraction from two threads at once gives what one thread gives.
TEST(Features, ExtractionIsTheSameFromConcurrentThreads) {
  cv::Mat gray;
  cv::cvtColor(RenderSeafloor(0, 0, 640, 480), gray, cv::COLOR_BGR2GRAY);
  FeatureExtractor extractor(FeatureOptions{});
  const Features alone = extractor.Extract(gray);
  Features one, two;
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) (i == 0 ? one : two) = extractor.Extract(gray);
  });
  for (const Features* f : {&one, &two}) {
    ASSERT_EQ(f->points.size(), alone.points.size());
    EXPECT_EQ(cv::norm(f->descriptors, alone.descriptors, cv::NORM_INF), 0.0);
  }
}

// A feature found on an image and on the image turned 180 degrees must be at the same place: a
// constant offset (OpenCV 4.6's SIFT puts every keypoint 0.25 px right of and below where it is)
// cancels between frames of one heading but doubles between a lawnmower's lanes.
TEST(Features, PositionsAgreeOnAnImageTurnedHalfRound) {
  cv::Mat gray;
  cv::cvtColor(RenderSeafloor(0, 0, 480, 360), gray, cv::COLOR_BGR2GRAY);
  cv::Mat turned;
  cv::rotate(gray, turned, cv::ROTATE_180);
  for (const bool upsample : {true, false}) {
    FeatureOptions o;
    o.detect_scale = 1.0;
    o.double_first_octave = upsample;
    const FeatureExtractor extractor(o);
    const Features a = extractor.Extract(gray), b = extractor.Extract(turned);
    const Matches m = MatchFeatures(a, b, o);
    // p in the image is (w - 1 - x, h - 1 - y) in the turned one: their sum is (w - 1, h - 1).
    std::vector<float> dx, dy;
    for (size_t i = 0; i < m.from.size(); ++i) {
      const float x = m.from[i].x + m.to[i].x - float(gray.cols - 1), y = m.from[i].y + m.to[i].y - float(gray.rows - 1);
      if (std::abs(x) < 2 && std::abs(y) < 2) {
        dx.push_back(x);
        dy.push_back(y);
      }
    }
    ASSERT_GT(dx.size(), 100u) << "upsample " << upsample;
    std::nth_element(dx.begin(), dx.begin() + long(dx.size() / 2), dx.end());
    std::nth_element(dy.begin(), dy.begin() + long(dy.size() / 2), dy.end());
    // Twice the offset: 0.5 px before the correction.
    EXPECT_LT(std::abs(dx[dx.size() / 2]), 0.05) << "upsample " << upsample;
    EXPECT_LT(std::abs(dy[dy.size() / 2]), 0.05) << "upsample " << upsample;
  }
}

// Without the doubled octave, the features are the same kind (most of them match the doubled
// octave's) and as many as asked for on textured ground.
TEST(Features, HalvedDetectionFindsTheSameFeatures) {
  cv::Mat gray;
  cv::cvtColor(RenderSeafloor(0, 0, 640, 480), gray, cv::COLOR_BGR2GRAY);
  FeatureOptions o;
  o.detect_scale = 1.0;
  o.max_features = 500;
  const Features doubled = FeatureExtractor(o).Extract(gray);
  o.double_first_octave = false;
  const Features halved = FeatureExtractor(o).Extract(gray);
  ASSERT_EQ(halved.descriptors.rows, static_cast<int>(halved.points.size()));
  EXPECT_GT(halved.points.size(), 300u);
  const Matches m = MatchFeatures(halved, doubled, o);
  int same_place = 0;
  for (size_t i = 0; i < m.from.size(); ++i) same_place += cv::norm(m.from[i] - m.to[i]) < 1.0;
  EXPECT_GT(same_place, static_cast<int>(halved.points.size() / 3));
}

// SIFT's descriptors (whole numbers 0..255, as floats) and ORB's (bits): cv::norm's distance.
TEST(DescriptorDistance, IsCvNormsToTheBit) {
  cv::RNG rng(3);
  Features a, b;
  a.descriptors.create(40, 128, CV_32F);
  b.descriptors.create(50, 128, CV_32F);
  for (cv::Mat* d : {&a.descriptors, &b.descriptors}) {
    cv::Mat bytes(d->size(), CV_8U);
    rng.fill(bytes, cv::RNG::UNIFORM, 0, 256);
    bytes.convertTo(*d, CV_32F);
  }
  a.norm = b.norm = cv::NORM_L2;
  for (int i = 0; i < a.descriptors.rows; ++i)
    for (int j = 0; j < b.descriptors.rows; ++j)
      ASSERT_EQ(DescriptorDistance(a, i, b, j), cv::norm(a.descriptors.row(i), b.descriptors.row(j), cv::NORM_L2));
  a.descriptors.create(10, 32, CV_8U);
  b.descriptors.create(10, 32, CV_8U);
  rng.fill(a.descriptors, cv::RNG::UNIFORM, 0, 256);
  rng.fill(b.descriptors, cv::RNG::UNIFORM, 0, 256);
  a.norm = b.norm = cv::NORM_HAMMING;
  EXPECT_EQ(DescriptorDistance(a, 3, b, 7), cv::norm(a.descriptors.row(3), b.descriptors.row(7), cv::NORM_HAMMING));
}

// SIFT's descriptors are whole numbers 0..255: the matrix is OpenCV's to the bit, whatever the
// path (16-bit dot products with VNNI, float differences with AVX-512, OpenCV's elsewhere), for
// rows that fill whole vectors and rows that do not (37 of b's: two blocks of 16 and 5).
TEST(SquaredDistanceMatrix, IsCvBatchDistancesToTheBit) {
  cv::RNG rng(5);
  Features a, b;
  for (auto [f, rows] : {std::pair<Features*, int>{&a, 45}, {&b, 37}}) {
    cv::Mat bytes(rows, 128, CV_8U);
    rng.fill(bytes, cv::RNG::UNIFORM, 0, 256);
    bytes.row(0).setTo(255);  // the largest distances: 128 x 255^2, under 2^24
    bytes.convertTo(f->descriptors, CV_32F);
  }
  b.descriptors.row(1).setTo(0);
  cv::Mat theirs;
  cv::batchDistance(a.descriptors, b.descriptors, theirs, CV_32F, cv::noArray(), cv::NORM_L2SQR);
  const cv::Mat ours = SquaredDistanceMatrix(a, b);
  ASSERT_EQ(ours.size(), theirs.size());
  EXPECT_EQ(cv::norm(ours, theirs, cv::NORM_INF), 0.0);
  EXPECT_EQ(ours.at<float>(0, 1), 128.f * 255 * 255);
  // Entries that are not whole numbers (not SIFT's): the float path, OpenCV's to rounding.
  a.descriptors.row(3).copyTo(b.descriptors.row(2));
  a.descriptors.at<float>(3, 7) += 0.25f;
  cv::batchDistance(a.descriptors, b.descriptors, theirs, CV_32F, cv::noArray(), cv::NORM_L2SQR);
  EXPECT_LE(cv::norm(SquaredDistanceMatrix(a, b), theirs, cv::NORM_INF), 1e-3);
  EXPECT_EQ(SquaredDistanceMatrix(a, b).at<float>(3, 2), 0.0625f);
}

// The ratio test and the mutual-best check as one row and one column after another would make
// them, ties included: descriptors of a few small values tie often, and the matrix's widths are
// not whole vectors of 16.
TEST(MatchFeatures, EqualsTheMatchesOfAScanInOrderTiesIncluded) {
  cv::RNG rng(11);
  for (auto [rows_a, rows_b] : {std::pair<int, int>{2, 2}, {5, 17}, {31, 16}, {40, 37}, {120, 200}}) {
    Features a, b;
    for (auto [f, rows, y] : {std::tuple<Features*, int, float>{&a, rows_a, 0.f}, {&b, rows_b, 1.f}}) {
      cv::Mat bytes(rows, 128, CV_8U);
      rng.fill(bytes, cv::RNG::UNIFORM, 0, 3);
      bytes.convertTo(f->descriptors, CV_32F);
      for (int i = 0; i < rows; ++i) f->points.emplace_back(float(i), y);
    }
    // Rows alike: columns whose smallest is in two rows, and (in b) rows tied for a's nearest.
    for (int i = 0; i + 1 < rows_a; i += 3) a.descriptors.row(i).copyTo(a.descriptors.row(i + 1));
    for (int j = 5; j + 1 < rows_b; j += 7) b.descriptors.row(j).copyTo(b.descriptors.row(j + 1));
    for (bool cross : {true, false}) {
      FeatureOptions o;
      o.cross_check = cross;
      o.ratio = 0.95;
      cv::Mat d;
      cv::batchDistance(a.descriptors, b.descriptors, d, CV_32F, cv::noArray(), cv::NORM_L2SQR);
      std::vector<std::pair<float, float>> want;
      for (int i = 0; i < d.rows; ++i) {
        float d1 = FLT_MAX, d2 = FLT_MAX;
        int j1 = -1;
        for (int j = 0; j < d.cols; ++j) {
          const float v = d.at<float>(i, j);
          if (v < d1) d2 = d1, d1 = v, j1 = j;
          else if (v < d2) d2 = v;
        }
        if (j1 < 0 || !(d1 < float(o.ratio * o.ratio) * d2)) continue;
        int first = 0;  // the first row holding column j1's smallest
        for (int r = 1; r < d.rows; ++r)
          if (d.at<float>(r, j1) < d.at<float>(first, j1)) first = r;
        if (cross && first != i) continue;
        want.emplace_back(float(i), float(j1));
      }
      const Matches got = MatchFeatures(a, b, o);
      std::vector<std::pair<float, float>> pairs;
      for (size_t k = 0; k < got.from.size(); ++k) pairs.emplace_back(got.from[k].x, got.to[k].x);
      EXPECT_EQ(pairs, want) << rows_a << " x " << rows_b << (cross ? ", cross-checked" : "");
    }
  }
}

// Descriptors as stored (bytes) give the distances, the distance of a pair and the matches of
// the same numbers in float, to the bit.
TEST(MatchFeatures, BytesAreMatchedAsTheirFloats) {
  cv::RNG rng(3);
  Features fa, fb, ba, bb;
  for (auto [f, b, rows] : {std::tuple<Features*, Features*, int>{&fa, &ba, 83}, {&fb, &bb, 61}}) {
    cv::Mat bytes(rows, 128, CV_8U);
    rng.fill(bytes, cv::RNG::UNIFORM, 0, 60);
    bytes.convertTo(f->descriptors, CV_32F);
    b->descriptors = bytes;
    for (int i = 0; i < rows; ++i) f->points.emplace_back(float(i), float(rows));
    b->points = f->points;
  }
  // Some of b near some of a: matches that pass the ratio test.
  for (int i = 0; i < 20; ++i) {
    ba.descriptors.row(i).copyTo(bb.descriptors.row(2 * i));
    bb.descriptors.at<uchar>(2 * i, i) = uchar(bb.descriptors.at<uchar>(2 * i, i) + 3);
    bb.descriptors.row(2 * i).convertTo(fb.descriptors.row(2 * i), CV_32F);
  }
  EXPECT_EQ(cv::norm(SquaredDistanceMatrix(ba, bb), SquaredDistanceMatrix(fa, fb), cv::NORM_INF), 0.0);
  for (int i = 0; i < 83; i += 7)
    for (int j = 0; j < 61; j += 5) ASSERT_EQ(DescriptorDistance(ba, i, bb, j), DescriptorDistance(fa, i, fb, j));
  const Matches from_bytes = MatchFeatures(ba, bb, FeatureOptions()), from_floats = MatchFeatures(fa, fb, FeatureOptions());
  EXPECT_GE(from_floats.from.size(), 15u);
  EXPECT_EQ(from_bytes.from, from_floats.from);
  EXPECT_EQ(from_bytes.to, from_floats.to);
}

}  // namespace
}  // namespace rolamos
