#include "engine/sift_detector.h"

#include <algorithm>
#include <cfloat>
#include <climits>
#include <cmath>
#include <tuple>

#include <immintrin.h>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/sift_descriptor.h"
#include "engine/sift_math.h"
#include "engine/sift_pyramid.h"
#include "rolamos/error.hpp"

namespace rolamos {

bool SiftOptions::IsValid(std::string* error) const {
  if (features < 0 || layers < 1 || layers > 10 || !(contrast_threshold >= 0) || !(edge_threshold > 0) ||
      !(sigma > 0.5 && sigma < 10)) {
    *error = "SIFT settings out of range (features >= 0, 1-10 layers, contrast >= 0, edge > 0, sigma in (0.5, 10))";
    return false;
  }
  return true;
}

namespace {

constexpr int kBorder = 5;          // pixels of each DoG image where no extremum is sought
constexpr int kMaxSteps = 5;        // refinement steps before an extremum is given up
constexpr int kOrientationBins = 36;
constexpr float kOrientationSigma = 1.5f;   // of the orientation window, in the keypoint's scales
constexpr float kOrientationRadius = 4.5f;  // 3 sigma
constexpr float kPeakRatio = 0.8f;          // of the highest, for another orientation

using Pyramid = std::vector<std::vector<cv::Mat>>;

struct Search {
  const Pyramid& gauss;
  const Pyramid& dog;
  int layers;
  float contrast, edge, sigma;
};

// The DoG's value, gradient and Hessian at (layer, y, x) of octave o, by central differences, in
// units of the image's range (OpenCV's scales and order of operations).
struct Local {
  float value;
  cv::Vec3f gradient;  // x, y, scale
  float dxx, dyy, dss, dxy, dxs, dys;
};

Local At(const Search& s, int o, int layer, int y, int x) {
  constexpr float img_scale = 1.f / 255;
  constexpr float deriv = img_scale * 0.5f, second = img_scale, cross = img_scale * 0.25f;
  const cv::Mat& img = s.dog[size_t(o)][size_t(layer)];
  const cv::Mat& prev = s.dog[size_t(o)][size_t(layer - 1)];
  const cv::Mat& next = s.dog[size_t(o)][size_t(layer + 1)];
  Local l;
  l.value = img.at<float>(y, x);
  l.gradient = cv::Vec3f((img.at<float>(y, x + 1) - img.at<float>(y, x - 1)) * deriv,
                         (img.at<float>(y + 1, x) - img.at<float>(y - 1, x)) * deriv,
                         (next.at<float>(y, x) - prev.at<float>(y, x)) * deriv);
  const float v2 = l.value * 2;
  l.dxx = (img.at<float>(y, x + 1) + img.at<float>(y, x - 1) - v2) * second;
  l.dyy = (img.at<float>(y + 1, x) + img.at<float>(y - 1, x) - v2) * second;
  l.dss = (next.at<float>(y, x) + prev.at<float>(y, x) - v2) * second;
  l.dxy = (img.at<float>(y + 1, x + 1) - img.at<float>(y + 1, x - 1) - img.at<float>(y - 1, x + 1) +
           img.at<float>(y - 1, x - 1)) * cross;
  l.dxs = (next.at<float>(y, x + 1) - next.at<float>(y, x - 1) - prev.at<float>(y, x + 1) + prev.at<float>(y, x - 1)) *
          cross;
  l.dys = (next.at<float>(y + 1, x) - next.at<float>(y - 1, x) - prev.at<float>(y + 1, x) + prev.at<float>(y - 1, x)) *
          cross;
  return l;
}

// Section 4: the extremum at (layer, r, c) of octave o moved to where the quadratic through its
// neighbours peaks; false when it wanders off, is too weak or lies on an edge.
bool Refine(const Search& s, int o, int* layer, int* r, int* c, cv::KeyPoint* k) {
  const cv::Size size = s.dog[size_t(o)][0].size();
  float xi = 0, xr = 0, xc = 0;
  int step = 0;
  for (; step < kMaxSteps; ++step) {
    const Local l = At(s, o, *layer, *r, *c);
    const cv::Matx33f H(l.dxx, l.dxy, l.dxs, l.dxy, l.dyy, l.dys, l.dxs, l.dys, l.dss);
    const cv::Vec3f X = H.solve(l.gradient, cv::DECOMP_LU);
    xi = -X[2];
    xr = -X[1];
    xc = -X[0];
    if (std::abs(xi) < 0.5f && std::abs(xr) < 0.5f && std::abs(xc) < 0.5f) break;
    constexpr float far = float(INT_MAX / 3);
    if (std::abs(xi) > far || std::abs(xr) > far || std::abs(xc) > far) return false;
    *c += cvRound(xc);
    *r += cvRound(xr);
    *layer += cvRound(xi);
    if (*layer < 1 || *layer > s.layers || *c < kBorder || *c >= size.width - kBorder || *r < kBorder ||
        *r >= size.height - kBorder)
      return false;
  }
  if (step >= kMaxSteps) return false;
  const int y = *r, x = *c;
  const Local l = At(s, o, *layer, y, x);
  const float t = cv::Matx31f(l.gradient).dot(cv::Matx31f(xc, xr, xi));
  const float contrast = l.value * (1.f / 255) + t * 0.5f;
  if (std::abs(contrast) * s.layers < s.contrast) return false;
  // Edges: the principal curvatures' ratio from the Hessian's trace and determinant.
  const float tr = l.dxx + l.dyy, det = l.dxx * l.dyy - l.dxy * l.dxy;
  if (det <= 0 || tr * tr * s.edge >= (s.edge + 1) * (s.edge + 1) * det) return false;
  k->pt.x = (float(x) + xc) * float(1 << o);
  k->pt.y = (float(y) + xr) * float(1 << o);
  k->octave = o + (*layer << 8) + (cvRound((xi + 0.5) * 255) << 16);
  k->size = s.sigma * std::pow(2.f, (float(*layer) + xi) / float(s.layers)) * float(1 << o) * 2;
  k->response = std::abs(contrast);
  return true;
}


// Section 5: the histogram of gradient orientations (36 bins, Gaussian-weighted by `sigma`)
// within `radius` of `pt`, smoothed; returns its highest bin.
__attribute__((target("avx512f,fma"))) float OrientationHistogram(const cv::Mat& img, cv::Point pt, int radius,
                                                                   float sigma, float* hist) {
  constexpr int n = kOrientationBins;
  thread_local std::vector<float> factors;
  GaussianFactors(radius, -1.f / (2.f * sigma * sigma), &factors);
  const float* f = factors.data();
  float temp[n + 4] = {};
  float* th = temp + 2;
  const __m512 per_degree = _mm512_set1_ps(n / 360.f);
  const __m512i vn = _mm512_set1_epi32(n), zero_i = _mm512_setzero_si512();
  const int j_first = std::max(-radius, 1 - pt.x), j_last = std::min(radius, img.cols - 2 - pt.x);
  for (int i = -radius; i <= radius; ++i) {
    const int y = pt.y + i;
    if (y <= 0 || y >= img.rows - 1 || j_first > j_last) continue;
    PrefetchRow(img, y + 1 + kPrefetchRows, pt.x + j_first - 1, pt.x + j_last + 1);
    const __m512 row_weight = _mm512_set1_ps(f[i + radius]);
    for (int j0 = j_first; j0 <= j_last; j0 += 16) {
      const __mmask16 valid =
          j_last - j0 >= 15 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << (j_last - j0 + 1)) - 1);
      __m512 dx, dy;
      Gradients(img, y, pt.x + j0, valid, &dx, &dy);
      const __m512 weight = _mm512_mul_ps(row_weight, _mm512_loadu_ps(f + j0 + radius));
      const __m512 mag = _mm512_sqrt_ps(_mm512_fmadd_ps(dx, dx, _mm512_mul_ps(dy, dy)));
      __m512i bin = _mm512_cvtps_epi32(_mm512_mul_ps(per_degree, Atan2Degrees(dy, dx)));
      bin = _mm512_mask_sub_epi32(bin, _mm512_cmpge_epi32_mask(bin, vn), bin, vn);
      bin = _mm512_mask_add_epi32(bin, _mm512_cmplt_epi32_mask(bin, zero_i), bin, vn);
      alignas(64) int32_t bins[16];
      alignas(64) float add[16];
      _mm512_store_si512(bins, bin);
      _mm512_store_ps(add, _mm512_mul_ps(weight, mag));
      for (unsigned m = valid; m; m &= m - 1) {
        const int l = __builtin_ctz(m);
        th[bins[l]] += add[l];
      }
    }
  }
  th[-1] = th[n - 1];
  th[-2] = th[n - 2];
  th[n] = th[0];
  th[n + 1] = th[1];
  float top = 0;
  for (int i = 0; i < n; ++i) {
    hist[i] = std::fma(th[i - 2] + th[i + 2], 1.f / 16.f, std::fma(th[i - 1] + th[i + 1], 4.f / 16.f, th[i] * (6.f / 16.f)));
    top = i == 0 ? hist[0] : std::max(top, hist[i]);
  }
  return top;
}

// The keypoints (one per orientation peak) of the refined extremum `k` at (r, c) of layer
// `layer` of octave o.
void Orient(const Search& s, int o, int layer, int r, int c, cv::KeyPoint k, std::vector<cv::KeyPoint>* out) {
  constexpr int n = kOrientationBins;
  float hist[n];
  const float scale = k.size * 0.5f / float(1 << o);
  const float top = OrientationHistogram(s.gauss[size_t(o)][size_t(layer)], cv::Point(c, r),
                                         cvRound(kOrientationRadius * scale), kOrientationSigma * scale, hist);
  const float threshold = top * kPeakRatio;
  for (int j = 0; j < n; ++j) {
    const int left = j > 0 ? j - 1 : n - 1, right = j < n - 1 ? j + 1 : 0;
    if (!(hist[j] > hist[left] && hist[j] > hist[right] && hist[j] >= threshold)) continue;
    float bin = float(j) + 0.5f * (hist[left] - hist[right]) / (hist[left] - 2 * hist[j] + hist[right]);
    bin = bin < 0 ? n + bin : bin >= n ? bin - n : bin;
    k.angle = 360.f - (360.f / n) * bin;
    if (std::abs(k.angle - 360.f) < FLT_EPSILON) k.angle = 0.f;
    out->push_back(k);
  }
}

// A refined extremum: its keypoint (no orientation yet) and where the refinement ended.
struct Extremum {
  cv::KeyPoint k;
  int octave, layer, r, c;
  auto Place() const { return std::make_tuple(octave, layer, r, c); }
};

// Rows [begin, end) of DoG layer `layer` of octave o: its extrema against their 26 neighbours in
// scale and space, sixteen pixels at a time, refined.
__attribute__((target("avx512f"))) void SearchRows(const Search& s, int o, int layer, float threshold, int begin,
                                                    int end, std::vector<Extremum>* out) {
  const cv::Mat& img = s.dog[size_t(o)][size_t(layer)];
  const cv::Mat& prev = s.dog[size_t(o)][size_t(layer - 1)];
  const cv::Mat& next = s.dog[size_t(o)][size_t(layer + 1)];
  const int cols = img.cols;
  const __m512 thr = _mm512_set1_ps(threshold), zero = _mm512_setzero_ps();
  for (int r = begin; r < end; ++r) {
    // (No software prefetch: the rows are read in order, which the hardware prefetches.)
    const float* rows[9] = {prev.ptr<float>(r - 1), prev.ptr<float>(r), prev.ptr<float>(r + 1),
                            img.ptr<float>(r - 1),  img.ptr<float>(r),  img.ptr<float>(r + 1),
                            next.ptr<float>(r - 1), next.ptr<float>(r), next.ptr<float>(r + 1)};
    for (int c = kBorder; c < cols - kBorder; c += 16) {
      const int left = cols - kBorder - c;
      const __mmask16 in = left >= 16 ? __mmask16(0xFFFF) : static_cast<__mmask16>((1u << left) - 1);
      const __m512 val = _mm512_maskz_loadu_ps(in, rows[4] + c);
      __mmask16 cand = in & _mm512_cmp_ps_mask(_mm512_abs_ps(val), thr, _CMP_GT_OQ);
      if (!cand) continue;
      // Each row's three, then the rows' pairwise (the centre is its own row's middle).
      __m512 hi[9], lo[9];
      for (int k = 0; k < 9; ++k) {
        const __m512 a = _mm512_maskz_loadu_ps(cand, rows[k] + c - 1), b = _mm512_maskz_loadu_ps(cand, rows[k] + c + 1);
        hi[k] = _mm512_max_ps(a, b);
        lo[k] = _mm512_min_ps(a, b);
        if (k == 4) continue;
        const __m512 m = _mm512_maskz_loadu_ps(cand, rows[k] + c);
        hi[k] = _mm512_max_ps(hi[k], m);
        lo[k] = _mm512_min_ps(lo[k], m);
      }
      for (int k = 0; k < 4; ++k) {
        hi[k] = _mm512_max_ps(hi[k], hi[k + 4]);
        lo[k] = _mm512_min_ps(lo[k], lo[k + 4]);
      }
      hi[0] = _mm512_max_ps(_mm512_max_ps(hi[0], hi[2]), _mm512_max_ps(_mm512_max_ps(hi[1], hi[3]), hi[8]));
      lo[0] = _mm512_min_ps(_mm512_min_ps(lo[0], lo[2]), _mm512_min_ps(_mm512_min_ps(lo[1], lo[3]), lo[8]));
      cand &= (_mm512_cmp_ps_mask(val, zero, _CMP_GT_OQ) & _mm512_cmp_ps_mask(val, hi[0], _CMP_GE_OQ)) |
              (_mm512_cmp_ps_mask(val, zero, _CMP_LT_OQ) & _mm512_cmp_ps_mask(val, lo[0], _CMP_LE_OQ));
      for (unsigned m = cand; m; m &= m - 1) {
        int r1 = r, c1 = c + __builtin_ctz(m), l1 = layer;
        cv::KeyPoint k;
        if (Refine(s, o, &l1, &r1, &c1, &k)) out->push_back({k, o, l1, r1, c1});
      }
    }
  }
}

// The keypoints of the strongest extrema, as OpenCV's removeDuplicatedSorted and retainBest would
// leave them of all the extrema oriented, orienting only those: keypoints of one extremum share its
// response, so the `features` strongest keypoints (with all those as strong as the last of them)
// come from the strongest extrema. An extremum reached from two pixels is one (its copies'
// keypoints would be duplicates). Orienting every extremum above the threshold cost as much as
// finding them.
std::vector<cv::KeyPoint> OrientStrongest(const Search& s, std::vector<Extremum> extrema, int features) {
  std::sort(extrema.begin(), extrema.end(), [](const Extremum& a, const Extremum& b) { return a.Place() < b.Place(); });
  extrema.erase(std::unique(extrema.begin(), extrema.end(),
                            [](const Extremum& a, const Extremum& b) { return a.Place() == b.Place(); }),
                extrema.end());
  std::sort(extrema.begin(), extrema.end(), [](const Extremum& a, const Extremum& b) {
    return a.k.response != b.k.response ? a.k.response > b.k.response : a.Place() < b.Place();
  });
  std::vector<std::vector<cv::KeyPoint>> oriented(extrema.size());
  size_t done = 0;  // extrema oriented: [0, done)
  auto orient_to = [&](size_t end) {
    end = std::min(end, extrema.size());
    if (end <= done) return;
    // Oriented in the order of their layers' rows, not of their strength: each window then
    // overlaps the last one's in cache (in strength order, most of a window's first rows missed
    // it). Each extremum's keypoints are its own, whatever the order.
    std::vector<size_t> order(end - done);
    for (size_t i = 0; i < order.size(); ++i) order[i] = done + i;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return extrema[a].Place() < extrema[b].Place(); });
    cv::parallel_for_(cv::Range(0, static_cast<int>(order.size())), [&](const cv::Range& range) {
      for (int n = range.start; n < range.end; ++n) {
        const size_t i = order[size_t(n)];
        const Extremum& e = extrema[i];
        Orient(s, e.octave, e.layer, e.r, e.c, e.k, &oriented[i]);
      }
    });
    done = end;
  };
  size_t kept = extrema.size();  // extrema whose keypoints are kept: [0, kept)
  if (features <= 0) {
    orient_to(extrema.size());
  } else {
    size_t count = 0, i = 0;
    bool full = false;
    while (!full && i < extrema.size()) {
      orient_to(i + std::max<size_t>(1, size_t(features) - count));
      for (; i < done; ++i) {
        count += oriented[i].size();
        if (count >= size_t(features)) {
          full = true;
          break;
        }
      }
    }
    if (full) {
      // retainBest keeps every keypoint as strong as the last one it needs.
      const float last = extrema[i].k.response;
      kept = i + 1;
      // (When there are exactly `features`, retainBest keeps them all: the extrema left give none.)
      while (kept < extrema.size() && extrema[kept].k.response == last) orient_to(++kept);
    }
  }
  std::vector<cv::KeyPoint> keypoints;
  for (size_t i = 0; i < kept; ++i) keypoints.insert(keypoints.end(), oriented[i].begin(), oriented[i].end());
  return keypoints;
}

}  // namespace

std::vector<cv::KeyPoint> FindSift(const cv::Mat& image, const cv::Mat& mask, const SiftOptions& options,
                                   cv::Mat* descriptors) {
  std::string error;
  if (!options.IsValid(&error)) Fail("SIFT", error);
  if (image.type() != CV_8UC1) Fail("SIFT", "image type " + cv::typeToString(image.type()) + " is not 8-bit grey");
  if (!mask.empty() && (mask.type() != CV_8UC1 || mask.size() != image.size()))
    Fail("SIFT", "the mask is not 8-bit grey of the image's size");
  std::vector<cv::KeyPoint> keypoints;
  if (!FastSiftApplies()) {
    const auto sift = cv::SIFT::create(options.features, options.layers, options.contrast_threshold,
                                       options.edge_threshold, options.sigma);
    if (!descriptors) sift->detect(image, keypoints, mask);
    else if (mask.empty()) sift->detectAndCompute(image, cv::noArray(), keypoints, *descriptors);
    else sift->detectAndCompute(image, mask, keypoints, *descriptors);
    return keypoints;
  }
  constexpr int first = -1;  // the doubled first octave
  const cv::Mat base = SiftBaseImage(image, true, static_cast<float>(options.sigma));
  const int octaves = cvRound(std::log(double(std::min(base.cols, base.rows))) / std::log(2.) - 2) - first;
  Pyramid dog;
  const Pyramid gauss = SiftGaussianPyramid(base, octaves, options.layers, options.layers + 2, options.sigma, &dog);
  // The scan in bands of rows, each its own list, joined in order.
  struct Band {
    int octave, layer, begin, end;
  };
  std::vector<Band> bands;
  for (int o = 0; o < octaves; ++o)
    for (int i = 1; i <= options.layers; ++i) {
      const int rows = dog[size_t(o)][size_t(i)].rows;
      for (int r = kBorder; r < rows - kBorder; r += 64) bands.push_back({o, i, r, std::min(r + 64, rows - kBorder)});
    }
  const Search search{gauss, dog, options.layers, float(options.contrast_threshold), float(options.edge_threshold),
                      float(options.sigma)};
  const float threshold = float(cvFloor(0.5 * options.contrast_threshold / options.layers * 255));
  std::vector<std::vector<Extremum>> found(bands.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(bands.size())), [&](const cv::Range& range) {
    for (int b = range.start; b < range.end; ++b) {
      const Band& band = bands[size_t(b)];
      SearchRows(search, band.octave, band.layer, threshold, band.begin, band.end, &found[size_t(b)]);
    }
  });
  std::vector<Extremum> extrema;
  for (const auto& f : found) extrema.insert(extrema.end(), f.begin(), f.end());
  keypoints = OrientStrongest(search, std::move(extrema), options.features);
  for (auto& k : keypoints) {
    k.octave = (k.octave & ~255) | ((k.octave + first) & 255);
    k.pt *= 0.5f;
    k.size *= 0.5f;
  }
  if (!mask.empty()) cv::KeyPointsFilter::runByPixelsMask(keypoints, mask);
  if (descriptors) DescribeSiftOn(gauss, first, keypoints, descriptors);
  return keypoints;
}

}  // namespace rolamos
