#include "objects/bow_features.h"

#include <cmath>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "objects/dihedral.h"
#include "objects/object_crop.h"
#include "rolamos/error.hpp"

namespace rolamos {

bool ObjectFeatureOptions::IsValid(std::string* error) const {
  if (image_size < 32 || image_size > 1024) {
    *error = "object image size must be in 32..1024 pixels";
    return false;
  }
  if (grid_step < 2 || grid_step > image_size / 2) {
    *error = "dense grid step must be in 2..image_size/2";
    return false;
  }
  if (patch_sizes.empty()) {
    *error = "at least one SIFT patch size is needed";
    return false;
  }
  for (int s : patch_sizes)
    if (s < 4 || s > image_size) {
      *error = "SIFT patch size " + std::to_string(s) + " is outside 4..image_size";
      return false;
    }
  if (pyramid_levels < 1 || pyramid_levels > 3) {
    *error = "spatial pyramid levels must be 1..3";
    return false;
  }
  if (hue_bins < 0 || saturation_bins < 0 || hue_bins > 64 || saturation_bins > 16 ||
      (hue_bins == 0) != (saturation_bins == 0)) {
    *error = "colour bins must both be 0 (no colour) or hue 1..64 and saturation 1..16";
    return false;
  }
  if (descriptor != "sift" && descriptor != "opponent-sift") {
    *error = "descriptor \"" + descriptor + "\" is not sift or opponent-sift";
    return false;
  }
  if (encoding != "bow" && encoding != "vlad" && encoding != "fisher") {
    *error = "encoding \"" + encoding + "\" is not bow, vlad or fisher";
    return false;
  }
  if (pca_dims < 8 || pca_dims > DescriptorSize(*this)) {
    *error = "PCA dimensions (fisher) must be in 8.." + std::to_string(DescriptorSize(*this));
    return false;
  }
  if (colour_statistics && encoding != "fisher") {
    *error = "colour statistics need the Fisher encoding (encoding \"fisher\")";
    return false;
  }
  if (spatial_coordinates && encoding != "fisher") {
    *error = "spatial coordinates need the Fisher encoding (encoding \"fisher\")";
    return false;
  }
  if (orientations != 1 && orientations != 2 && orientations != 4 && orientations != 8) {
    *error = "orientations must be 1, 2, 4 or 8";
    return false;
  }
  if (colour_pca_dims < 8 || colour_pca_dims > 96) {
    *error = "colour statistics PCA dimensions must be in 8..96";
    return false;
  }
  if (!(colour_weight >= 0)) {
    *error = "colour weight cannot be negative";
    return false;
  }
  return true;
}

cv::Mat ToBgr8(const cv::Mat& image) {
  cv::Mat bgr = image;
  if (bgr.depth() != CV_8U) bgr.convertTo(bgr, CV_8U, bgr.depth() == CV_16U ? 1.0 / 257 : 1.0);
  if (bgr.channels() == 1) cv::cvtColor(bgr, bgr, cv::COLOR_GRAY2BGR);
  if (bgr.channels() == 4) cv::cvtColor(bgr, bgr, cv::COLOR_BGRA2BGR);
  return bgr;
}

cv::Mat NormaliseSample(const cv::Mat& image, int image_size) {
  const cv::Mat bgr = ToBgr8(image);
  cv::Mat out;
  cv::resize(bgr, out, cv::Size(image_size, image_size), 0, 0,
             bgr.cols > image_size ? cv::INTER_AREA : cv::INTER_LINEAR);
  return out;
}

int DescriptorSize(const ObjectFeatureOptions& o) { return o.descriptor == "opponent-sift" ? 384 : 128; }

std::vector<cv::KeyPoint> DenseKeypoints(cv::Size sample, const ObjectFeatureOptions& o) {
  std::vector<cv::KeyPoint> keypoints;
  for (int size : o.patch_sizes) {
    // OpenCV's SIFT spans 4 x 4 bins of 3 sigma each, sigma = keypoint size / 2: a patch of
    // `size` pixels is a keypoint of size / 6.
    const int margin = size / 2;
    for (int y = margin; y <= sample.height - margin; y += o.grid_step)
      for (int x = margin; x <= sample.width - margin; x += o.grid_step)
        keypoints.emplace_back(static_cast<float>(x), static_cast<float>(y), size / 6.0f, 0.f);
  }
  return keypoints;
}

cv::Mat DenseDescriptors(const cv::Mat& sample, const ObjectFeatureOptions& o, const std::vector<cv::KeyPoint>& keypoints) {
  // The channels described: gray, or the three opponent colour channels (van de Sande et al.):
  // deep-sea biota differ by colour as much as by shape.
  std::vector<cv::Mat> channels;
  if (o.descriptor == "opponent-sift") {
    cv::Mat f;
    sample.convertTo(f, CV_32F);
    std::vector<cv::Mat> bgr;
    cv::split(f, bgr);
    const cv::Mat& b = bgr[0];
    const cv::Mat& g = bgr[1];
    const cv::Mat& r = bgr[2];
    cv::Mat o1 = (r - g) / std::sqrt(2.0) + 128, o2 = (r + g - 2 * b) / std::sqrt(6.0) + 128,
            o3 = (r + g + b) / std::sqrt(3.0);
    for (cv::Mat* m : {&o1, &o2, &o3}) {
      cv::Mat u8;
      m->convertTo(u8, CV_8U, m == &o3 ? 255.0 / 441.7 : 1.0);
      channels.push_back(u8);
    }
  } else {
    cv::Mat gray;
    cv::cvtColor(sample, gray, cv::COLOR_BGR2GRAY);
    channels.push_back(gray);
  }
  // Dim, low-contrast ROV footage: normalise local contrast so the gradients carry the shape.
  for (auto& c : channels) cv::createCLAHE(2.0, cv::Size(4, 4))->apply(c, c);
  std::vector<cv::Mat> parts;
  const auto sift = cv::SIFT::create();
  for (const auto& c : channels) {
    std::vector<cv::KeyPoint> k = keypoints;  // compute() may drop none at these sizes; keep order
    cv::Mat d;
    sift->compute(c, k, d);
    CV_Assert(k.size() == keypoints.size());
    parts.push_back(d);
  }
  cv::Mat desc;
  cv::hconcat(parts, desc);
  // RootSIFT per channel: Hellinger distance between descriptors as Euclidean distance.
  for (int i = 0; i < desc.rows; ++i) {
    for (int part = 0; part < desc.cols / 128; ++part) {
      float* d = desc.ptr<float>(i) + part * 128;
      double sum = 0;
      for (int k = 0; k < 128; ++k) sum += d[k];
      const float inv = sum > 0 ? static_cast<float>(1.0 / sum) : 0.f;
      for (int k = 0; k < 128; ++k) d[k] = std::sqrt(d[k] * inv);
    }
  }
  return desc;
}

std::vector<SampleView> DescribeViews(const cv::Mat& image, const ObjectFeatureOptions& o) {
  std::vector<cv::Mat> samples = {NormaliseSample(image, o.image_size)};
  if (o.object_view) samples.push_back(NormaliseSample(ObjectCrop(ToBgr8(image)), o.image_size));
  std::vector<SampleView> views;
  for (const cv::Mat& sample : samples) {
    SampleView v;
    const std::vector<cv::KeyPoint> keypoints = DenseKeypoints(sample.size(), o);
    v.descriptors = DenseDescriptors(sample, o, keypoints);
    if (o.colour_statistics) v.colour = ColourStatistics(sample, keypoints);
    if (o.hue_bins > 0) cv::cvtColor(sample, v.hsv, cv::COLOR_BGR2HSV);
    for (const auto& k : keypoints) v.where.push_back(k.pt);
    views.push_back(std::move(v));
  }
  return views;
}

cv::Mat PlaceColumns(const std::vector<cv::Point2f>& where, int image_size) {
  cv::Mat out(static_cast<int>(where.size()), 2, CV_32F);
  for (int i = 0; i < out.rows; ++i) {
    out.at<float>(i, 0) = where[static_cast<size_t>(i)].x / image_size - 0.5f;
    out.at<float>(i, 1) = where[static_cast<size_t>(i)].y / image_size - 0.5f;
  }
  return out;
}

cv::Mat BuildVocabulary(const cv::Mat& samples, int words, unsigned seed) {
  if (samples.rows < words)
    Fail("vocabulary", std::to_string(samples.rows) + " descriptors cannot make " +
                           std::to_string(words) + " words (more or larger training images needed)");
  cv::setRNGSeed(static_cast<int>(seed));
  cv::Mat labels, centres;
  cv::kmeans(samples, words, labels,
             cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 25, 1e-4), 1,
             cv::KMEANS_PP_CENTERS, centres);
  return centres;
}

BowEncoder::BowEncoder(const ObjectFeatureOptions& options, cv::Mat vocabulary, cv::Mat pca, FisherCodebook colour)
    : options_(options), vocabulary_(std::move(vocabulary)), colour_(std::move(colour)), cells_(Cells(options)) {
  std::string error;
  if (!options.IsValid(&error)) Fail("object features", error);
  if (options.encoding == "fisher") {
    fisher_.gmm = vocabulary_;
    fisher_.pca = std::move(pca);
    const int appended = options.spatial_coordinates ? 2 : 0;
    if (!fisher_.IsValid(DescriptorSize(options), appended))
      Fail("object features", "the Fisher codebook does not fit the descriptors");
    if (options.colour_statistics && !colour_.IsValid(96, appended))
      Fail("object features", "the colour statistics' Fisher codebook is missing or does not fit them");
  } else {
    CV_Assert(vocabulary_.type() == CV_32F && vocabulary_.cols == DescriptorSize(options) && vocabulary_.rows > 0);
  }
}

namespace {

void NormaliseL1(float* v, int n, float weight) {
  double sum = 0;
  for (int i = 0; i < n; ++i) sum += v[i];
  if (sum <= 0) return;
  const float k = static_cast<float>(weight / sum);
  for (int i = 0; i < n; ++i) v[i] *= k;
}

}  // namespace

std::vector<BowEncoder::Cell> BowEncoder::Cells(const ObjectFeatureOptions& o) {
  std::vector<Cell> cells;
  const float size = static_cast<float>(o.image_size);
  // Spatial pyramid: each level weighs one in total.
  for (int l = 0; l < o.pyramid_levels; ++l) {
    const int n = 1 << l;
    const float side = size / n;
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) cells.push_back({cv::Rect2f(x * side, y * side, side, side), 1.0f / (n * n), 0});
  }
  // Samples are crops centred on their object: the central half describes the object itself,
  // apart from the seafloor around it.
  if (o.centre_cell) cells.push_back({cv::Rect2f(size / 4, size / 4, size / 2, size / 2), 1.0f, 0});
  // The object's own square (see object_crop.h): the whole of it and its quarters.
  if (o.object_view) {
    cells.push_back({cv::Rect2f(0, 0, size, size), 1.0f, 1});
    for (int y = 0; y < 2; ++y)
      for (int x = 0; x < 2; ++x) cells.push_back({cv::Rect2f(x * size / 2, y * size / 2, size / 2, size / 2), 0.25f, 1});
  }
  return cells;
}

int BowEncoder::WordDims() const {
  if (options_.encoding == "fisher") return 2 * fisher_.components() * fisher_.mixture_dims();
  return options_.encoding == "vlad" ? vocabulary_.rows * vocabulary_.cols : vocabulary_.rows;
}

int BowEncoder::ColourFisherDims() const {
  return options_.colour_statistics ? 2 * colour_.components() * colour_.mixture_dims() : 0;
}

int BowEncoder::dims() const {
  return static_cast<int>(cells_.size()) * (WordDims() + ColourFisherDims() + options_.hue_bins * options_.saturation_bins);
}

// Per cell: for each component k, sum over its descriptors of p_k(x) (x - m_k) / s_k and of
// p_k(x) ((x - m_k)^2 / s_k^2 - 1), scaled by 1 / sqrt(w_k) and 1 / sqrt(2 w_k).
void BowEncoder::FisherStatistics(const FisherCodebook& book, const cv::Mat& x, const std::vector<cv::Point2f>& where,
                                  int view, float* v, int stride) const {
  const cv::Mat post = book.Posteriors(x);
  const int d = x.cols, K = book.components();
  std::vector<float> u(static_cast<size_t>(d));
  std::vector<int> in;
  for (int i = 0; i < x.rows; ++i) {
    in.clear();
    for (int c = 0; c < static_cast<int>(cells_.size()); ++c)
      if (cells_[static_cast<size_t>(c)].view == view && cells_[static_cast<size_t>(c)].rect.contains(where[static_cast<size_t>(i)]))
        in.push_back(c);
    const float* xi = x.ptr<float>(i);
    const float* p = post.ptr<float>(i);
    for (int k = 0; k < K; ++k) {
      if (p[k] < 1e-4f) continue;  // the posteriors are peaked: most components see nothing
      const float* g = book.gmm.ptr<float>(k);
      const float a = p[k] / std::sqrt(g[2 * d]), b = p[k] / std::sqrt(2 * g[2 * d]);
      for (int j = 0; j < d; ++j) u[static_cast<size_t>(j)] = (xi[j] - g[j]) / std::sqrt(g[d + j]);
      for (int c : in) {
        float* mu = v + c * stride + k * 2 * d;
        float* sigma = mu + d;
        for (int j = 0; j < d; ++j) {
          const float t = u[static_cast<size_t>(j)];
          mu[j] += a * t;
          sigma[j] += b * (t * t - 1);
        }
      }
    }
  }
}

namespace {

void SignedSqrt(float* v, int n) {
  for (int k = 0; k < n; ++k) v[k] = v[k] >= 0 ? std::sqrt(v[k]) : -std::sqrt(-v[k]);
}

// Scales v to an L2 norm of `norm` (zero stays zero).
void NormaliseL2(float* v, int n, float norm) {
  double n2 = 0;
  for (int k = 0; k < n; ++k) n2 += double(v[k]) * v[k];
  const float s = n2 > 0 ? static_cast<float>(norm / std::sqrt(n2)) : 0.f;
  for (int k = 0; k < n; ++k) v[k] *= s;
}

}  // namespace

std::vector<int> BowEncoder::Orientations() const {
  switch (options_.orientations) {
    case 2: return {0, 4};
    case 4: return {0, 1, 2, 3};
    case 8: return {0, 1, 2, 3, 4, 5, 6, 7};
    default: return {0};
  }
}

cv::Mat BowEncoder::Spatial(const cv::Mat& projected, const std::vector<cv::Point2f>& where) const {
  if (!options_.spatial_coordinates) return projected;
  cv::Mat out;
  cv::hconcat(projected, PlaceColumns(where, options_.image_size), out);
  return out;
}

cv::Mat BowEncoder::Encode(const cv::Mat& image) const {
  const std::vector<SampleView> views = DescribeViews(image, options_);
  const std::vector<int> orientations = Orientations();
  cv::Mat out = cv::Mat::zeros(1, dims(), CV_32F);
  for (int t : orientations) {
    cv::Mat one = cv::Mat::zeros(1, dims(), CV_32F);
    EncodeInto(views, DihedralTransform(t), one.ptr<float>());
    out += one;
  }
  if (orientations.size() == 1) return out;
  // The average, each part scaled back to its weight: histograms are L1-normalised already,
  // the vector parts are L2-normalised again.
  out *= 1.0 / orientations.size();
  if (options_.encoding == "bow") return out;
  float* v = out.ptr<float>();
  const int cells = static_cast<int>(cells_.size()), words = WordDims(), colour = ColourFisherDims();
  for (int c = 0; c < cells; ++c) {
    NormaliseL2(v + c * words, words, cells_[static_cast<size_t>(c)].weight);
    if (colour > 0) NormaliseL2(v + cells * words + c * colour, colour, cells_[static_cast<size_t>(c)].weight);
  }
  return out;
}

void BowEncoder::EncodeInto(const std::vector<SampleView>& views, const DihedralTransform& turn, float* v) const {
  const bool vlad = options_.encoding == "vlad", fisher = options_.encoding == "fisher";
  const int dim = vocabulary_.cols;
  const int words = WordDims(), cells = static_cast<int>(cells_.size()), colour = ColourFisherDims();
  const int colours = options_.hue_bins * options_.saturation_bins;
  const float side = static_cast<float>(options_.image_size);
  float* colour_v = v + cells * words;
  float* hist = colour_v + cells * colour;
  for (int view = 0; view < static_cast<int>(views.size()); ++view) {
    const SampleView& in = views[static_cast<size_t>(view)];
    // Positions are pixel indices; their centres turn with the sample.
    std::vector<cv::Point2f> where(in.where.size());
    for (size_t i = 0; i < where.size(); ++i)
      where[i] = turn.Point(in.where[i] + cv::Point2f(0.5f, 0.5f), side) - cv::Point2f(0.5f, 0.5f);
    const cv::Mat desc = turn.Sift(in.descriptors);
    std::vector<cv::DMatch> nearest;
    if (fisher)
      FisherStatistics(fisher_, Spatial(fisher_.Project(desc), where), where, view, v, words);
    else
      cv::BFMatcher(cv::NORM_L2).match(desc, vocabulary_, nearest);
    if (colour > 0)
      FisherStatistics(colour_, Spatial(colour_.Project(turn.ColourStatistics(in.colour)), where), where, view, colour_v, colour);
    for (const auto& m : nearest) {
      const cv::Point2f p = where[static_cast<size_t>(m.queryIdx)];
      for (int c = 0; c < cells; ++c) {
        if (cells_[static_cast<size_t>(c)].view != view || !cells_[static_cast<size_t>(c)].rect.contains(p)) continue;
        if (!vlad) {
          v[c * words + m.trainIdx] += 1.f;
          continue;
        }
        // VLAD: the descriptor's residual to its word, summed per word.
        float* r = v + c * words + m.trainIdx * dim;
        const float* d = desc.ptr<float>(m.queryIdx);
        const float* w = vocabulary_.ptr<float>(m.trainIdx);
        for (int k = 0; k < dim; ++k) r[k] += d[k] - w[k];
      }
    }
    // Colour histograms: hue and saturation, weighted by value (the hue of dark pixels is noise).
    for (int y = 0; colours > 0 && y < in.hsv.rows; ++y) {
      const cv::Vec3b* p = in.hsv.ptr<cv::Vec3b>(y);
      for (int x = 0; x < in.hsv.cols; ++x) {
        const int h = std::min(options_.hue_bins - 1, p[x][0] * options_.hue_bins / 180);
        const int s = std::min(options_.saturation_bins - 1, p[x][1] * options_.saturation_bins / 256);
        const cv::Point2f at = turn.Point(cv::Point2f(x + 0.5f, y + 0.5f), side);
        for (int c = 0; c < cells; ++c)
          if (cells_[static_cast<size_t>(c)].view == view && cells_[static_cast<size_t>(c)].rect.contains(at))
            hist[c * colours + h * options_.saturation_bins + s] += p[x][2] / 255.f;
      }
    }
  }
  for (int c = 0; c < cells; ++c) {
    float* block = v + c * words;
    const float weight = cells_[static_cast<size_t>(c)].weight;
    if (colours > 0) NormaliseL1(hist + c * colours, colours, static_cast<float>(options_.colour_weight) * weight);
    if (!vlad && !fisher) {
      NormaliseL1(block, words, weight);
      continue;
    }
    // VLAD: intra-normalisation per word; both: signed square root, then L2 over the cell.
    for (int w = 0; w < (vlad ? vocabulary_.rows : 0); ++w) {
      NormaliseL2(block + w * dim, dim, 1.f);
      SignedSqrt(block + w * dim, dim);
    }
    if (fisher) SignedSqrt(block, words);
    NormaliseL2(block, words, weight);
    if (colour > 0) {
      SignedSqrt(colour_v + c * colour, colour);
      NormaliseL2(colour_v + c * colour, colour, weight);
    }
  }
}

}  // namespace rolamos
