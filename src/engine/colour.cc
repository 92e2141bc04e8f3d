#include "engine/colour.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/area_resize.h"
#include "rolamos/error.hpp"

namespace rolamos {

bool ColourOptions::IsValid(std::string* error) const {
  if (degree < 0 || degree > 8 || freeze_frames < 4 || !(exposure_prior > 0)) {
    *error = "colour settings are out of range (polynomial degree 0..8, freeze after at least 4 frames)";
    return false;
  }
  return true;
}

namespace {

constexpr double kMinLevel = 2.0;  // grey levels: darker pixels carry no lighting information

// The polynomial's terms x^i y^j, i + j <= degree, at (x, y) in [-1, 1].
std::vector<double> Terms(double x, double y, int degree) {
  std::vector<double> t;
  for (int i = 0; i <= degree; ++i)
    for (int j = 0; i + j <= degree; ++j) t.push_back(std::pow(x, i) * std::pow(y, j));
  return t;
}

}  // namespace

ColourModel::ColourModel(const ColourOptions& options) : options_(options) {
  std::string error;
  if (!options.IsValid(&error)) Fail("colour", error);
  log_sum_ = cv::Mat::zeros(grid_, CV_64FC3);
  count_ = cv::Mat::zeros(grid_, CV_64F);
}

void ColourModel::Add(const cv::Mat& frame, const cv::Mat& usable) {
  if (frozen() || frame.empty()) return;
  CV_Assert(frame.type() == CV_8UC3);
  // Through a quarter-size copy (an integer reduction, OpenCV's fast path): half the time of
  // reducing the frame to the grid at once, the same cells within one grey level.
  cv::Mat quarter, quarter_ok, small, ok;
  const cv::Size q(std::max(grid_.width, frame.cols / 4), std::max(grid_.height, frame.rows / 4));
  ResizeArea(frame, quarter, q);
  cv::resize(quarter, small, grid_, 0, 0, cv::INTER_AREA);
  if (!usable.empty()) {
    ResizeArea(usable, quarter_ok, q);
    cv::resize(quarter_ok, ok, grid_, 0, 0, cv::INTER_AREA);
  }
  // Saturated cells say nothing about the lighting either.
  for (int y = 0; y < grid_.height; ++y)
    for (int x = 0; x < grid_.width; ++x) {
      const cv::Vec3b p = small.at<cv::Vec3b>(y, x);
      if (!ok.empty() && ok.at<uchar>(y, x) < 250) continue;
      if (std::max({p[0], p[1], p[2]}) >= 250) continue;
      cv::Vec3d& s = log_sum_.at<cv::Vec3d>(y, x);
      for (int c = 0; c < 3; ++c) s[c] += std::log(std::max(kMinLevel, double(p[c])));
      count_.at<double>(y, x) += 1;
    }
  const cv::Scalar m = usable.empty() ? cv::mean(quarter) : cv::mean(quarter, quarter_ok == 255);
  for (int c = 0; c < 3; ++c) mean_sum_[size_t(c)] += m[c];
  ++frames_;
}

void ColourModel::Fit() const {
  if (fitted_at_ == frames_) return;
  fitted_at_ = frames_;
  coefficients_.clear();
  balance_ = {1, 1, 1};
  if (frames_ < 8) return;
  // Lighting: log brightness of each cell over the frames, less its channel's mean, fitted by a
  // smooth polynomial (what is left of the seafloor's own texture averages out).
  const int terms = static_cast<int>(Terms(0, 0, options_.degree).size());
  std::vector<std::vector<double>> rows;
  std::vector<cv::Vec3d> values;
  std::vector<double> weights;
  for (int y = 0; y < grid_.height; ++y)
    for (int x = 0; x < grid_.width; ++x) {
      const double n = count_.at<double>(y, x);
      if (n < 3) continue;
      rows.push_back(Terms(2.0 * (x + 0.5) / grid_.width - 1, 2.0 * (y + 0.5) / grid_.height - 1, options_.degree));
      values.push_back(log_sum_.at<cv::Vec3d>(y, x) / n);
      weights.push_back(std::sqrt(n));
    }
  if (options_.lighting && static_cast<int>(rows.size()) > 2 * terms) {
    Eigen::MatrixXd A(rows.size(), terms);
    Eigen::MatrixXd b(rows.size(), 3);
    for (size_t r = 0; r < rows.size(); ++r) {
      for (int k = 0; k < terms; ++k) A(Eigen::Index(r), k) = weights[r] * rows[r][size_t(k)];
      for (int c = 0; c < 3; ++c) b(Eigen::Index(r), c) = weights[r] * values[r][c];
    }
    const Eigen::MatrixXd x = A.colPivHouseholderQr().solve(b);
    coefficients_.assign(size_t(terms), {0, 0, 0});
    for (int k = 0; k < terms; ++k)
      for (int c = 0; c < 3; ++c) coefficients_[size_t(k)][size_t(c)] = x(k, c);
    // The constant term is the channel's level, not lighting: the correction keeps the level.
    coefficients_[0] = {0, 0, 0};
  }
  // Water colour: the survey's mean colour made grey, within bounds (a seafloor of one colour
  // keeps most of it), and only against a clear cast.
  if (options_.water_colour) {
    std::array<double, 3> mean{};
    for (int c = 0; c < 3; ++c) mean[size_t(c)] = std::max(1.0, mean_sum_[size_t(c)] / frames_);
    const double grey = (mean[0] + mean[1] + mean[2]) / 3;
    const double cast = *std::max_element(mean.begin(), mean.end()) / *std::min_element(mean.begin(), mean.end());
    if (cast > 1.15)
      for (int c = 0; c < 3; ++c) balance_[size_t(c)] = std::clamp(grey / mean[size_t(c)], 0.6, 2.5);
  }
}

cv::Mat ColourModel::Correction(cv::Size frame) const {
  Fit();
  cv::Mat small(grid_, CV_32FC3, cv::Scalar::all(1));
  if (!coefficients_.empty()) {
    for (int y = 0; y < grid_.height; ++y)
      for (int x = 0; x < grid_.width; ++x) {
        const auto t = Terms(2.0 * (x + 0.5) / grid_.width - 1, 2.0 * (y + 0.5) / grid_.height - 1, options_.degree);
        cv::Vec3f& v = small.at<cv::Vec3f>(y, x);
        for (int c = 0; c < 3; ++c) {
          double p = 0;
          for (size_t k = 0; k < t.size(); ++k) p += coefficients_[k][size_t(c)] * t[k];
          v[c] = static_cast<float>(std::clamp(std::exp(-p), 0.25, 4.0));
        }
      }
  }
  cv::Mat out;
  cv::resize(small, out, frame, 0, 0, cv::INTER_CUBIC);
  out = cv::max(out, 0.2);
  cv::multiply(out, cv::Scalar(balance_[0], balance_[1], balance_[2]), out);
  return out;
}

std::string ColourModel::ToJson() const {
  Fit();
  nlohmann::json j = {{"format", "rolamos-lighting"}, {"version", 1}, {"frames", frames_},
                      {"degree", options_.degree}, {"white_balance", balance_}};
  nlohmann::json c = nlohmann::json::array();
  for (const auto& k : coefficients_) c.push_back(k);
  j["coefficients"] = c;  // per term x^i y^j (i outer, j inner, i + j <= degree): log brightness, BGR
  return j.dump(1) + "\n";
}

ColourModel ColourModel::FromJson(const std::string& text, const ColourOptions& options, const std::string& where) {
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || j.value("format", "") != "rolamos-lighting") Fail(where, "is not a rolamos lighting file");
  ColourOptions o = options;
  try {
    o.degree = j.at("degree").get<int>();
    ColourModel m(o);
    m.frames_ = std::max(o.freeze_frames, j.at("frames").get<int>());  // frozen as written
    for (const auto& k : j.at("coefficients")) m.coefficients_.push_back({k.at(0), k.at(1), k.at(2)});
    for (int c = 0; c < 3; ++c) m.balance_[size_t(c)] = j.at("white_balance").at(size_t(c)).get<double>();
    if (!m.coefficients_.empty() && m.coefficients_.size() != Terms(0, 0, o.degree).size())
      Fail(where, "has " + std::to_string(m.coefficients_.size()) + " coefficients for degree " + std::to_string(o.degree));
    m.fitted_at_ = m.frames_;
    return m;
  } catch (const nlohmann::json::exception& e) {
    Fail(where, std::string("malformed lighting: ") + e.what());
  }
}

}  // namespace rolamos
