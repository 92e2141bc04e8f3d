#include "engine/preprocess.h"

#include <array>
#include <cmath>
#include <filesystem>

#include <immintrin.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "engine/bilateral_filter.h"
#include "engine/bilinear_warp.h"
#include "engine/grey.h"
#include "rolamos/error.hpp"

namespace rolamos {
namespace {

// The temporal term's weight of the previous frame (x 256) by the pixel's largest channel
// difference.
using TemporalWeights = std::array<int, 256>;

// Pixels [begin, end) of a row: each moved towards the previous frame's by its weight.
void BlendPixels(const uchar* c, const uchar* p, uchar* o, int begin, int end, const TemporalWeights& lut) {
  for (int x = begin; x < end; ++x) {
    int d = 0;
    for (int k = 0; k < 3; ++k) d = std::max(d, std::abs(int(c[3 * x + k]) - int(p[3 * x + k])));
    const int w = lut[size_t(d)];
    for (int k = 0; k < 3; ++k)
      o[3 * x + k] = static_cast<uchar>(c[3 * x + k] + (((int(p[3 * x + k]) - int(c[3 * x + k])) * w + 128) >> 8));
  }
}

// The vector blend holds the weights in one 16-entry byte table: weights up to 255, none past a
// difference of 15 (the default tolerance, 16 grey levels, qualifies).
bool VectorBlendApplies(const TemporalWeights& lut) {
  static const bool cpu = __builtin_cpu_supports("sse4.1");
  for (int d = 0; d < 256; ++d)
    if (lut[size_t(d)] < 0 || lut[size_t(d)] > 255 || (d >= 16 && lut[size_t(d)] != 0)) return false;
  return cpu;
}

// BlendPixels five pixels (15 bytes) at a time, the same integers: 3.3 -> 0.65 ms a 1292 x 964
// frame on one core. Returns the pixels done; the rest of the row (the last five or more) is left to
// BlendPixels, so that no 16-byte load or store passes the row's end.
__attribute__((target("sse4.1"))) int BlendRowSse(const uchar* c, const uchar* p, uchar* o, int width,
                                                  const TemporalWeights& lut) {
  alignas(16) uchar table[16];
  for (int d = 0; d < 16; ++d) table[d] = static_cast<uchar>(lut[size_t(d)]);
  const __m128i weights = _mm_load_si128(reinterpret_cast<const __m128i*>(table));
  // Each byte of a pixel gets the other two of its pixel's bytes (byte 15 is the next pixel's).
  const __m128i next = _mm_setr_epi8(1, 2, 0, 4, 5, 3, 7, 8, 6, 10, 11, 9, 13, 14, 12, 15);
  const __m128i after = _mm_setr_epi8(2, 0, 1, 5, 3, 4, 8, 6, 7, 11, 9, 10, 14, 12, 13, 15);
  const __m128i fifteen = _mm_set1_epi8(15), high = _mm_set1_epi8(char(0x80)), zero = _mm_setzero_si128();
  const __m128i round = _mm_set1_epi16(128);
  int x = 0;
  for (; 3 * x + 16 <= 3 * (width - 1); x += 5) {
    const __m128i cv = _mm_loadu_si128(reinterpret_cast<const __m128i*>(c + 3 * x));
    const __m128i pv = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 3 * x));
    const __m128i diff = _mm_or_si128(_mm_subs_epu8(cv, pv), _mm_subs_epu8(pv, cv));
    const __m128i d = _mm_max_epu8(diff, _mm_max_epu8(_mm_shuffle_epi8(diff, next), _mm_shuffle_epi8(diff, after)));
    // Differences past 15 index with the top bit set: weight 0.
    const __m128i past = _mm_cmpeq_epi8(_mm_max_epu8(d, _mm_set1_epi8(16)), d);
    const __m128i w = _mm_shuffle_epi8(weights, _mm_or_si128(_mm_and_si128(d, fifteen), _mm_and_si128(past, high)));
    auto half = [&](__m128i c16, __m128i p16, __m128i w16) {
      const __m128i moved = _mm_mullo_epi16(_mm_sub_epi16(p16, c16), w16);
      return _mm_add_epi16(c16, _mm_srai_epi16(_mm_add_epi16(moved, round), 8));
    };
    const __m128i lo = half(_mm_cvtepu8_epi16(cv), _mm_cvtepu8_epi16(pv), _mm_cvtepu8_epi16(w));
    const __m128i hi = half(_mm_unpackhi_epi8(cv, zero), _mm_unpackhi_epi8(pv, zero), _mm_unpackhi_epi8(w, zero));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(o + 3 * x), _mm_packus_epi16(lo, hi));
  }
  return x;
}

}  // namespace

Calibration ReadCalibration(const std::string& path) {
  if (!std::filesystem::exists(path)) Fail(path, "no such calibration file");
  cv::FileStorage fs;
  try {
    if (!fs.open(path, cv::FileStorage::READ)) Fail(path, "is not a YAML, XML or JSON file OpenCV reads");
  } catch (const cv::Exception& e) {
    Fail(path, std::string("cannot be parsed: ") + e.err);
  }
  Calibration c;
  cv::Mat K, D;
  try {
    fs["camera_matrix"] >> K;
    fs["distortion_coefficients"] >> D;
    int w = 0, h = 0;
    fs["image_width"] >> w;
    fs["image_height"] >> h;
    c.image_size = cv::Size(w, h);
  } catch (const cv::Exception& e) {
    Fail(path, std::string("has a malformed field: ") + e.err);
  }
  if (K.rows != 3 || K.cols != 3)
    Fail(path, "field \"camera_matrix\" must be a 3x3 matrix");
  K.convertTo(K, CV_64F);
  c.camera_matrix = cv::Matx33d(K);
  const auto& k = c.camera_matrix;
  if (!(k(0, 0) > 0 && k(1, 1) > 0 && k(2, 2) == 1 && k(1, 0) == 0 && k(2, 0) == 0 && k(2, 1) == 0))
    Fail(path, "field \"camera_matrix\" is not a camera matrix (fx, fy > 0, last row 0 0 1)");
  if (!D.empty()) {
    const int n = static_cast<int>(D.total());
    if (n != 4 && n != 5 && n != 8 && n != 12 && n != 14)
      Fail(path, "field \"distortion_coefficients\" has " + std::to_string(n) +
                     " numbers (4, 5, 8, 12 or 14 expected)");
    D.reshape(1, 1).convertTo(c.distortion, CV_64F);
  }
  return c;
}

bool PreprocessOptions::IsValid(std::string* error) const {
  if (!(fov_deg > 5 && fov_deg < 170)) {
    *error = "field of view " + std::to_string(fov_deg) + " degrees is outside 5..170";
    return false;
  }
  if (bilateral_diameter < 1 || bilateral_diameter > 25 || !(bilateral_sigma_color > 0) ||
      !(bilateral_sigma_space > 0)) {
    *error = "bilateral filter settings are out of range";
    return false;
  }
  if (!(temporal_weight >= 0 && temporal_weight < 1) || !(temporal_tolerance > 0)) {
    *error = "temporal filter weight must be in [0, 1) and its tolerance positive";
    return false;
  }
  if (despeckle_px < 0 || despeckle_px > 10 || !(speck_contrast > 0)) {
    *error = "despeckle radius " + std::to_string(despeckle_px) + " is outside 0..10 pixels";
    return false;
  }
  if (!(clahe_clip > 0)) {
    *error = "CLAHE clip limit must be positive";
    return false;
  }
  return true;
}

Preprocessor::Preprocessor(const PreprocessOptions& options) : options_(options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("preprocessing", error);
  if (options.calibration == "auto")
    Fail("calibration \"auto\"", "is estimated from the first frames by MosaicInput, not by the pre-processor");
  if (!options.calibration.empty()) calibration_ = ReadCalibration(options.calibration);
  // Coefficients all zero (as --calibration auto writes for a lens without distortion, and as
  // hand-written files often hold): the frames are used as they are, not resampled through a map
  // that moves nothing and blurs a little.
  if (calibration_ && !calibration_->distortion.empty() && cv::countNonZero(calibration_->distortion) == 0)
    calibration_->distortion = cv::Mat();
}

cv::Mat Preprocessor::Spatial(const cv::Mat& frame) { return Bilateral(Undistort(frame)); }

cv::Mat Preprocessor::Bilateral(const cv::Mat& frame) const {
  if (!options_.bilateral) return frame;
  cv::Mat smoothed;
  BilateralFilter(frame, smoothed, options_.bilateral_diameter, options_.bilateral_sigma_color,
                  options_.bilateral_sigma_space);
  return smoothed;
}

cv::Mat Preprocessor::Undistort(const cv::Mat& frame) {
  cv::Mat out = frame;
  if (calibration_) {
    if (calibration_->image_size.area() > 0 && calibration_->image_size != frame.size())
      Fail(options_.calibration, "is for " + std::to_string(calibration_->image_size.width) + "x" +
                                     std::to_string(calibration_->image_size.height) +
                                     " frames, this frame is " + std::to_string(frame.cols) + "x" +
                                     std::to_string(frame.rows));
    cv::Mat map_x, map_y;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (map_x_.empty() || map_x_.size() != frame.size()) {
        // alpha 0: the undistorted frame holds only valid pixels (no black corners to blend).
        rectified_K_ = calibration_->distortion.empty()
                           ? calibration_->camera_matrix
                           : cv::Matx33d(cv::getOptimalNewCameraMatrix(
                                 cv::Mat(calibration_->camera_matrix), calibration_->distortion,
                                 frame.size(), 0.0));
        // OpenCV fills the frame in each axis on its own: pixels 3 % taller than wide for a
        // 90-degree lens, which the engine's cameras (one focal length) cannot hold. Square pixels,
        // zoomed by the larger: still every pixel valid.
        const double f = std::max(rectified_K_(0, 0), rectified_K_(1, 1));
        rectified_K_(0, 0) = rectified_K_(1, 1) = f;
        cv::initUndistortRectifyMap(cv::Mat(calibration_->camera_matrix), calibration_->distortion,
                                    cv::Mat(), cv::Mat(rectified_K_), frame.size(), CV_16SC2,
                                    map_x_, map_y_);
      }
      map_x = map_x_;
      map_y = map_y_;
    }
    // Into a new image: `out` shares the caller's pixels, and remap writes over its destination
    // when the size fits. The overlay search undistorted the frames it held in place that way,
    // and the engine then undistorted them again (the first 24 frames of a calibrated run: 24 px).
    if (!calibration_->distortion.empty()) {
      cv::Mat undistorted;
      cv::remap(frame, undistorted, map_x, map_y, cv::INTER_LINEAR);
      out = undistorted;
    }
  }
  return out;
}

cv::Mat Preprocessor::DetectionImage(const cv::Mat& frame, double scale, cv::Mat* usable) const {
  cv::Mat gray;
  if (frame.channels() == 3) BgrToGrey(frame, gray);
  else gray = frame;
  if (scale < 1.0) {
    cv::Mat small;
    ResizeArea(gray, small, scale);
    gray = small;
  }
  if (usable) {
    usable->release();
    if (options_.despeckle_px > 0) {
      // Specks: what a small opening removes and stands out from its surroundings.
      const int d = 2 * options_.despeckle_px + 1;
      const cv::Mat disc = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(d, d));
      cv::Mat tophat;
      cv::morphologyEx(gray, tophat, cv::MORPH_TOPHAT, disc);
      cv::Mat specks = tophat > options_.speck_contrast;
      cv::dilate(specks, specks, disc);
      *usable = specks == 0;
    }
  }
  if (!options_.clahe) return gray;
  // Tiles of about 64 pixels whatever the detection image's size.
  const cv::Size tiles(std::max(2, gray.cols / 64), std::max(2, gray.rows / 64));
  auto clahe = cv::createCLAHE(options_.clahe_clip, tiles);
  cv::Mat out;
  clahe->apply(gray, out);
  return out;
}

cv::Mat Preprocessor::Temporal(const cv::Mat& current, const cv::Mat& previous,
                               const cv::Matx33d& current_to_previous) const {
  if (!options_.temporal || previous.empty()) return current;
  // Where the previous frame does not reach, the current pixel stays as it is: warping onto a
  // copy of the current frame with a transparent border makes those pixels agree with it.
  cv::Mat prev_here = current.clone();
  WarpInside(previous, current_to_previous, prev_here);
  // Robust weight: full where the frames agree, none where they differ by more than the
  // tolerance (a particle, a fish, a misregistration). One 8-bit pass with a weight table.
  TemporalWeights lut;
  for (int d = 0; d < 256; ++d)
    lut[size_t(d)] = static_cast<int>(std::lround(
        256.0 * options_.temporal_weight * std::max(0.0, 1.0 - d / options_.temporal_tolerance)));
  const bool vector = VectorBlendApplies(lut);
  cv::Mat out(current.size(), CV_8UC3);
  cv::parallel_for_(cv::Range(0, current.rows), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const uchar* c = current.ptr(y);
      const uchar* p = prev_here.ptr(y);
      uchar* o = out.ptr(y);
      const int done = vector ? BlendRowSse(c, p, o, current.cols, lut) : 0;
      BlendPixels(c, p, o, done, current.cols, lut);
    }
  });
  return out;
}

cv::Matx33d Preprocessor::CameraMatrix(cv::Size size) const {
  if (calibration_) {
    std::lock_guard<std::mutex> lock(mutex_);
    return map_x_.empty() ? calibration_->camera_matrix : rectified_K_;
  }
  // Without calibration: the horizontal field of view given (70 degrees unless told), centred.
  const double f = 0.5 * size.width / std::tan(0.5 * options_.fov_deg * CV_PI / 180);
  return cv::Matx33d(f, 0, (size.width - 1) / 2.0, 0, f, (size.height - 1) / 2.0, 0, 0, 1);
}

}  // namespace rolamos
