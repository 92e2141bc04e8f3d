// Pixel layouts and codecs shared by the writer, the reader and the CLI.
#pragma once

#include <string>
#include <vector>

namespace rolamos {

// kJpegMask: JPEG (YCbCr 4:2:0) for the colour, and an image's alpha, if it has one, as a
// 1-bit transparency mask per level (GDAL's internal masks): a tile encodes 8 times faster than
// WebP's (effort 0); at quality 85 the engine's patches are 0-16 % larger than WebP at 90, as
// close to the lossless blend at level 0. kJpeg keeps alpha as a fourth JPEG sample.
enum class Compression { kNone, kJpeg, kDeflate, kZstd, kWebp, kJpegMask };

// Accepts "none", "jpeg", "deflate", "zstd", "webp", "jpeg-mask" (case-insensitive). Returns
// false otherwise.
bool ParseCompression(const std::string& name, Compression* out);
std::string CompressionName(Compression c);
std::vector<std::string> CompressionNames();
bool IsLossless(Compression c);

// Pixels as the library hands them around: cv::Mat in OpenCV's channel order (gray, gray+alpha,
// BGR, BGRA), 8 or 16 bits per sample. Files store RGB order; the conversion happens at the file.
struct PixelLayout {
  long long width = 0;
  long long height = 0;
  int channels = 3;  // 1 gray, 2 gray+alpha, 3 colour, 4 colour+alpha
  int bits = 8;      // 8 or 16

  bool HasAlpha() const { return channels == 2 || channels == 4; }
  int CvType() const;  // CV_8UC3 and so on
  bool IsValid(std::string* error) const;
};

}  // namespace rolamos
