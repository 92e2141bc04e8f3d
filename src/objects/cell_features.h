// Descriptions of an image on a grid of 8-pixel cells, for sliding-window detection: a window is
// the concatenation of a square of cells, so every window of a level shares one computation.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace rolamos {

// rows x cols cells of `dims` floats each, row-major and contiguous. Cell (r, c) covers the
// pixels [cell * c - origin, cell * (c + 1) - origin) of the image it describes (same for rows).
struct CellMap {
  int rows = 0, cols = 0, dims = 0;
  int cell = 8, origin = 0;
  std::vector<float> data;
  const float* at(int r, int c) const { return data.data() + (static_cast<size_t>(r) * cols + c) * dims; }
};

// Ours, 33 numbers per cell: the image is first divided by its local brightness and contrast
// (Gaussian, sigma 3 cells), so vignetting and light cones leave the description unchanged; then
// Felzenszwalb et al.'s 31 HOG numbers (18 signed and 9 unsigned orientation bins, each
// normalised by the cell's four 2 x 2-cell neighbourhoods and clipped at 0.2, and 4 gradient
// energies): a burrow is a dark opening, and the signed bins say which side is dark; and the
// cell's mean and spread of normalised brightness. The image is padded by one cell (mirrored), so
// origin = cell. `gray`: one channel, CV_8U, CV_16U or CV_32F (0..1).
CellMap DescribeCells(const cv::Mat& gray);
inline constexpr int kCellDims = 33;

// The peer: OpenCV's HOGDescriptor (Dalal and Triggs: 16-pixel blocks of 2 x 2 cells of 9 bins,
// L2-Hys) computed every 8 pixels; a "cell" here is one block, 36 numbers, and a window of 5 x 5
// blocks covers the same 48 pixels as ours. Padded by one cell like DescribeCells.
CellMap DescribeHogBlocks(const cv::Mat& gray8);

}  // namespace rolamos
