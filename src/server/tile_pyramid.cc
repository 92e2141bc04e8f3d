#include "server/tile_pyramid.h"

#include <cmath>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace rolamos {

TilePyramid::TilePyramid(std::shared_ptr<TiledImage> image) : image_(std::move(image)) {
  const double side = double(std::max(image_->width(), image_->height()));
  max_level_ = static_cast<int>(std::ceil(std::log2(std::max(1.0, side))));
  const int zooms = side <= kTile ? 0 : static_cast<int>(std::ceil(std::log2(side / kTile)));
  xyz_shift_ = std::max(0, max_level_ - zooms);
}

cv::Size TilePyramid::LevelSize(int level) const {
  const double scale = std::ldexp(1.0, level - max_level_);
  return cv::Size(static_cast<int>(std::ceil(image_->width() * scale)),
                  static_cast<int>(std::ceil(image_->height() * scale)));
}

cv::Mat TilePyramid::Tile(int level, long long tx, long long ty) const {
  if (level < 0 || level > max_level_ || tx < 0 || ty < 0) return {};
  const double scale = std::ldexp(1.0, level - max_level_);
  const cv::Size size = LevelSize(level);
  if (tx * kTile >= size.width || ty * kTile >= size.height) return {};
  const int tw = static_cast<int>(std::min<long long>(kTile, size.width - tx * kTile));
  const int th = static_cast<int>(std::min<long long>(kTile, size.height - ty * kTile));
  return image_->ReadResampled(tx * kTile / scale, ty * kTile / scale, scale, cv::Size(tw, th));
}

bool TilePyramid::XyzTileTouchesImage(int z, long long x, long long y) const {
  const int level = z + xyz_shift_;
  if (z < 0 || level > max_level_ || x < 0 || y < 0) return false;
  const cv::Size size = LevelSize(level);
  return x * kTile < size.width && y * kTile < size.height;
}

cv::Mat TilePyramid::XyzTile(int z, long long x, long long y) const {
  const int level = z + xyz_shift_;
  if (z < 0 || z > 40 || level > max_level_ || x < 0 || y < 0 || x >= (1LL << z) || y >= (1LL << z)) return {};
  cv::Mat out(kTile, kTile, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  const cv::Mat part = Tile(level, x, y);
  if (part.empty()) return out;  // inside the grid, past the image: nothing there
  cv::Mat bgra = part;
  if (bgra.depth() == CV_16U) bgra.convertTo(bgra, CV_8U, 1.0 / 257.0);
  if (bgra.channels() == 1) cv::cvtColor(bgra, bgra, cv::COLOR_GRAY2BGRA);
  else if (bgra.channels() == 3) cv::cvtColor(bgra, bgra, cv::COLOR_BGR2BGRA);
  else if (bgra.channels() == 2) {
    cv::Mat gray, alpha, planes[4];
    cv::extractChannel(bgra, gray, 0);
    cv::extractChannel(bgra, alpha, 1);
    planes[0] = planes[1] = planes[2] = gray;
    planes[3] = alpha;
    cv::merge(planes, 4, bgra);
  }
  bgra.copyTo(out(cv::Rect(0, 0, bgra.cols, bgra.rows)));
  return out;
}

std::vector<uchar> TilePyramid::Encode(cv::Mat tile, const std::string& ext, int jpeg_quality,
                                       const cv::Scalar& background) {
  if (tile.depth() == CV_16U) tile.convertTo(tile, CV_8U, 1.0 / 257.0);
  std::vector<uchar> bytes;
  if (ext == "png") {
    cv::imencode(".png", tile, bytes, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } else if (ext == "webp") {
    if (tile.channels() == 2) cv::cvtColor(tile, tile, cv::COLOR_GRAY2BGRA);  // keeps alpha
    if (tile.channels() == 1) cv::cvtColor(tile, tile, cv::COLOR_GRAY2BGR);
    cv::imencode(".webp", tile, bytes, {cv::IMWRITE_WEBP_QUALITY, jpeg_quality});
  } else {
    if (tile.channels() == 4) {
      // Over the background where there is no data (and in proportion at the data's edges).
      cv::Mat flat(tile.size(), CV_8UC3);
      for (int y = 0; y < tile.rows; ++y) {
        const cv::Vec4b* p = tile.ptr<cv::Vec4b>(y);
        cv::Vec3b* q = flat.ptr<cv::Vec3b>(y);
        for (int x = 0; x < tile.cols; ++x) {
          const int a = p[x][3];
          for (int k = 0; k < 3; ++k)
            q[x][k] = static_cast<uchar>((p[x][k] * a + int(background[k]) * (255 - a) + 127) / 255);
        }
      }
      tile = flat;
    }
    if (tile.channels() == 2) cv::extractChannel(tile, tile, 0);
    cv::imencode(".jpg", tile, bytes, {cv::IMWRITE_JPEG_QUALITY, jpeg_quality});
  }
  return bytes;
}

std::string TilePyramid::DziDescriptor(const std::string& ext) const {
  return "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
         "<Image xmlns=\"http://schemas.microsoft.com/deepzoom/2008\" Format=\"" + ext +
         "\" Overlap=\"0\" TileSize=\"" + std::to_string(kTile) + "\">\n  <Size Width=\"" +
         std::to_string(image_->width()) + "\" Height=\"" + std::to_string(image_->height()) +
         "\"/>\n</Image>\n";
}

std::vector<std::pair<std::string, std::string>> StoreImages(const Store& store) {
  std::vector<std::pair<std::string, std::string>> images;
  if (store.HasMosaic()) images.emplace_back("mosaic", store.MosaicPath());
  for (const auto& p : store.patches()) images.emplace_back("patch-" + std::to_string(p.id), store.ImagePath(p.id));
  return images;
}

bool TileEncodingIsValid(int jpeg_quality, double cache_mb, std::string* error) {
  if (jpeg_quality < 1 || jpeg_quality > 100) {
    *error = "JPEG quality " + std::to_string(jpeg_quality) + " is outside 1..100";
    return false;
  }
  TileCacheOptions c;
  c.max_memory_mb = cache_mb;
  return c.IsValid(error);
}

}  // namespace rolamos
