#include "engine/features.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>

#include <immintrin.h>

#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "engine/sift_descriptor.h"
#include "engine/sift_detector.h"
#include "engine/sift_pyramid.h"
#include "rolamos/error.hpp"
#include "util/cpu_features.h"

namespace rolamos {

bool FeatureOptions::IsValid(std::string* error) const {
  if (type != "sift" && type != "orb" && type != "akaze") {
    *error = "features \"" + type + "\" are not sift, orb or akaze";
    return false;
  }
  if (max_features < 50) {
    *error = "at least 50 features are needed";
    return false;
  }
  if (!(detect_scale == 0 || (detect_scale > 0.1 && detect_scale <= 1.0))) {
    *error = "detection scale " + std::to_string(detect_scale) + " is not 0 (by frame size) or in (0.1, 1]";
    return false;
  }
  if (!(detect_pixels >= 1e4 && detect_pixels <= 1e8)) {
    *error = "detection image size " + std::to_string(detect_pixels) + " pixels is outside 1e4..1e8";
    return false;
  }
  if (!(contrast_threshold > 0 && contrast_threshold < 0.5)) {
    *error = "SIFT contrast threshold " + std::to_string(contrast_threshold) + " is outside (0, 0.5)";
    return false;
  }
  if (!(ratio > 0.3 && ratio < 1.0)) {
    *error = "ratio test threshold must be in (0.3, 1)";
    return false;
  }
  return true;
}

double FeatureOptions::ScaleFor(cv::Size frame) const {
  if (detect_scale > 0) return detect_scale;
  const double area = std::max(1.0, double(frame.area()));
  return std::clamp(std::sqrt(detect_pixels / area), 0.1, 1.0);
}

FeatureExtractor::FeatureExtractor(const FeatureOptions& options) : options_(options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("features", error);
}

namespace {

// SIFT's layers per octave and base blur (OpenCV's defaults, Lowe's values).
constexpr int kSiftLayers = 3;
constexpr double kSiftSigma = 1.6;

// ORB's or AKAZE's detector, one per call: OpenCV does not promise that one detector may run on
// several threads at once, and creating one costs microseconds. (SIFT is FindSift's.)
cv::Ptr<cv::Feature2D> CreateDetector(const FeatureOptions& options) {
  if (options.type == "orb")
    return cv::ORB::create(options.max_features, 1.2f, 8, 31, 0, 2, cv::ORB::HARRIS_SCORE, 31, 10);
  return cv::AKAZE::create(cv::AKAZE::DESCRIPTOR_MLDB, 0, 3, 0.0008f);
}

// OpenCV (before 4.8's enable_precise_upscale) doubles SIFT's first octave with INTER_LINEAR,
// whose pixel centres sit a quarter pixel off the doubled grid it then reads positions from:
// every keypoint comes out 0.25 px right of and below where it is (opencv/opencv#23123). The
// offset cancels between frames of the same heading and doubles between frames turned 180
// degrees (the next lane of a lawnmower), so it is taken off.
constexpr float kSiftUpscaleBias = 0.25f;

// SIFT keypoints found on `image` halved (where OpenCV's doubled first octave is `image`'s own
// size) and described on `image` at their octave, one up: no octave at twice the size.
std::vector<cv::KeyPoint> DescribeFromHalf(const FeatureOptions& options, const cv::Mat& image, const cv::Mat& mask,
                                           cv::Mat* descriptors) {
  cv::Mat half, half_mask;
  cv::resize(image, half, cv::Size((image.cols + 1) / 2, (image.rows + 1) / 2), 0, 0, cv::INTER_AREA);
  if (!mask.empty()) cv::resize(mask, half_mask, half.size(), 0, 0, cv::INTER_NEAREST);
  SiftOptions sift;
  sift.features = options.max_features;
  sift.layers = kSiftLayers;
  sift.contrast_threshold = options.contrast_threshold;
  sift.sigma = kSiftSigma;
  std::vector<cv::KeyPoint> keypoints = FindSift(half, half_mask, sift, nullptr);
  // OpenCV packs (octave, layer, offset) in `octave`: the octave in the low byte, signed.
  const float sx = float(image.cols) / float(half.cols), sy = float(image.rows) / float(half.rows);
  for (auto& k : keypoints) {
    int octave = k.octave & 255;
    octave = octave < 128 ? octave : (-128 | octave);
    k.octave = (k.octave & ~255) | ((octave + 1) & 255);
    k.pt.x = (k.pt.x - kSiftUpscaleBias + 0.5f) * sx - 0.5f;
    k.pt.y = (k.pt.y - kSiftUpscaleBias + 0.5f) * sy - 0.5f;
    k.size *= 0.5f * (sx + sy);
  }
  if (!keypoints.empty()) DescribeSift(image, keypoints, kSiftLayers, kSiftSigma, descriptors);
  return keypoints;
}

// One SIFT pass at `contrast`: keypoints in frame pixels, their descriptors.
std::vector<cv::KeyPoint> RunSift(FeatureOptions options, double contrast, const cv::Mat& image, const cv::Mat& mask,
                                  cv::Mat* descriptors) {
  options.contrast_threshold = contrast;
  descriptors->release();
  if (!options.double_first_octave) return DescribeFromHalf(options, image, mask, descriptors);
  std::vector<cv::KeyPoint> keypoints;
  SiftOptions sift;
  sift.features = options.max_features;
  sift.layers = kSiftLayers;
  sift.contrast_threshold = contrast;
  sift.sigma = kSiftSigma;
  keypoints = FindSift(image, mask, sift, descriptors);
  for (auto& k : keypoints) k.pt -= cv::Point2f(kSiftUpscaleBias, kSiftUpscaleBias);
  return keypoints;
}

// Keypoints (and their descriptor rows) strongest first, ties by position: SIFT returns its
// strongest in an order that depends on the weaker candidates it dropped, which the starting
// threshold changes; the matching's RANSAC draws depend on the order.
void SortCanonically(std::vector<cv::KeyPoint>* keypoints, cv::Mat* descriptors) {
  const auto& k = *keypoints;
  std::vector<int> order(k.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    const cv::KeyPoint &p = k[size_t(a)], &q = k[size_t(b)];
    return std::tie(q.response, p.pt.y, p.pt.x, p.size, p.angle) < std::tie(p.response, q.pt.y, q.pt.x, q.size, q.angle);
  });
  std::vector<cv::KeyPoint> sorted;
  sorted.reserve(k.size());
  cv::Mat rows(descriptors->rows, descriptors->cols, descriptors->type());
  for (size_t i = 0; i < order.size(); ++i) {
    sorted.push_back(k[size_t(order[i])]);
    if (!descriptors->empty()) descriptors->row(order[i]).copyTo(rows.row(static_cast<int>(i)));
  }
  keypoints->swap(sorted);
  if (!descriptors->empty()) *descriptors = rows;
}

}  // namespace

Features FeatureExtractor::Extract(const cv::Mat& gray) const {
  CV_Assert(gray.type() == CV_8UC1);
  const double scale = options_.ScaleFor(gray.size());
  cv::Mat small = gray;
  if (scale < 1.0) ResizeArea(gray, small, scale);
  return ExtractScaled(small, scale);
}

std::vector<cv::KeyPoint> FeatureExtractor::DetectSift(const cv::Mat& image, const cv::Mat& mask,
                                                       cv::Mat* descriptors) const {
  const double base = options_.contrast_threshold;
  if (FastSiftApplies()) {
    // FindSift orients and describes only the strongest: nothing to gain from a higher threshold
    // (halved or not: DescribeFromHalf finds its keypoints with FindSift too).
    std::vector<cv::KeyPoint> keypoints = RunSift(options_, base, image, mask, descriptors);
    SortCanonically(&keypoints, descriptors);
    return keypoints;
  }
  const double start = std::max(base, double(start_contrast_->load(std::memory_order_relaxed)));
  std::vector<cv::KeyPoint> keypoints = RunSift(options_, start, image, mask, descriptors);
  const bool full = static_cast<int>(keypoints.size()) >= options_.max_features;
  // Too few above the raised threshold: the weaker ones may be among the strongest kept.
  if (start > base && !full) keypoints = RunSift(options_, base, image, mask, descriptors);
  // SIFT keeps a candidate when its response is at least a third of the contrast threshold
  // (OpenCV divides it among the octave's three layers), so a frame whose weakest kept feature
  // has response r keeps the same strongest features from a threshold of 3 r. The next frame
  // starts below that, by a margin for ground that changes.
  float next = 0;
  if (static_cast<int>(keypoints.size()) >= options_.max_features) {
    float weakest = std::numeric_limits<float>::max();
    for (const auto& k : keypoints) weakest = std::min(weakest, k.response);
    next = kStartMargin * 3.0f * weakest;
  }
  start_contrast_->store(next, std::memory_order_relaxed);
  SortCanonically(&keypoints, descriptors);
  return keypoints;
}

Features FeatureExtractor::ExtractScaled(const cv::Mat& small, double scale, const cv::Mat& mask) const {
  CV_Assert(small.type() == CV_8UC1 && scale > 0);
  CV_Assert(mask.empty() || (mask.type() == CV_8UC1 && mask.size() == small.size()));
  std::vector<cv::KeyPoint> keypoints;
  Features f;
  f.norm = options_.type == "sift" ? cv::NORM_L2 : cv::NORM_HAMMING;
  if (options_.type == "sift")
    keypoints = DetectSift(small, mask, &f.descriptors);
  else if (mask.empty())
    CreateDetector(options_)->detectAndCompute(small, cv::noArray(), keypoints, f.descriptors);
  else
    CreateDetector(options_)->detectAndCompute(small, mask, keypoints, f.descriptors);
  if (options_.type == "akaze" && static_cast<int>(keypoints.size()) > options_.max_features) {
    // AKAZE has no count limit: keep the strongest.
    std::vector<int> order(keypoints.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
    std::partial_sort(order.begin(), order.begin() + options_.max_features, order.end(),
                      [&](int a, int b) { return keypoints[a].response > keypoints[b].response; });
    order.resize(static_cast<size_t>(options_.max_features));
    cv::Mat d(static_cast<int>(order.size()), f.descriptors.cols, f.descriptors.type());
    std::vector<cv::KeyPoint> kept;
    for (size_t i = 0; i < order.size(); ++i) {
      f.descriptors.row(order[i]).copyTo(d.row(static_cast<int>(i)));
      kept.push_back(keypoints[static_cast<size_t>(order[i])]);
    }
    keypoints.swap(kept);
    f.descriptors = d;
  }
  for (const auto& k : keypoints)
    f.strong += options_.type != "sift" || k.response >= options_.min_response;
  // Keypoint centres at the reduced scale back to full-resolution pixel coordinates.
  const float s = static_cast<float>(1.0 / scale);
  const float shift = 0.5f * (s - 1.0f);
  f.points.reserve(keypoints.size());
  for (const auto& k : keypoints) f.points.emplace_back(k.pt.x * s + shift, k.pt.y * s + shift);
  return f;
}

namespace {

// cv::batchDistance's squared L2 matrix (a.rows x b.rows) for SIFT's descriptors: their entries
// are whole numbers 0..255, so every difference, square and sum (< 2^24) is exact in float and
// the order of adding changes nothing, OpenCV's values to the bit. Sixteen of b's rows at once
// against each of a's, from a transposed copy: a broadcast, a subtraction and a multiply-add a
// step, where OpenCV reduces each pair's vector on its own.
__attribute__((target("avx512f"))) void SquaredDistancesAvx512(const cv::Mat& a, const cv::Mat& b, cv::Mat& d) {
  d.create(a.rows, b.rows, CV_32F);
  const int n = a.cols;
  std::vector<float> block(size_t(n) * 16);
  for (int j0 = 0; j0 < b.rows; j0 += 16) {
    const int m = std::min(16, b.rows - j0);
    for (int k = 0; k < n; ++k)
      for (int l = 0; l < 16; ++l) block[size_t(k * 16 + l)] = l < m ? b.ptr<float>(j0 + l)[k] : 0.f;
    const __mmask16 lanes = m == 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << m) - 1);
    for (int i = 0; i < a.rows; ++i) {
      const float* row = a.ptr<float>(i);
      __m512 even = _mm512_setzero_ps(), odd = _mm512_setzero_ps();
      int k = 0;
      for (; k + 2 <= n; k += 2) {
        const __m512 d0 = _mm512_sub_ps(_mm512_set1_ps(row[k]), _mm512_loadu_ps(&block[size_t(k * 16)]));
        const __m512 d1 = _mm512_sub_ps(_mm512_set1_ps(row[k + 1]), _mm512_loadu_ps(&block[size_t(k * 16 + 16)]));
        even = _mm512_fmadd_ps(d0, d0, even);
        odd = _mm512_fmadd_ps(d1, d1, odd);
      }
      if (k < n) {
        const __m512 d0 = _mm512_sub_ps(_mm512_set1_ps(row[k]), _mm512_loadu_ps(&block[size_t(k * 16)]));
        even = _mm512_fmadd_ps(d0, d0, even);
      }
      _mm512_mask_storeu_ps(d.ptr<float>(i) + j0, lanes, _mm512_add_ps(even, odd));
    }
  }
}

// SIFT's descriptors as 16-bit whole numbers, two to a 32-bit word (the last one's pair 0 when
// the length is odd), and each row's squared norm; false where an entry is not a whole number
// in 0..255 (not SIFT's, which SquaredDistancesAvx512 then handles). Bytes (descriptors as
// stored) are whole numbers in 0..255 already.
bool DescriptorWords(const cv::Mat& m, std::vector<int32_t>* words, std::vector<int32_t>* norms) {
  const int n = m.cols, pairs = (n + 1) / 2;
  words->resize(size_t(m.rows) * size_t(pairs));
  norms->resize(size_t(m.rows));
  const bool bytes = m.type() == CV_8U;
  for (int i = 0; i < m.rows; ++i) {
    int32_t* out = words->data() + size_t(i) * size_t(pairs);
    int32_t norm = 0;
    if (bytes) {
      const uchar* row = m.ptr<uchar>(i);
      for (int k = 0; k < pairs; ++k) {
        const int v0 = row[2 * k], v1 = 2 * k + 1 < n ? row[2 * k + 1] : 0;
        out[k] = int32_t(uint32_t(v0) | (uint32_t(v1) << 16));
        norm += v0 * v0 + v1 * v1;
      }
      (*norms)[size_t(i)] = norm;
      continue;
    }
    const float* row = m.ptr<float>(i);
    for (int k = 0; k < pairs; ++k) {
      int v[2] = {0, 0};
      for (int h = 0; h < 2 && 2 * k + h < n; ++h) {
        const float x = row[2 * k + h];
        if (!(x >= 0.f && x <= 255.f) || x != std::floor(x)) return false;
        v[h] = static_cast<int>(x);
      }
      out[k] = int32_t(uint32_t(v[0]) | (uint32_t(v[1]) << 16));
      norm += v[0] * v[0] + v[1] * v[1];
    }
    (*norms)[size_t(i)] = norm;
  }
  return true;
}

// |a|^2 + |b|^2 - 2 a.b for sixteen of b's rows, written as floats.
__attribute__((target("avx512f"))) inline void StoreDistances(__m512i dot, int32_t a_norm, __m512i b_norms,
                                                               __mmask16 lanes, float* out) {
  const __m512i dist = _mm512_sub_epi32(_mm512_add_epi32(_mm512_set1_epi32(a_norm), b_norms), _mm512_slli_epi32(dot, 1));
  _mm512_mask_storeu_ps(out, lanes, _mm512_cvtepi32_ps(dist));
}

// The same matrix as SquaredDistancesAvx512 from dot products in 16-bit whole numbers: |a|^2 +
// |b|^2 - 2 a.b, each term a whole number under 2^24, so the same values to the bit. VNNI takes
// 32 products and their pairwise sums a step, where the float path takes 16 differences and 16
// multiply-adds (recovery matches on the engine's thread: a tenth of its time on turning stills).
// False (nothing written) for descriptors that are not SIFT's whole numbers.
__attribute__((target("avx512f,avx512bw,avx512vnni"))) bool SquaredDistancesVnni(const cv::Mat& a, const cv::Mat& b,
                                                                                 cv::Mat& d) {
  std::vector<int32_t> aw, an, bw, bn;
  if (!DescriptorWords(a, &aw, &an) || !DescriptorWords(b, &bw, &bn)) return false;
  const int pairs = (a.cols + 1) / 2;
  d.create(a.rows, b.rows, CV_32F);
  std::vector<int32_t> block(size_t(pairs) * 16);
  for (int j0 = 0; j0 < b.rows; j0 += 16) {
    const int m = std::min(16, b.rows - j0);
    for (int k = 0; k < pairs; ++k)
      for (int l = 0; l < 16; ++l) block[size_t(k * 16 + l)] = l < m ? bw[size_t(j0 + l) * size_t(pairs) + size_t(k)] : 0;
    const __mmask16 lanes = m == 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << m) - 1);
    const __m512i b_norms = _mm512_maskz_loadu_epi32(lanes, bn.data() + j0);
    // Four of a's rows a step, each with two sums: every load of b's block serves four rows.
    int i = 0;
    for (; i + 4 <= a.rows; i += 4) {
      const int32_t* row = aw.data() + size_t(i) * size_t(pairs);
      const size_t stride = size_t(pairs);
      __m512i s[4][2];
      for (auto& r : s) r[0] = r[1] = _mm512_setzero_si512();
      int k = 0;
      for (; k + 2 <= pairs; k += 2)
        for (int h = 0; h < 2; ++h) {
          const __m512i column = _mm512_loadu_si512(&block[size_t((k + h) * 16)]);
          for (int q = 0; q < 4; ++q)
            s[q][h] = _mm512_dpwssd_epi32(s[q][h], _mm512_set1_epi32(row[q * stride + size_t(k + h)]), column);
        }
      for (; k < pairs; ++k) {
        const __m512i column = _mm512_loadu_si512(&block[size_t(k * 16)]);
        for (int q = 0; q < 4; ++q) s[q][0] = _mm512_dpwssd_epi32(s[q][0], _mm512_set1_epi32(row[q * stride + size_t(k)]), column);
      }
      for (int q = 0; q < 4; ++q) StoreDistances(_mm512_add_epi32(s[q][0], s[q][1]), an[size_t(i + q)], b_norms, lanes, d.ptr<float>(i + q) + j0);
    }
    for (; i < a.rows; ++i) {
      const int32_t* row = aw.data() + size_t(i) * size_t(pairs);
      // Four sums in turn: each waits on its own last step only.
      __m512i s[4] = {_mm512_setzero_si512(), _mm512_setzero_si512(), _mm512_setzero_si512(), _mm512_setzero_si512()};
      int k = 0;
      for (; k + 4 <= pairs; k += 4)
        for (int q = 0; q < 4; ++q)
          s[q] = _mm512_dpwssd_epi32(s[q], _mm512_set1_epi32(row[k + q]), _mm512_loadu_si512(&block[size_t((k + q) * 16)]));
      for (; k < pairs; ++k)
        s[0] = _mm512_dpwssd_epi32(s[0], _mm512_set1_epi32(row[k]), _mm512_loadu_si512(&block[size_t(k * 16)]));
      StoreDistances(_mm512_add_epi32(_mm512_add_epi32(s[0], s[1]), _mm512_add_epi32(s[2], s[3])), an[size_t(i)], b_norms, lanes,
                     d.ptr<float>(i) + j0);
    }
  }
  return true;
}

// Sixteen descriptor entries as floats: float descriptors, or bytes (descriptors as stored).
__attribute__((target("avx512f"))) inline __m512 Load16(const float* p) { return _mm512_loadu_ps(p); }
__attribute__((target("avx512f"))) inline __m512 Load16(const uchar* p) {
  return _mm512_cvtepi32_ps(_mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p))));
}

// cv::norm(a, b, NORM_L2) of two descriptors without its dispatch and two Mat headers per pair (a
// fifth of a guided match's time): differences in float, squares summed in double, as OpenCV
// computes them; for SIFT's whole numbers every sum is exact, OpenCV's value to the bit, in float
// or in bytes.
template <typename T>
__attribute__((target("avx512f"))) double DistanceAvx512(const T* a, const T* b, int n) {
  __m512d low = _mm512_setzero_pd(), high = _mm512_setzero_pd();
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512 d = _mm512_sub_ps(Load16(a + i), Load16(b + i));
    const __m512d dl = _mm512_cvtps_pd(_mm512_castps512_ps256(d));
    const __m512d dh = _mm512_cvtps_pd(_mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(d), 1)));
    low = _mm512_fmadd_pd(dl, dl, low);
    high = _mm512_fmadd_pd(dh, dh, high);
  }
  double sum = _mm512_reduce_add_pd(_mm512_add_pd(low, high));
  for (; i < n; ++i) {
    const double v = double(float(a[i]) - float(b[i]));
    sum += v * v;
  }
  return std::sqrt(sum);
}

}  // namespace

cv::Mat SquaredDistanceMatrix(const Features& a, const Features& b) {
  const int type = a.descriptors.type();
  CV_Assert((type == CV_32F || type == CV_8U) && b.descriptors.type() == type);
  cv::Mat d;
  const bool same_length = b.descriptors.cols == a.descriptors.cols;
  if (CpuHasAvx512Vnni() && same_length && SquaredDistancesVnni(a.descriptors, b.descriptors, d)) return d;
  cv::Mat fa = a.descriptors, fb = b.descriptors;
  if (type == CV_8U) {  // the float paths' values are the same for the same whole numbers
    a.descriptors.convertTo(fa, CV_32F);
    b.descriptors.convertTo(fb, CV_32F);
  }
  if (CpuHasAvx512() && same_length)
    SquaredDistancesAvx512(fa, fb, d);
  else
    cv::batchDistance(fa, fb, d, CV_32F, cv::noArray(), cv::NORM_L2SQR);
  return d;
}

namespace {

// For each column of `d`, the first row holding its smallest value.
void ColumnMinima(const cv::Mat& d, std::vector<int>* best_a) {
  std::vector<float> best(static_cast<size_t>(d.cols), std::numeric_limits<float>::max());
  for (int i = 0; i < d.rows; ++i) {
    const float* row = d.ptr<float>(i);
    for (int j = 0; j < d.cols; ++j)
      if (row[j] < best[static_cast<size_t>(j)]) {
        best[static_cast<size_t>(j)] = row[j];
        (*best_a)[static_cast<size_t>(j)] = i;
      }
  }
}

// The same, 16 columns a step: each column still sees the rows in order and keeps the first.
__attribute__((target("avx512f"))) void ColumnMinimaAvx512(const cv::Mat& d, std::vector<int>* best_a) {
  std::vector<float> best(static_cast<size_t>(d.cols), std::numeric_limits<float>::max());
  for (int i = 0; i < d.rows; ++i) {
    const float* row = d.ptr<float>(i);
    const __m512i index = _mm512_set1_epi32(i);
    for (int j = 0; j < d.cols; j += 16) {
      const __mmask16 lanes = d.cols - j >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (d.cols - j)) - 1);
      const __m512 v = _mm512_maskz_loadu_ps(lanes, row + j), b = _mm512_maskz_loadu_ps(lanes, best.data() + j);
      const __mmask16 lower = _mm512_mask_cmp_ps_mask(lanes, v, b, _CMP_LT_OQ);
      _mm512_mask_storeu_ps(best.data() + j, lower, v);
      _mm512_mask_storeu_epi32(best_a->data() + j, lower, index);
    }
  }
}

// A row's smallest value, its first column, and its second smallest value (equal to the first
// when it occurs twice): Lowe's ratio test's d1, j1 and d2.
void BestTwo(const float* row, int cols, float* d1, float* d2, int* j1) {
  *d1 = *d2 = std::numeric_limits<float>::max();
  *j1 = -1;
  for (int j = 0; j < cols; ++j) {
    if (row[j] < *d1) {
      *d2 = *d1;
      *d1 = row[j];
      *j1 = j;
    } else if (row[j] < *d2) {
      *d2 = row[j];
    }
  }
}

// The same, 16 columns a step: each lane keeps the two smallest of its columns and the first
// column of its smallest; the row's are the smallest lane's, its first column the least of the
// lanes that hold it, and the second the least of that lane's second and the other lanes' first.
// The same values as BestTwo.
__attribute__((target("avx512f"))) void BestTwoAvx512(const float* row, int cols, float* d1, float* d2, int* j1) {
  const __m512 none = _mm512_set1_ps(std::numeric_limits<float>::max());
  __m512 m1 = none, m2 = none;
  __m512i at = _mm512_set1_epi32(-1), j = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i step = _mm512_set1_epi32(16);
  for (int j0 = 0; j0 < cols; j0 += 16, j = _mm512_add_epi32(j, step)) {
    const __mmask16 lanes = cols - j0 >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (cols - j0)) - 1);
    const __m512 v = _mm512_mask_loadu_ps(none, lanes, row + j0);
    const __mmask16 below1 = _mm512_cmp_ps_mask(v, m1, _CMP_LT_OQ);
    const __mmask16 below2 = _mm512_cmp_ps_mask(v, m2, _CMP_LT_OQ);
    m2 = _mm512_mask_mov_ps(_mm512_mask_mov_ps(m2, below2, v), below1, m1);
    m1 = _mm512_mask_mov_ps(m1, below1, v);
    at = _mm512_mask_mov_epi32(at, below1, j);
  }
  *d1 = _mm512_reduce_min_ps(m1);
  if (!(*d1 < std::numeric_limits<float>::max())) {
    *d2 = *d1;
    *j1 = -1;
    return;
  }
  const __mmask16 holding = _mm512_cmp_ps_mask(m1, _mm512_set1_ps(*d1), _CMP_EQ_OQ);
  *j1 = _mm512_mask_reduce_min_epi32(holding, at);
  const __mmask16 lane = static_cast<__mmask16>(1u << (*j1 & 15));
  *d2 = _mm512_reduce_min_ps(_mm512_mask_mov_ps(m1, lane, m2));
}

// Float descriptors (SIFT): one distance matrix serves the ratio test one way and the mutual-best
// check the other, where kNN matching and a reverse pass would compute most distances twice.
std::vector<cv::DMatch> MatchByDistanceMatrix(const Features& a, const Features& b,
                                              const FeatureOptions& options) {
  const cv::Mat d = SquaredDistanceMatrix(a, b);
  const bool wide = CpuHasAvx512();
  std::vector<int> best_a(static_cast<size_t>(d.cols), -1);  // for each b, its nearest a
  if (options.cross_check) wide ? ColumnMinimaAvx512(d, &best_a) : ColumnMinima(d, &best_a);
  const float ratio2 = static_cast<float>(options.ratio * options.ratio);
  std::vector<cv::DMatch> out;
  for (int i = 0; i < d.rows; ++i) {
    float d1, d2;
    int j1;
    wide ? BestTwoAvx512(d.ptr<float>(i), d.cols, &d1, &d2, &j1) : BestTwo(d.ptr<float>(i), d.cols, &d1, &d2, &j1);
    if (j1 < 0 || !(d1 < ratio2 * d2)) continue;
    if (options.cross_check && best_a[static_cast<size_t>(j1)] != i) continue;
    out.emplace_back(i, j1, std::sqrt(d1));
  }
  return out;
}

std::vector<cv::DMatch> MatchBinary(const Features& a, const Features& b, const FeatureOptions& options) {
  cv::BFMatcher matcher(a.norm);
  std::vector<std::vector<cv::DMatch>> ab;
  matcher.knnMatch(a.descriptors, b.descriptors, ab, 2);
  std::vector<cv::DMatch> candidates;
  for (const auto& k : ab) {
    const bool passes = k.size() == 2 ? k[0].distance < options.ratio * k[1].distance : k.size() == 1;
    if (passes) candidates.push_back(k[0]);
  }
  if (options.cross_check && !candidates.empty()) {
    // Mutual best: only the descriptors of b that some a chose need their best a.
    cv::Mat chosen(static_cast<int>(candidates.size()), b.descriptors.cols, b.descriptors.type());
    for (size_t i = 0; i < candidates.size(); ++i)
      b.descriptors.row(candidates[i].trainIdx).copyTo(chosen.row(static_cast<int>(i)));
    std::vector<cv::DMatch> back;
    matcher.match(chosen, a.descriptors, back);
    std::vector<cv::DMatch> mutual;
    for (size_t i = 0; i < candidates.size(); ++i)
      if (back[i].trainIdx == candidates[i].queryIdx) mutual.push_back(candidates[i]);
    candidates.swap(mutual);
  }
  return candidates;
}

}  // namespace

double DescriptorDistance(const Features& a, int i, const Features& b, int j) {
  const int type = a.descriptors.type();
  if (CpuHasAvx512() && a.norm == cv::NORM_L2 && b.descriptors.type() == type && a.descriptors.cols == b.descriptors.cols) {
    if (type == CV_32F) return DistanceAvx512(a.descriptors.ptr<float>(i), b.descriptors.ptr<float>(j), a.descriptors.cols);
    if (type == CV_8U) return DistanceAvx512(a.descriptors.ptr<uchar>(i), b.descriptors.ptr<uchar>(j), a.descriptors.cols);
  }
  return cv::norm(a.descriptors.row(i), b.descriptors.row(j), a.norm);
}

Matches MatchFeatures(const Features& a, const Features& b, const FeatureOptions& options) {
  Matches m;
  if (a.descriptors.rows < 2 || b.descriptors.rows < 2) return m;
  CV_Assert(a.norm == b.norm && a.descriptors.type() == b.descriptors.type());
  const int type = a.descriptors.type();
  const std::vector<cv::DMatch> matches = a.norm == cv::NORM_L2 && (type == CV_32F || type == CV_8U)
                                              ? MatchByDistanceMatrix(a, b, options)
                                              : MatchBinary(a, b, options);
  for (const auto& c : matches) {
    m.from.push_back(a.points[static_cast<size_t>(c.queryIdx)]);
    m.to.push_back(b.points[static_cast<size_t>(c.trainIdx)]);
  }
  return m;
}

}  // namespace rolamos
