#include "raster/tile_encoder.h"

#include <immintrin.h>

#include <opencv2/imgproc.hpp>
#include <webp/encode.h>

#include "rolamos/error.hpp"
#include "raster/tiff_file.h"
#include "raster/tiff_tags.h"
#include "util/cpu_features.h"

namespace rolamos {

TileEncoder::TileEncoder(const PixelLayout& layout, const TiffWriteOptions& options, bool mask)
    : layout_(layout), options_(options), mask_(mask) {
  Reset();
}

TileEncoder::~TileEncoder() = default;

void TileEncoder::Reset() {
  if (file_) file_->Discard();
  file_ = TiffFile::OpenMemory("w");
  // A column of tiles; each Encode uses the next one and then forgets its bytes.
  capacity_ = 4096;
  LevelTags level;
  level.width = static_cast<uint32_t>(options_.tile_size);
  level.height = static_cast<uint32_t>(options_.tile_size) * capacity_;
  if (mask_) SetMaskTags(file_->get(), options_, level);
  else SetLevelTags(file_->get(), layout_, options_, level, /*for_encoding=*/true);
  header_size_ = file_->memory().size();
  next_tile_ = 0;
}

namespace {

std::vector<uint8_t> EncodeWebp(const cv::Mat& tile, const TiffWriteOptions& options) {
  WebPConfig config;
  if (!WebPConfigPreset(&config, WEBP_PRESET_DEFAULT, static_cast<float>(options.quality)))
    Fail("tile encoder (webp)", "libwebp version mismatch");
  config.method = options.webp_method;
  WebPPicture picture;
  if (!WebPPictureInit(&picture)) Fail("tile encoder (webp)", "libwebp version mismatch");
  picture.width = tile.cols;
  picture.height = tile.rows;
  picture.use_argb = 0;
  const int stride = static_cast<int>(tile.step[0]);
  const bool ok = tile.channels() == 4 ? WebPPictureImportRGBA(&picture, tile.data, stride)
                                       : WebPPictureImportRGB(&picture, tile.data, stride);
  if (!ok) {
    WebPPictureFree(&picture);
    Fail("tile encoder (webp)", "out of memory importing a tile");
  }
  WebPMemoryWriter writer;
  WebPMemoryWriterInit(&writer);
  picture.writer = WebPMemoryWrite;
  picture.custom_ptr = &writer;
  const bool encoded = WebPEncode(&config, &picture);
  const int code = picture.error_code;
  WebPPictureFree(&picture);
  std::vector<uint8_t> out(writer.mem, writer.mem + writer.size);
  WebPMemoryWriterClear(&writer);
  if (!encoded) Fail("tile encoder (webp)", "libwebp error " + std::to_string(code));
  return out;
}

}  // namespace

std::vector<uint8_t> TileEncoder::Encode(const cv::Mat& tile) {
  CV_Assert(tile.isContinuous() && tile.rows == options_.tile_size &&
            tile.cols == (mask_ ? options_.tile_size / 8 : options_.tile_size));
  if (options_.compression == Compression::kWebp && !mask_) return EncodeWebp(tile, options_);
  if (next_tile_ >= capacity_) Reset();
  TIFF* tif = file_->get();
  const uint32_t index = next_tile_++;
  const tmsize_t bytes = static_cast<tmsize_t>(tile.total() * tile.elemSize());
  if (TIFFWriteEncodedTile(tif, index, const_cast<uchar*>(tile.data), bytes) < 0)
    Fail("tile encoder (" + CompressionName(options_.compression) + ")", file_->TakeError());
  uint64_t* offsets = nullptr;
  uint64_t* counts = nullptr;
  if (!TIFFGetField(tif, TIFFTAG_TILEOFFSETS, &offsets) ||
      !TIFFGetField(tif, TIFFTAG_TILEBYTECOUNTS, &counts))
    Fail("tile encoder", "libtiff kept no tile offsets");
  const auto& mem = file_->memory();
  if (offsets[index] + counts[index] > mem.size()) Fail("tile encoder", "tile outside its buffer");
  std::vector<uint8_t> out(mem.begin() + static_cast<long>(offsets[index]),
                           mem.begin() + static_cast<long>(offsets[index] + counts[index]));
  // The next tile is appended at the end of the file: make that the header's end again.
  file_->TruncateMemory(header_size_);
  return out;
}

std::vector<uint8_t> TileEncoder::JpegTables() {
  if (mask_ || (options_.compression != Compression::kJpeg && options_.compression != Compression::kJpegMask))
    return {};
  if (next_tile_ == 0)
    Encode(cv::Mat::zeros(options_.tile_size, options_.tile_size, layout_.CvType()));
  uint32_t count = 0;
  void* data = nullptr;
  if (!TIFFGetField(file_->get(), TIFFTAG_JPEGTABLES, &count, &data) || !data)
    Fail("tile encoder", "libtiff made no JPEG tables");
  const auto* bytes = static_cast<const uint8_t*>(data);
  return std::vector<uint8_t>(bytes, bytes + count);
}

std::unique_ptr<TileEncoder> TileEncoderPool::Take() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!idle_.empty()) {
      auto encoder = std::move(idle_.back());
      idle_.pop_back();
      return encoder;
    }
  }
  return std::make_unique<TileEncoder>(layout_, options_, mask_);
}

void TileEncoderPool::Give(std::unique_ptr<TileEncoder> encoder) {
  std::lock_guard<std::mutex> lock(mutex_);
  idle_.push_back(std::move(encoder));
}

std::vector<uint8_t> TileEncoderPool::Encode(const cv::Mat& tile) {
  auto encoder = Take();
  auto bytes = encoder->Encode(tile);
  Give(std::move(encoder));
  return bytes;
}

std::vector<uint8_t> TileEncoderPool::JpegTables() {
  auto encoder = Take();
  auto tables = encoder->JpegTables();
  Give(std::move(encoder));
  return tables;
}

namespace {

// BGRA -> RGBA of 8-bit pixels: cv::cvtColor's bytes, without its dispatch and thread pool per
// tile (0.9 % of a still's CPU).
__attribute__((target("avx2"))) void SwapRedBlueAvx2(const uchar* in, uchar* out, int pixels) {
  const __m256i order = _mm256_setr_epi8(2, 1, 0, 3, 6, 5, 4, 7, 10, 9, 8, 11, 14, 13, 12, 15, 2, 1, 0, 3, 6, 5, 4, 7,
                                         10, 9, 8, 11, 14, 13, 12, 15);
  int i = 0;
  for (; i + 8 <= pixels; i += 8)
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + 4 * i),
                        _mm256_shuffle_epi8(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(in + 4 * i)), order));
  for (; i < pixels; ++i) {
    out[4 * i] = in[4 * i + 2];
    out[4 * i + 1] = in[4 * i + 1];
    out[4 * i + 2] = in[4 * i];
    out[4 * i + 3] = in[4 * i + 3];
  }
}

void SwapRedBlue(const cv::Mat& src, cv::Mat& dst) {
  if (src.type() != CV_8UC4 || !CpuHasAvx2()) {
    cv::cvtColor(src, dst, cv::COLOR_BGRA2RGBA);
    return;
  }
  for (int y = 0; y < src.rows; ++y) SwapRedBlueAvx2(src.ptr(y), dst.ptr(y), src.cols);
}

}  // namespace

cv::Mat CutFileTile(const cv::Mat& band, int tx, int tile_size) {
  const int x0 = tx * tile_size;
  const int w = std::min(tile_size, band.cols - x0);
  const int h = std::min(tile_size, band.rows);
  cv::Mat src = band(cv::Rect(x0, 0, w, h));
  cv::Mat tile(tile_size, tile_size, band.type());
  cv::Mat inner = tile(cv::Rect(0, 0, w, h));
  switch (band.channels()) {
    case 3: cv::cvtColor(src, inner, cv::COLOR_BGR2RGB); break;
    case 4: SwapRedBlue(src, inner); break;
    default: src.copyTo(inner); break;
  }
  if (w < tile_size || h < tile_size) {
    cv::Mat padded;
    cv::copyMakeBorder(inner, padded, 0, tile_size - h, 0, tile_size - w, cv::BORDER_REPLICATE | cv::BORDER_ISOLATED);
    return padded;
  }
  return tile;
}

}  // namespace rolamos
