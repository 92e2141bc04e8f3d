#include "rolamos/survey.hpp"

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "rolamos/error.hpp"
#include "test_support.h"
#include "util/homography.h"

namespace rolamos {
namespace {

SurveyOptions Clean(const std::string& path) {
  SurveyOptions o;
  o.frame_width = 480;
  o.frame_height = 360;
  o.focal_px = 420;
  o.frames = 24;
  o.path = path;
  o.attenuation = o.vignetting = o.backscatter = o.noise = 0;
  o.particles = 0;
  o.jpeg_quality = 0;  // PNG: exact pixels
  return o;
}

// The ground truth is right when frame i, warped by world->frame_j * frame_i->world, lands on
// frame j pixel for pixel where they overlap.
TEST(Synth, GroundTruthHomographiesRelateFrames) {
  for (const std::string path : {"lawnmower", "spiral", "random", "inspect"}) {
    test::ScratchDir dir;
    Survey s = WriteSurvey(Clean(path), dir.path());
    ASSERT_EQ(s.frames.size(), 24u);
    Survey back = ReadSurvey(dir.path());
    ASSERT_EQ(back.frames.size(), 24u);
    for (int i : {0, 5, 11}) {
      const int j = i + 1;
      cv::Mat fi = cv::imread(dir / back.frames[i].file), fj = cv::imread(dir / back.frames[j].file);
      const cv::Matx33d H = ToMatx(back.frames[j].frame_to_world).inv() * ToMatx(back.frames[i].frame_to_world);
      cv::Mat warped, mask;
      cv::warpPerspective(fi, warped, cv::Mat(H), fj.size());
      cv::warpPerspective(cv::Mat(fi.size(), CV_8U, cv::Scalar(255)), mask, cv::Mat(H), fj.size(),
                          cv::INTER_NEAREST);
      cv::erode(mask, mask, cv::Mat(), cv::Point(-1, -1), 3);
      ASSERT_GT(cv::countNonZero(mask), fj.total() / 5) << path << " " << i;
      cv::Mat diff;
      cv::absdiff(warped, fj, diff);
      const double mean_abs = cv::mean(diff, mask)[1];
      EXPECT_LT(mean_abs, 4.0) << path << " frames " << i << "," << j;
    }
  }
}

// Through a distorting lens (--k1) the frames relate by the ground truth's homographies once the
// lens is taken out with the survey's own camera matrix; as they come they do not.
TEST(Synth, ALensDistortsTheFramesAndTheGroundTruthStaysThePinholes) {
  test::ScratchDir dir;
  SurveyOptions o = Clean("lawnmower");
  o.k1 = -0.15;
  const Survey s = WriteSurvey(o, dir.path());
  const cv::Mat D = (cv::Mat_<double>(1, 4) << o.k1, 0, 0, 0);
  for (int i : {3, 9}) {
    const int j = i + 1;
    cv::Mat raw_i = cv::imread(dir / s.frames[i].file), raw_j = cv::imread(dir / s.frames[j].file), fi, fj;
    cv::undistort(raw_i, fi, cv::Mat(s.camera_matrix), D, cv::Mat(s.camera_matrix));
    cv::undistort(raw_j, fj, cv::Mat(s.camera_matrix), D, cv::Mat(s.camera_matrix));
    const cv::Matx33d H = ToMatx(s.frames[j].frame_to_world).inv() * ToMatx(s.frames[i].frame_to_world);
    auto mean_difference = [&](const cv::Mat& a, const cv::Mat& b) {
      cv::Mat warped, mask, diff;
      cv::warpPerspective(a, warped, cv::Mat(H), b.size());
      cv::warpPerspective(cv::Mat(a.size(), CV_8U, cv::Scalar(255)), mask, cv::Mat(H), b.size(), cv::INTER_NEAREST);
      cv::erode(mask, mask, cv::Mat(), cv::Point(-1, -1), 3);
      cv::absdiff(warped, b, diff);
      return cv::mean(diff, mask)[1];
    };
    EXPECT_LT(mean_difference(fi, fj), 4.0) << "frames " << i << "," << j;
    EXPECT_GT(mean_difference(raw_i, raw_j), 8.0) << "frames " << i << "," << j << ": no distortion seen";
  }
}

// An ROV's approach: the first frames come down from three times the altitude at a steady speed;
// the ground is drawn three times smaller in the first frame than after the descent, and the
// water takes more of its red.
TEST(Synth, ADescentComesDownToTheAltitudeAndDimsTheRedFromHigher) {
  test::ScratchDir dir;
  SurveyOptions o = Clean("lawnmower");
  o.frames = 12;
  o.descent_from = 3;
  o.descent_frames = 6;
  const Survey s = WriteSurvey(o, dir.path());
  auto scale = [&](int i) { return CentreScale(ToMatx(s.frames[size_t(i)].frame_to_world), s.frame_size); };
  EXPECT_NEAR(scale(0) / scale(11), 3.0, 0.2);  // texture pixels per frame pixel
  EXPECT_NEAR(scale(3) / scale(11), 2.0, 0.15);  // half way down
  EXPECT_NEAR(scale(6) / scale(11), 1.0, 0.1);
  const cv::Scalar high = cv::mean(cv::imread(dir / s.frames[0].file)), low = cv::mean(cv::imread(dir / s.frames[11].file));
  EXPECT_LT(high[2] / high[0], low[2] / low[0]) << "red over blue";
  o.descent_from = 6;
  EXPECT_THROW(WriteSurvey(o, dir.path()), Error);
}

// Motion blur smears a frame along the camera's motion, not across it, and leaves its pose (the
// ground truth, the exposure's middle) where it was: the blurred frames still meet each other
// through it as sharp ones do.
TEST(Synth, MotionBlurSmearsAlongTheMotionAndKeepsTheGroundTruth) {
  test::ScratchDir sharp_dir, blurred_dir;
  SurveyOptions o = Clean("lawnmower");
  o.forward_overlap = 0.9;
  o.frames = 8;
  const Survey sharp = WriteSurvey(o, sharp_dir.path());
  o.motion_blur = 0.8;
  const Survey blurred = WriteSurvey(o, blurred_dir.path());
  const int i = 5, j = 6;  // inside the first lane
  for (int k = 0; k < 9; ++k) ASSERT_EQ(sharp.frames[i].frame_to_world[k], blurred.frames[i].frame_to_world[k]);
  const cv::Matx33d H = ToMatx(blurred.frames[j].frame_to_world).inv() * ToMatx(blurred.frames[i].frame_to_world);
  const cv::Vec3d c = H * cv::Vec3d(240, 180, 1);
  cv::Point2d along(c[0] / c[2] - 240, c[1] / c[2] - 180);
  ASSERT_GT(cv::norm(along), 5.0) << "the camera moves between frames " << i << " and " << j;
  along *= 1.0 / cv::norm(along);
  // Mean absolute derivative of the grey frame along and across the motion.
  auto derivatives = [&](const cv::Mat& frame) {
    cv::Mat grey, gx, gy;
    cv::cvtColor(frame, grey, cv::COLOR_BGR2GRAY);
    cv::Sobel(grey, gx, CV_32F, 1, 0);
    cv::Sobel(grey, gy, CV_32F, 0, 1);
    const cv::Mat d_along = gx * along.x + gy * along.y, d_across = gx * -along.y + gy * along.x;
    return std::make_pair(cv::mean(cv::abs(d_along))[0], cv::mean(cv::abs(d_across))[0]);
  };
  const auto [sharp_along, sharp_across] = derivatives(cv::imread(sharp_dir / sharp.frames[i].file));
  const auto [blur_along, blur_across] = derivatives(cv::imread(blurred_dir / blurred.frames[i].file));
  EXPECT_LT(blur_along, 0.6 * sharp_along) << "no smear along the motion";
  EXPECT_GT(blur_across, 0.8 * blur_along) << "smeared across the motion as much as along it";
  EXPECT_GT(blur_across / sharp_across, 1.5 * blur_along / sharp_along);
  // The two blurred frames meet through the ground truth (blur is symmetric about the pose).
  const cv::Mat fi = cv::imread(blurred_dir / blurred.frames[i].file), fj = cv::imread(blurred_dir / blurred.frames[j].file);
  cv::Mat warped, mask, diff;
  cv::warpPerspective(fi, warped, cv::Mat(H), fj.size());
  cv::warpPerspective(cv::Mat(fi.size(), CV_8U, cv::Scalar(255)), mask, cv::Mat(H), fj.size(), cv::INTER_NEAREST);
  cv::erode(mask, mask, cv::Mat(), cv::Point(-1, -1), 3);
  cv::absdiff(warped, fj, diff);
  EXPECT_LT(cv::mean(diff, mask)[1], 2.0);
  o.motion_blur = 1.5;
  EXPECT_THROW(WriteSurvey(o, blurred_dir.path()), Error);
}

TEST(Synth, BadOptionsAreRefused) {
  test::ScratchDir dir;
  SurveyOptions o = Clean("zigzag");
  EXPECT_THROW(WriteSurvey(o, dir.path()), Error);
  o = Clean("lawnmower");
  o.texture = dir / "missing.jpg";
  EXPECT_THROW(WriteSurvey(o, dir.path()), Error);
  o = Clean("lawnmower");
  o.frames = 1;
  EXPECT_THROW(WriteSurvey(o, dir.path()), Error);
}

// The frames also as a video, in each codec asked for: every frame in it, at the frames' size;
// a codec that does not go with the container is refused before anything is written.
TEST(Synth, WritesTheFramesAsAVideoInTheCodecAskedFor) {
  for (const auto& [file, codec] : std::vector<std::pair<std::string, std::string>>{
           {"v.mp4", ""}, {"v.mp4", "h264"}, {"v.avi", "mjpeg"}}) {
    test::ScratchDir dir;
    SurveyOptions o = Clean("lawnmower");
    o.frames = 12;
    o.video = file;
    o.video_codec = codec;
    WriteSurvey(o, dir.path());
    cv::VideoCapture in(dir / file, cv::CAP_FFMPEG);
    ASSERT_TRUE(in.isOpened()) << file << " " << codec;
    const int tag = static_cast<int>(in.get(cv::CAP_PROP_FOURCC));
    const std::string fourcc{char(tag & 255), char((tag >> 8) & 255), char((tag >> 16) & 255), char((tag >> 24) & 255)};
    const std::string expected = codec == "h264" ? "h264" : codec == "mjpeg" ? "mjpg" : "mp4v";
    std::string lower = fourcc;
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    EXPECT_TRUE(lower == expected || (codec == "h264" && lower == "avc1")) << file << " " << codec << ": " << fourcc;
    int n = 0;
    for (cv::Mat f; in.read(f); ++n) ASSERT_EQ(f.size(), cv::Size(480, 360));
    EXPECT_EQ(n, 12) << file << " " << codec;
  }
  SurveyOptions o = Clean("lawnmower");
  o.video = "v.avi";
  o.video_codec = "h264";
  std::string error;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("h264"), std::string::npos);
  o.video_codec = "vp9";
  EXPECT_FALSE(o.IsValid(&error));
}

}  // namespace
}  // namespace rolamos
