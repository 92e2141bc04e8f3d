#include "objects/bow_features.h"

#include <cmath>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

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
  if (encoding != "bow" && encoding != "vlad") {
    *error = "encoding \"" + encoding + "\" is not bow or vlad";
    return false;
  }
  if (!(colour_weight >= 0)) {
    *error = "colour weight cannot be negative";
    return false;
  }
  return true;
}

cv::Mat NormaliseSample(const cv::Mat& image, int image_size) {
  cv::Mat bgr = image;
  if (bgr.depth() != CV_8U) bgr.convertTo(bgr, CV_8U, bgr.depth() == CV_16U ? 1.0 / 257 : 1.0);
  if (bgr.channels() == 1) cv::cvtColor(bgr, bgr, cv::COLOR_GRAY2BGR);
  if (bgr.channels() == 4) cv::cvtColor(bgr, bgr, cv::COLOR_BGRA2BGR);
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

BowEncoder::BowEncoder(const ObjectFeatureOptions& options, cv::Mat vocabulary)
    : options_(options), vocabulary_(std::move(vocabulary)), cells_(Cells(options)) {
  std::string error;
  if (!options.IsValid(&error)) Fail("object features", error);
  CV_Assert(vocabulary_.type() == CV_32F && vocabulary_.cols == DescriptorSize(options) && vocabulary_.rows > 0);
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
      for (int x = 0; x < n; ++x) cells.push_back({cv::Rect2f(x * side, y * side, side, side), 1.0f / (n * n)});
  }
  // Samples are crops centred on their object: the central half describes the object itself,
  // apart from the seafloor around it.
  if (o.centre_cell) cells.push_back({cv::Rect2f(size / 4, size / 4, size / 2, size / 2), 1.0f});
  return cells;
}

int BowEncoder::dims() const {
  const int words = options_.encoding == "vlad" ? vocabulary_.rows * vocabulary_.cols : vocabulary_.rows;
  return static_cast<int>(cells_.size()) * (words + options_.hue_bins * options_.saturation_bins);
}

cv::Mat BowEncoder::Encode(const cv::Mat& image) const {
  const cv::Mat sample = NormaliseSample(image, options_.image_size);
  std::vector<cv::Point2f> where;
  const cv::Mat desc = DenseDescriptors(sample, options_, &where);
  const bool vlad = options_.encoding == "vlad";
  const int dim = vocabulary_.cols;
  const int words = vlad ? vocabulary_.rows * dim : vocabulary_.rows, cells = static_cast<int>(cells_.size());
  const int colours = options_.hue_bins * options_.saturation_bins;
  cv::Mat out = cv::Mat::zeros(1, dims(), CV_32F);
  float* v = out.ptr<float>();
  std::vector<cv::DMatch> nearest;
  cv::BFMatcher(cv::NORM_L2).match(desc, vocabulary_, nearest);
  for (const auto& m : nearest) {
    const cv::Point2f p = where[static_cast<size_t>(m.queryIdx)];
    for (int c = 0; c < cells; ++c) {
      if (!cells_[static_cast<size_t>(c)].rect.contains(p)) continue;
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
  for (int c = 0; c < cells; ++c) {
    float* block = v + c * words;
    if (!vlad) {
      NormaliseL1(block, words, cells_[static_cast<size_t>(c)].weight);
      continue;
    }
    // Intra-normalisation per word, signed square root, then L2 over the cell.
    for (int w = 0; w < vocabulary_.rows; ++w) {
      float* r = block + w * dim;
      double n2 = 0;
      for (int k = 0; k < dim; ++k) n2 += double(r[k]) * r[k];
      const float inv = n2 > 0 ? static_cast<float>(1.0 / std::sqrt(n2)) : 0.f;
      for (int k = 0; k < dim; ++k) {
        const float x = r[k] * inv;
        r[k] = x >= 0 ? std::sqrt(x) : -std::sqrt(-x);
      }
    }
    double n2 = 0;
    for (int k = 0; k < words; ++k) n2 += double(block[k]) * block[k];
    const float k2 = n2 > 0 ? static_cast<float>(cells_[static_cast<size_t>(c)].weight / std::sqrt(n2)) : 0.f;
    for (int k = 0; k < words; ++k) block[k] *= k2;
  }
  if (colours > 0) {
    cv::Mat hsv;
    cv::cvtColor(sample, hsv, cv::COLOR_BGR2HSV);
    float* col = v + cells * words;
    for (int y = 0; y < hsv.rows; ++y) {
      const cv::Vec3b* p = hsv.ptr<cv::Vec3b>(y);
      for (int x = 0; x < hsv.cols; ++x) {
        const int h = std::min(options_.hue_bins - 1, p[x][0] * options_.hue_bins / 180);
        const int s = std::min(options_.saturation_bins - 1, p[x][1] * options_.saturation_bins / 256);
        const float w = p[x][2] / 255.f;  // weighted by value: the hue of dark pixels is noise
        const cv::Point2f at(x + 0.5f, y + 0.5f);
        for (int c = 0; c < cells; ++c)
          if (cells_[static_cast<size_t>(c)].rect.contains(at)) col[c * colours + h * options_.saturation_bins + s] += w;
      }
    }
    for (int c = 0; c < cells; ++c)
      NormaliseL1(col + c * colours, colours, static_cast<float>(options_.colour_weight) * cells_[static_cast<size_t>(c)].weight);
  }
  return out;
}

}  // namespace rolamos
