// Homographies as the store keeps them (9 numbers, row-major) and as OpenCV computes with them,
// and the bounding box of an image warped by one. Shared by the engine and the tiles side.
#pragma once

#include <array>

#include <opencv2/core.hpp>

namespace rolamos {

cv::Matx33d ToMatx(const std::array<double, 9>& h);
// Normalised so that the last element is 1.
std::array<double, 9> ToArray9(const cv::Matx33d& m);
// Where H takes the point p.
cv::Point2d ApplyHomography(const cv::Matx33d& H, cv::Point2d p);
// How H stretches the plane around p (its Jacobian there).
cv::Matx22d HomographyJacobian(const cv::Matx33d& H, cv::Point2d p);
// How many times larger H draws the centre of an image of `size` (the square root of the area
// ratio there): below 1, the image is drawn smaller than it was taken.
double CentreScale(const cv::Matx33d& H, cv::Size size);
// Bounding box of an image of `size` (pixel edges, -0.5 .. size - 0.5) mapped by H.
cv::Rect2d WarpedBounds(const cv::Matx33d& H, cv::Size size);
// The largest distance between where `a` and `b` put the corners of an image of `size`.
double MaxCornerShift(const cv::Matx33d& a, const cv::Matx33d& b, cv::Size size);
// The homography that puts each corner of an image of `size` at `weight_a` of the way from where
// `b` puts it to where `a` does: two placements of one image averaged.
cv::Matx33d BlendHomographies(const cv::Matx33d& a, const cv::Matx33d& b, double weight_a, cv::Size size);

}  // namespace rolamos
