// Region export: .tif outputs stream band by band through PyramidTiffWriter (any size); PNG and
// JPEG outputs are built in memory up to a stated pixel limit.
#include <cmath>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rolamos/error.hpp"
#include "rolamos/region_export.hpp"
#include "util/files.h"

namespace rolamos {

bool ExportOptions::IsValid(std::string* error) const {
  const std::string ext = Extension(output);
  if (output.empty()) {
    *error = "no output file given";
    return false;
  }
  if (ext != ".tif" && ext != ".tiff" && ext != ".png" && ext != ".jpg" && ext != ".jpeg") {
    *error = "output " + output + ": unknown extension \"" + ext + "\" (use .tif, .png or .jpg)";
    return false;
  }
  if (level < 0 && !(scale > 0 && scale <= 1.0)) {
    *error = "scale " + std::to_string(scale) + " is outside (0, 1]";
    return false;
  }
  if (region.width < 0 || region.height < 0 || region.x < 0 || region.y < 0) {
    *error = "region has negative numbers";
    return false;
  }
  if (jpeg_quality < 1 || jpeg_quality > 100) {
    *error = "JPEG quality " + std::to_string(jpeg_quality) + " is outside 1..100";
    return false;
  }
  return true;
}

ExportResult ExportRegion(const TiledImage& source, const ExportOptions& options,
                          const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("export", error);
  const auto& info = source.info();
  cv::Rect2d region = options.region;
  if (region.width == 0 || region.height == 0)
    region = cv::Rect2d(0, 0, double(source.width()), double(source.height()));
  if (region.x + region.width > source.width() + 1e-9 ||
      region.y + region.height > source.height() + 1e-9)
    Fail(info.path, "region " + std::to_string(long(region.x)) + "," +
                        std::to_string(long(region.y)) + "," + std::to_string(long(region.width)) +
                        "," + std::to_string(long(region.height)) + " is outside the image (" +
                        std::to_string(source.width()) + "x" + std::to_string(source.height()) +
                        ")");
  ExportResult result;
  if (options.level >= 0) {
    if (options.level >= source.num_levels())
      Fail(info.path, "level " + std::to_string(options.level) + " does not exist (levels 0.." +
                          std::to_string(source.num_levels() - 1) + ")");
    result.level = options.level;
    result.scale = double(info.levels[static_cast<size_t>(options.level)].width) / source.width();
  } else {
    result.scale = options.scale;
    result.level = source.LevelForScale(options.scale);
  }
  result.width = std::max(1L, std::lround(region.width * result.scale));
  result.height = std::max(1L, std::lround(region.height * result.scale));

  std::optional<Georef> georef;
  if (info.georef) georef = info.georef->ForWindow(region.x, region.y, result.scale);

  const std::string ext = Extension(options.output);
  if (ext == ".tif" || ext == ".tiff") {
    PixelLayout layout;
    layout.width = result.width;
    layout.height = result.height;
    layout.channels = info.channels;
    layout.bits = info.bits;
    PyramidTiffWriter writer(options.output, layout, options.tiff);
    if (georef) writer.SetGeoref(*georef);
    const int band = writer.band_height();
    for (long long y = 0; y < result.height; y += band) {
      const int rows = static_cast<int>(std::min<long long>(band, result.height - y));
      writer.WriteBand(source.ReadResampled(region.x, region.y + y / result.scale, result.scale,
                                            cv::Size(static_cast<int>(result.width), rows)));
      if (progress) progress(double(y + rows) / result.height);
    }
    writer.Finish();
    return result;
  }

  if (result.width * result.height > options.max_memory_pixels)
    Fail(options.output, std::to_string(result.width) + "x" + std::to_string(result.height) +
                             " pixels is more than the " +
                             std::to_string(options.max_memory_pixels) +
                             " a PNG/JPEG export builds in memory; export to .tif (streamed) or "
                             "choose a smaller scale");
  if (result.width > 65500 && ext != ".png")
    Fail(options.output, "JPEG cannot be wider or taller than 65500 pixels; export to .tif");
  cv::Mat pixels = source.ReadResampled(region.x, region.y, result.scale,
                                        cv::Size(static_cast<int>(result.width),
                                                 static_cast<int>(result.height)));
  if (progress) progress(0.9);
  std::vector<int> params;
  if (ext == ".png") {
    params = {cv::IMWRITE_PNG_COMPRESSION, 3};
  } else {
    if (pixels.depth() == CV_16U) pixels.convertTo(pixels, CV_8U, 1.0 / 257.0);
    if (pixels.channels() == 4) cv::cvtColor(pixels, pixels, cv::COLOR_BGRA2BGR);
    if (pixels.channels() == 2) cv::extractChannel(pixels, pixels, 0);
    params = {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality};
  }
  // Encode in memory, then write atomically: a failed export leaves no half file behind.
  std::vector<uchar> bytes;
  if (!cv::imencode(ext, pixels, bytes, params))
    Fail(options.output, "OpenCV could not encode the image");
  WriteFileAtomic(options.output, std::string(bytes.begin(), bytes.end()));
  if (progress) progress(1.0);
  return result;
}

}  // namespace rolamos
