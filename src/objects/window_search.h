// The sliding-window search shared by training and detection: the pyramid of scales, a level's
// cell map, the box a window stands for, and every window's linear score.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "objects/cell_features.h"

namespace rolamos {

// A window is kWindowPixels square at its level; the box it stands for is its central
// kBoxPixels (one cell of context on each side).
inline constexpr int kBoxPixels = 32;
inline constexpr int kWindowPixels = 48;

struct WindowSearch {
  std::string features = "cells";  // cells or hog
  double min_box = 18, max_box = 200;
  int scales_per_octave = 4;

  int WindowCells() const { return features == "hog" ? 5 : 6; }
  int Dims() const { return WindowCells() * WindowCells() * (features == "hog" ? 36 : kCellDims); }
  // Level scales (level pixels per image pixel), largest first: a box of min_box pixels is
  // kBoxPixels at the first, max_box at the last.
  std::vector<double> Scales() const;
  // The level's description (gray: one channel, 8 or 16 bits or float 0..1, image pixels).
  CellMap Describe(const cv::Mat& gray, double scale) const;
  // Image pixels of the box of the window whose first cell is (r, c).
  static cv::Rect2d Box(const CellMap& map, int r, int c, double scale);
  // The window's vector (Dims() floats).
  void Vector(const CellMap& map, int r, int c, float* out) const;
  // Every window's score, (rows - cells + 1) x (cols - cells + 1), CV_32F; empty when the level
  // is smaller than a window.
  cv::Mat Scores(const CellMap& map, const std::vector<float>& weights, double bias) const;
};

double BoxIou(const cv::Rect2d& a, const cv::Rect2d& b);
// Gray, same depth, from BGR, BGRA or gray.
cv::Mat ToGray(const cv::Mat& image);

}  // namespace rolamos
