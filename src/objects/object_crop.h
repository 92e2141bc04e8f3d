// Where the object is in a sample: the crops are centred on an object that often fills a tenth of
// them, at any size. Describing only the fixed grid of the whole crop mixes the object's few
// descriptors with the seafloor's many, at whatever scale it was filmed. This finds the blob that
// stands out from the seafloor near the centre (colour distance from a heavily blurred copy,
// weighted towards the centre) and returns a square around it, so that the object is described
// at a normalised size.
#pragma once

#include <opencv2/core.hpp>

namespace rolamos {

// The square region (in `image` pixels, possibly reaching past its borders) around the most
// salient blob near the centre, `margin` times its larger side.
cv::Rect ObjectBox(const cv::Mat& bgr, double margin = 1.6);

// That region's pixels (edges replicated where it leaves the image).
cv::Mat ObjectCrop(const cv::Mat& bgr, double margin = 1.6);

}  // namespace rolamos
