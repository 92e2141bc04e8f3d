// Still frames from JPEG files, decoded by libjpeg-turbo straight into OpenCV's blue-green-red
// order. cv::imread has libjpeg decode into red-green-blue and then swaps each pixel's bytes
// one at a time: that swap alone was 3.7 % of all the CPU a still took at 800 x 600
// (bench/RESULTS.md, session 33). libjpeg-turbo converts from YCbCr into either order with the
// same arithmetic, so the pixels are cv::imread's (tests).
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace rolamos {

// Decodes the JPEG file `path` into *image (CV_8UC3, BGR), as cv::imread(path, IMREAD_COLOR)
// would. Only the common kind is decoded here: three YCbCr components, upright (no EXIF
// orientation, or 1). Anything else (grey, CMYK, an EXIF turn cv::imread applies, a file libjpeg
// cannot decode or that is not a JPEG) returns false with *image empty: the caller decodes it
// with cv::imread, which reads every kind and says what is wrong with a bad one.
bool ReadJpegBgr(const std::string& path, cv::Mat* image);
// The same from a JPEG file's bytes, already read.
bool DecodeJpegBgr(const std::string& bytes, cv::Mat* image);

// The EXIF orientation (1-8) in an APP1 marker's payload ("Exif\0\0" and a TIFF header), 1 when
// the payload is EXIF without an orientation, 0 when it is not EXIF or does not parse.
int ExifOrientation(const unsigned char* data, size_t size);

}  // namespace rolamos
