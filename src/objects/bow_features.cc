#include "objects/bow_features.h"

#include <cmath>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

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

cv::Mat DenseDescriptors(const cv::Mat& sample, const ObjectFeatureOptions& o,
                         std::vector<cv::Point2f>* positions) {
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
  std::vector<cv::KeyPoint> keypoints;
  for (int size : o.patch_sizes) {
    // OpenCV's SIFT spans 4 x 4 bins of 3 sigma each, sigma = keypoint size / 2: a patch of
    // `size` pixels is a keypoint of size / 6.
    const int margin = size / 2;
    for (int y = margin; y <= sample.rows - margin; y += o.grid_step)
      for (int x = margin; x <= sample.cols - margin; x += o.grid_step)
        keypoints.emplace_back(static_cast<float>(x), static_cast<float>(y), size / 6.0f, 0.f);
  }
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
  if (positions) {
    positions->clear();
    for (const auto& k : keypoints) positions->push_back(k.pt);
  }
  return desc;
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

BowEncoder::BowEncoder(const ObjectFeatureOptions& options, cv::Mat vocabulary, cv::Mat pca)
    : options_(options), vocabulary_(std::move(vocabulary)), cells_(Cells(options)) {
  std::string error;
  if (!options.IsValid(&error)) Fail("object features", error);
  if (options.encoding == "fisher") {
    fisher_.gmm = vocabulary_;
    fisher_.pca = std::move(pca);
    if (!fisher_.IsValid(DescriptorSize(options))) Fail("object features", "the Fisher codebook does not fit the descriptors");
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
  if (options_.encoding == "fisher") return 2 * fisher_.components() * fisher_.dims();
  return options_.encoding == "vlad" ? vocabulary_.rows * vocabulary_.cols : vocabulary_.rows;
}

int BowEncoder::dims() const {
  return static_cast<int>(cells_.size()) * (WordDims() + options_.hue_bins * options_.saturation_bins);
}

// Per cell: for each component k, sum over its descriptors of p_k(x) (x - m_k) / s_k and of
// p_k(x) ((x - m_k)^2 / s_k^2 - 1), scaled by 1 / sqrt(w_k) and 1 / sqrt(2 w_k).
void BowEncoder::FisherStatistics(const cv::Mat& desc, const std::vector<cv::Point2f>& where, int view, float* v) const {
  const cv::Mat x = fisher_.Project(desc);
  const cv::Mat post = fisher_.Posteriors(x);
  const int d = fisher_.dims(), K = fisher_.components(), words = WordDims();
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
      const float* g = fisher_.gmm.ptr<float>(k);
      const float a = p[k] / std::sqrt(g[2 * d]), b = p[k] / std::sqrt(2 * g[2 * d]);
      for (int j = 0; j < d; ++j) u[static_cast<size_t>(j)] = (xi[j] - g[j]) / std::sqrt(g[d + j]);
      for (int c : in) {
        float* mu = v + c * words + k * 2 * d;
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

cv::Mat BowEncoder::Encode(const cv::Mat& image) const {
  const bool vlad = options_.encoding == "vlad", fisher = options_.encoding == "fisher";
  const int dim = vocabulary_.cols;
  const int words = WordDims(), cells = static_cast<int>(cells_.size());
  const int colours = options_.hue_bins * options_.saturation_bins;
  cv::Mat out = cv::Mat::zeros(1, dims(), CV_32F);
  float* v = out.ptr<float>();
  // The views described: the whole sample, and (object_view) the square around its object.
  std::vector<cv::Mat> samples = {NormaliseSample(image, options_.image_size)};
  if (options_.object_view) samples.push_back(NormaliseSample(ObjectCrop(ToBgr8(image)), options_.image_size));
  for (int view = 0; view < static_cast<int>(samples.size()); ++view) {
    std::vector<cv::Point2f> where;
    const cv::Mat desc = DenseDescriptors(samples[static_cast<size_t>(view)], options_, &where);
    std::vector<cv::DMatch> nearest;
    if (fisher)
      FisherStatistics(desc, where, view, v);
    else
      cv::BFMatcher(cv::NORM_L2).match(desc, vocabulary_, nearest);
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
  }
  for (int c = 0; c < cells; ++c) {
    float* block = v + c * words;
    if (!vlad && !fisher) {
      NormaliseL1(block, words, cells_[static_cast<size_t>(c)].weight);
      continue;
    }
    // VLAD: intra-normalisation per word; both: signed square root, then L2 over the cell.
    for (int w = 0; w < (vlad ? vocabulary_.rows : 0); ++w) {
      float* r = block + w * dim;
      double n2 = 0;
      for (int k = 0; k < dim; ++k) n2 += double(r[k]) * r[k];
      const float inv = n2 > 0 ? static_cast<float>(1.0 / std::sqrt(n2)) : 0.f;
      for (int k = 0; k < dim; ++k) {
        const float x = r[k] * inv;
        r[k] = x >= 0 ? std::sqrt(x) : -std::sqrt(-x);
      }
    }
    if (fisher)
      for (int k = 0; k < words; ++k) block[k] = block[k] >= 0 ? std::sqrt(block[k]) : -std::sqrt(-block[k]);
    double n2 = 0;
    for (int k = 0; k < words; ++k) n2 += double(block[k]) * block[k];
    const float k2 = n2 > 0 ? static_cast<float>(cells_[static_cast<size_t>(c)].weight / std::sqrt(n2)) : 0.f;
    for (int k = 0; k < words; ++k) block[k] *= k2;
  }
  if (colours > 0) {
    float* col = v + cells * words;
    for (int view = 0; view < static_cast<int>(samples.size()); ++view) {
      cv::Mat hsv;
      cv::cvtColor(samples[static_cast<size_t>(view)], hsv, cv::COLOR_BGR2HSV);
      for (int y = 0; y < hsv.rows; ++y) {
        const cv::Vec3b* p = hsv.ptr<cv::Vec3b>(y);
        for (int x = 0; x < hsv.cols; ++x) {
          const int h = std::min(options_.hue_bins - 1, p[x][0] * options_.hue_bins / 180);
          const int s = std::min(options_.saturation_bins - 1, p[x][1] * options_.saturation_bins / 256);
          const float w = p[x][2] / 255.f;  // weighted by value: the hue of dark pixels is noise
          const cv::Point2f at(x + 0.5f, y + 0.5f);
          for (int c = 0; c < cells; ++c)
            if (cells_[static_cast<size_t>(c)].view == view && cells_[static_cast<size_t>(c)].rect.contains(at))
              col[c * colours + h * options_.saturation_bins + s] += w;
        }
      }
    }
    for (int c = 0; c < cells; ++c)
      NormaliseL1(col + c * colours, colours, static_cast<float>(options_.colour_weight) * cells_[static_cast<size_t>(c)].weight);
  }
  return out;
}

}  // namespace rolamos
