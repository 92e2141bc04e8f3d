#include "objects/dihedral.h"

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "objects/bow_features.h"
#include "test_support.h"

namespace rolamos {
namespace {

// The image as the transform sees it: quarter turns clockwise, then the mirror.
cv::Mat Turned(const cv::Mat& image, int t) {
  cv::Mat out = image.clone();
  for (int k = 0; k < (t & 3); ++k) cv::rotate(out, out, cv::ROTATE_90_CLOCKWISE);
  if (t & 4) cv::flip(out, out, 1);
  return out;
}

cv::Mat Texture() {
  cv::Mat image(96, 96, CV_8UC3);
  cv::RNG rng(5);
  rng.fill(image, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(image, image, cv::Size(), 2.5);
  cv::ellipse(image, {40, 50}, {22, 9}, 30, 0, 360, {250, 200, 40}, -1);
  return image;
}

// The permutations are exact: a SIFT descriptor computed on the turned image, at the place its
// patch moved to, equals the permuted descriptor of the original (and so for colour statistics).
TEST(DihedralTransform, PermutedDescriptorsEqualDescriptorsOfTheTurnedImage) {
  const cv::Mat image = Texture();
  cv::Mat gray;
  cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  std::vector<cv::KeyPoint> here;
  for (int y = 16; y <= 80; y += 8)
    for (int x = 16; x <= 80; x += 8) here.emplace_back(static_cast<float>(x), static_cast<float>(y), 4.f, 0.f);
  cv::Mat original;
  cv::SIFT::create()->compute(gray, here, original);
  const cv::Mat colour = ColourStatistics(image, here);
  for (int t = 0; t < 8; ++t) {
    const DihedralTransform turn(t);
    std::vector<cv::KeyPoint> there = here;
    for (auto& k : there) k.pt = turn.Point(k.pt + cv::Point2f(0.5f, 0.5f), 96) - cv::Point2f(0.5f, 0.5f);
    cv::Mat turned_gray;
    cv::cvtColor(Turned(image, t), turned_gray, cv::COLOR_BGR2GRAY);
    cv::Mat expected;
    cv::SIFT::create()->compute(turned_gray, there, expected);
    ASSERT_EQ(expected.rows, original.rows);
    const cv::Mat got = turn.Sift(original);
    EXPECT_LT(cv::norm(got, expected, cv::NORM_L2) / cv::norm(expected), 1e-3) << "transform " << t;  // float rounding
    if (t != 0) EXPECT_GT(cv::norm(original, expected, cv::NORM_L2) / cv::norm(expected), 0.1) << "transform " << t;
    EXPECT_LT(cv::norm(turn.ColourStatistics(colour), ColourStatistics(Turned(image, t), there), cv::NORM_L2) /
                  cv::norm(colour), 1e-5)
        << "transform " << t;
  }
}

// Described in all eight orientations, an image and its turned copy give one description.
TEST(DihedralTransform, EncoderWithEightOrientationsIgnoresTurnsAndMirrors) {
  ObjectFeatureOptions o;
  o.image_size = 96;
  o.patch_sizes = {12, 24};
  o.encoding = "fisher";
  o.pca_dims = 16;
  o.colour_statistics = true;
  o.colour_pca_dims = 16;
  o.spatial_coordinates = true;
  const cv::Mat image = Texture();
  const SampleView view = DescribeViews(image, o).front();
  const cv::Mat places = PlaceColumns(view.where, o.image_size);
  const FisherCodebook words = BuildFisherCodebook(view.descriptors, 4, 16, 1, places);
  const FisherCodebook colours = BuildFisherCodebook(view.colour, 4, 16, 1, places);
  for (int orientations : {1, 8}) {
    o.orientations = orientations;
    const BowEncoder encoder(o, words.gmm, words.pca, colours);
    const cv::Mat a = encoder.Encode(image), b = encoder.Encode(Turned(image, 5));
    const double cosine = a.dot(b) / (cv::norm(a) * cv::norm(b));
    if (orientations == 8)
      EXPECT_GT(cosine, 0.98);
    else
      EXPECT_LT(cosine, 0.9);
  }
}

}  // namespace
}  // namespace rolamos
