#include "engine/preprocess.h"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "synth/seafloor_texture.h"
#include "test_support.h"

namespace rolamos {
namespace {

using test::ErrorOf;

TEST(Calibration, ReadsOpenCvFilesAndNamesBadFields) {
  test::ScratchDir dir;
  {
    cv::FileStorage fs(dir / "cam.yml", cv::FileStorage::WRITE);
    fs << "image_width" << 640 << "image_height" << 480;
    fs << "camera_matrix" << cv::Mat(cv::Matx33d(500, 0, 320, 0, 500, 240, 0, 0, 1));
    fs << "distortion_coefficients" << cv::Mat(cv::Matx<double, 1, 5>(-0.2, 0.05, 0, 0, 0));
  }
  Calibration c = ReadCalibration(dir / "cam.yml");
  EXPECT_EQ(c.image_size, cv::Size(640, 480));
  EXPECT_EQ(c.distortion.total(), 5u);
  {
    cv::FileStorage fs(dir / "bad.json", cv::FileStorage::WRITE);
    fs << "camera_matrix" << cv::Mat(cv::Matx22d(1, 0, 0, 1));
  }
  EXPECT_NE(ErrorOf([&] { ReadCalibration(dir / "bad.json"); }).find("camera_matrix"), std::string::npos);
  {
    cv::FileStorage fs(dir / "bad2.yml", cv::FileStorage::WRITE);
    fs << "camera_matrix" << cv::Mat(cv::Matx33d(500, 0, 320, 0, 500, 240, 0, 0, 1));
    fs << "distortion_coefficients" << cv::Mat(cv::Matx<double, 1, 3>(1, 2, 3));
  }
  EXPECT_NE(ErrorOf([&] { ReadCalibration(dir / "bad2.yml"); }).find("3 numbers"), std::string::npos);
  std::ofstream(dir / "junk.yml") << "%YAML:1.0\ncamera_matrix: [1, 2\n";
  EXPECT_NE(ErrorOf([&] { ReadCalibration(dir / "junk.yml"); }).find("junk.yml"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { ReadCalibration(dir / "none.yml"); }).find("no such"), std::string::npos);
  // A calibration for another frame size is refused at the first frame.
  PreprocessOptions o;
  o.calibration = dir / "cam.yml";
  Preprocessor p(o);
  EXPECT_NE(ErrorOf([&] { p.Spatial(cv::Mat(100, 100, CV_8UC3, cv::Scalar::all(0))); }).find("640x480"),
            std::string::npos);
}

// Undistortion makes a new image: it wrote over the caller's frame, and the frames the overlay
// search had undistorted were undistorted again by the engine (a calibrated run's first 24
// frames, 24 px off). Its camera has square pixels, as the engine's cameras have one focal length.
TEST(Preprocess, UndistortionLeavesTheFrameAloneAndHasSquarePixels) {
  test::ScratchDir dir;
  cv::FileStorage fs(dir / "cal.yml", cv::FileStorage::WRITE);
  fs << "image_width" << 160 << "image_height" << 120;
  fs << "camera_matrix" << cv::Mat(cv::Matx33d(80, 0, 79.5, 0, 80, 59.5, 0, 0, 1));
  fs << "distortion_coefficients" << (cv::Mat_<double>(1, 4) << -0.05, 0, 0, 0);
  fs.release();
  PreprocessOptions o;
  o.calibration = dir / "cal.yml";
  Preprocessor pre(o);
  cv::Mat frame(120, 160, CV_8UC3);
  cv::randu(frame, 1, 255);
  const cv::Mat before = frame.clone();
  const cv::Mat out = pre.Undistort(frame);
  EXPECT_EQ(cv::norm(frame, before, cv::NORM_INF), 0) << "the caller's frame was written over";
  EXPECT_GT(cv::norm(out, before, cv::NORM_INF), 0);
  const cv::Matx33d K = pre.CameraMatrix(frame.size());
  EXPECT_EQ(K(0, 0), K(1, 1));
  // No black band at a border: at most a few corner pixels (OpenCV's alpha 0 is found on a grid).
  cv::Mat grey;
  cv::cvtColor(out, grey, cv::COLOR_BGR2GRAY);
  EXPECT_LE(int(grey.total()) - cv::countNonZero(grey), int(grey.total()) / 1000);
}

TEST(Preprocess, TemporalTermRemovesParticlesWithoutSmearingTexture) {
  cv::Mat ground = RenderSeafloor(0, 0, 700, 500);
  const cv::Matx33d cur_to_prev(1, 0, 12, 0, 1, 7, 0, 0, 1);  // the camera moved
  cv::Mat current = ground(cv::Rect(12, 7, 640, 480)).clone();
  cv::Mat previous = ground(cv::Rect(0, 0, 640, 480)).clone();
  cv::Mat noisy = current.clone();
  cv::Mat noise(noisy.size(), CV_16SC3);
  cv::randn(noise, 0, 4);
  cv::Mat n16;
  noisy.convertTo(n16, CV_16SC3);
  n16 += noise;
  n16.convertTo(noisy, CV_8UC3);
  cv::circle(noisy, cv::Point(300, 200), 4, cv::Scalar(255, 255, 255), cv::FILLED);  // a particle
  PreprocessOptions o;
  Preprocessor p(o);
  cv::Mat out = p.Temporal(noisy, previous, cur_to_prev);
  const cv::Rect inner(20, 20, 600, 440);
  EXPECT_GT(test::Psnr(out(inner), current(inner)), test::Psnr(noisy(inner), current(inner)) + 0.5);
  // The particle disagrees with the previous frame: it is kept as it is, not half-blended.
  EXPECT_EQ(out.at<cv::Vec3b>(200, 300), cv::Vec3b(255, 255, 255));
}

// The temporal term's arithmetic, pixel by pixel, against which the filter (vectorised where the
// weights allow) is checked to the grey level.
cv::Mat TemporalByThePixel(const cv::Mat& current, const cv::Mat& previous, double weight, double tolerance) {
  cv::Mat out(current.size(), CV_8UC3);
  for (int y = 0; y < current.rows; ++y)
    for (int x = 0; x < current.cols; ++x) {
      const cv::Vec3b c = current.at<cv::Vec3b>(y, x), p = previous.at<cv::Vec3b>(y, x);
      int d = 0;
      for (int k = 0; k < 3; ++k) d = std::max(d, std::abs(int(c[k]) - int(p[k])));
      const int w = int(std::lround(256.0 * weight * std::max(0.0, 1.0 - d / tolerance)));
      for (int k = 0; k < 3; ++k) out.at<cv::Vec3b>(y, x)[k] = uchar(c[k] + (((int(p[k]) - int(c[k])) * w + 128) >> 8));
    }
  return out;
}

TEST(Preprocess, TemporalTermIsTheSameArithmeticAtAnyWidthAndSetting) {
  cv::RNG rng(3);
  for (const int width : {2, 6, 7, 8, 17, 18, 642}) {
    cv::Mat current(9, width, CV_8UC3), previous(9, width, CV_8UC3), step(9, width, CV_8UC3);
    rng.fill(current, cv::RNG::UNIFORM, 0, 256);
    // Differences from 0 to past the tolerance, both ways, and a few far past it.
    rng.fill(step, cv::RNG::UNIFORM, 0, 24);
    cv::add(current, step, previous);
    previous.row(4).setTo(cv::Scalar(0, 255, 7));
    for (const auto& [weight, tolerance] : {std::pair{0.5, 16.0}, {0.9, 16.0}, {0.3, 9.0}, {0.5, 40.0}}) {
      PreprocessOptions o;
      o.temporal_weight = weight;
      o.temporal_tolerance = tolerance;
      // The warp leaves the last row and column alone (their bilinear taps pass the edge).
      const cv::Rect inner(0, 0, width - 1, 8);
      const cv::Mat out = Preprocessor(o).Temporal(current, previous, cv::Matx33d::eye());
      EXPECT_EQ(cv::norm(out(inner), TemporalByThePixel(current, previous, weight, tolerance)(inner), cv::NORM_INF), 0)
          << "width " << width << ", weight " << weight << ", tolerance " << tolerance;
      const cv::Mat back = Preprocessor(o).Temporal(previous, current, cv::Matx33d::eye());
      EXPECT_EQ(cv::norm(back(inner), TemporalByThePixel(previous, current, weight, tolerance)(inner), cv::NORM_INF), 0);
    }
  }
}

}  // namespace
}  // namespace rolamos
