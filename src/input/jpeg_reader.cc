#include "input/jpeg_reader.h"

#include <algorithm>
#include <csetjmp>
#include <cstdio>

#include <jpeglib.h>

#include "rolamos/error.hpp"
#include "util/files.h"

namespace rolamos {
namespace {

// libjpeg's default error handler ends the process; this one jumps back to the decoder, which
// hands the file to cv::imread. Warnings (corrupt data libjpeg fills in) are printed as
// cv::imread lets libjpeg print them.
struct ErrorJump {
  jpeg_error_mgr pub;
  std::jmp_buf back;
};

[[noreturn]] void JumpBack(j_common_ptr info) { std::longjmp(reinterpret_cast<ErrorJump*>(info->err)->back, 1); }

unsigned ReadUnsigned(const unsigned char* p, int bytes, bool big_endian) {
  unsigned v = 0;
  for (int i = 0; i < bytes; ++i) v |= unsigned(p[big_endian ? i : bytes - 1 - i]) << (8 * (bytes - 1 - i));
  return v;
}

// True when no APP1 marker turns the image (cv::imread applies an EXIF orientation).
bool Upright(jpeg_saved_marker_ptr marker) {
  for (; marker; marker = marker->next) {
    if (marker->marker != JPEG_APP0 + 1) continue;
    const int orientation = ExifOrientation(marker->data, marker->data_length);
    if (orientation > 1) return false;
    // An APP1 that is EXIF but did not parse: cv::imread may read it otherwise.
    if (orientation == 0 && marker->data_length >= 6 && std::equal(marker->data, marker->data + 6, "Exif\0\0"))
      return false;
  }
  return true;
}

// The decoding itself, between setjmp and the handler's longjmp: nothing here owns memory that
// a jump would leak (libjpeg's own is freed by jpeg_destroy_decompress; *image by its owner).
bool Decode(const unsigned char* data, size_t size, cv::Mat* image) {
  jpeg_decompress_struct info;
  ErrorJump error;
  info.err = jpeg_std_error(&error.pub);
  error.pub.error_exit = JumpBack;
  if (setjmp(error.back)) {
    jpeg_destroy_decompress(&info);
    return false;
  }
  jpeg_create_decompress(&info);
  jpeg_mem_src(&info, data, static_cast<unsigned long>(size));
  jpeg_save_markers(&info, JPEG_APP0 + 1, 0xFFFF);
  if (jpeg_read_header(&info, TRUE) != JPEG_HEADER_OK || info.num_components != 3 ||
      info.jpeg_color_space != JCS_YCbCr || !Upright(info.marker_list)) {
    jpeg_destroy_decompress(&info);
    return false;
  }
  info.out_color_space = JCS_EXT_BGR;
  jpeg_start_decompress(&info);
  image->create(static_cast<int>(info.output_height), static_cast<int>(info.output_width), CV_8UC3);
  while (info.output_scanline < info.output_height) {
    // As many rows as the decoder hands out at once (its upsampling's height).
    JSAMPROW rows[16];
    const unsigned n = std::min<unsigned>(16, info.output_height - info.output_scanline);
    for (unsigned k = 0; k < n; ++k) rows[k] = image->ptr<unsigned char>(static_cast<int>(info.output_scanline + k));
    jpeg_read_scanlines(&info, rows, n);
  }
  jpeg_finish_decompress(&info);
  jpeg_destroy_decompress(&info);
  return true;
}

}  // namespace

int ExifOrientation(const unsigned char* data, size_t size) {
  // "Exif\0\0", then a TIFF header: byte order, 42, the first directory's offset.
  if (size < 14 || !std::equal(data, data + 6, "Exif\0\0")) return 0;
  const unsigned char* tiff = data + 6;
  const size_t n = size - 6;
  const bool big = tiff[0] == 'M' && tiff[1] == 'M';
  if (!big && !(tiff[0] == 'I' && tiff[1] == 'I')) return 0;
  if (ReadUnsigned(tiff + 2, 2, big) != 42) return 0;
  const size_t ifd = ReadUnsigned(tiff + 4, 4, big);
  if (ifd + 2 > n) return 0;
  const size_t entries = ReadUnsigned(tiff + ifd, 2, big);
  if (ifd + 2 + 12 * entries > n) return 0;
  for (size_t i = 0; i < entries; ++i) {
    const unsigned char* e = tiff + ifd + 2 + 12 * i;
    if (ReadUnsigned(e, 2, big) != 0x0112) continue;
    // A SHORT: its value sits in the first two bytes of the value field.
    const int v = static_cast<int>(ReadUnsigned(e + 8, 2, big));
    return v >= 1 && v <= 8 ? v : 0;
  }
  return 1;
}

bool ReadJpegBgr(const std::string& path, cv::Mat* image) {
  image->release();
  std::string bytes;
  try {
    bytes = ReadSmallFile(path);  // a missing, unreadable or huge file: cv::imread says which
  } catch (const Error&) {
    return false;
  }
  return DecodeJpegBgr(bytes, image);
}

bool DecodeJpegBgr(const std::string& bytes, cv::Mat* image) {
  image->release();
  if (bytes.size() < 4 || bytes[0] != '\xFF' || bytes[1] != '\xD8') return false;
  if (Decode(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(), image)) return true;
  image->release();
  return false;
}

}  // namespace rolamos
