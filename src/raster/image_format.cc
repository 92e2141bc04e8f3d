#include "rolamos/image_format.hpp"

#include <opencv2/core.hpp>

#include "util/files.h"

namespace rolamos {
namespace {

struct CodecName {
  Compression c;
  const char* name;
};
constexpr CodecName kCodecs[] = {{Compression::kNone, "none"},
                                 {Compression::kJpeg, "jpeg"},
                                 {Compression::kDeflate, "deflate"},
                                 {Compression::kZstd, "zstd"},
                                 {Compression::kWebp, "webp"},
                                 {Compression::kJpegMask, "jpeg-mask"}};

}  // namespace

bool ParseCompression(const std::string& name, Compression* out) {
  std::string n = ToLower(name);
  if (n == "jpg") n = "jpeg";
  if (n == "zip") n = "deflate";
  for (const auto& c : kCodecs) {
    if (n == c.name) {
      *out = c.c;
      return true;
    }
  }
  return false;
}

std::string CompressionName(Compression c) {
  for (const auto& k : kCodecs)
    if (k.c == c) return k.name;
  return "unknown";
}

std::vector<std::string> CompressionNames() {
  std::vector<std::string> names;
  for (const auto& k : kCodecs) names.push_back(k.name);
  return names;
}

bool IsLossless(Compression c) {
  return c == Compression::kNone || c == Compression::kDeflate || c == Compression::kZstd;
}

int PixelLayout::CvType() const {
  return CV_MAKETYPE(bits == 16 ? CV_16U : CV_8U, channels);
}

bool PixelLayout::IsValid(std::string* error) const {
  // 2^31 - 1 per side keeps every level addressable with 32-bit TIFF dimensions.
  const long long kMaxSide = (1LL << 31) - 1;
  if (width <= 0 || height <= 0) {
    *error = "image size " + std::to_string(width) + "x" + std::to_string(height) +
             " is empty or negative";
    return false;
  }
  if (width > kMaxSide || height > kMaxSide) {
    *error = "image size " + std::to_string(width) + "x" + std::to_string(height) +
             " is larger than a TIFF can hold (2^31-1 per side)";
    return false;
  }
  if (channels < 1 || channels > 4) {
    *error = std::to_string(channels) + " channels; 1 to 4 are supported";
    return false;
  }
  if (bits != 8 && bits != 16) {
    *error = std::to_string(bits) + " bits per sample; 8 or 16 are supported";
    return false;
  }
  return true;
}

}  // namespace rolamos
